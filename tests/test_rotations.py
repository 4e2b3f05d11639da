"""Tests for cuboidlib.rotations: quaternions and rotation matrices."""

import math

import pytest
import torch

from cuboidlib.rotations import (
    quaternion_multiply,
    quaternion_to_rotation_matrix,
    random_quaternions,
    rotation_matrix_to_quaternion,
    standardize_quaternion,
)


def gen(seed=0):
    return torch.Generator().manual_seed(seed)


def axis_angle_quaternion(axis, angle):
    axis = torch.tensor(axis, dtype=torch.float64)
    axis = axis / axis.norm()
    return torch.cat([torch.tensor([math.cos(angle / 2)], dtype=torch.float64), math.sin(angle / 2) * axis])


def test_identity_quaternion_gives_identity_matrix():
    R = quaternion_to_rotation_matrix(torch.tensor([1.0, 0.0, 0.0, 0.0]))
    torch.testing.assert_close(R, torch.eye(3))


def test_quarter_turn_about_z_maps_x_to_y():
    q = axis_angle_quaternion([0, 0, 1], math.pi / 2)
    R = quaternion_to_rotation_matrix(q)
    expected = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    torch.testing.assert_close(R, expected)
    # The columns are the rotated local axes: local x now points along world y.
    torch.testing.assert_close(R[:, 0], torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))


def test_rotation_matrices_are_orthonormal_with_det_one():
    q = random_quaternions(4, 5, generator=gen(1), dtype=torch.float64)
    R = quaternion_to_rotation_matrix(q)
    assert R.shape == (4, 5, 3, 3)
    torch.testing.assert_close(R.transpose(-1, -2) @ R, torch.eye(3, dtype=torch.float64).expand(4, 5, 3, 3))
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(4, 5, dtype=torch.float64))


def test_slightly_non_unit_quaternion_still_gives_a_rotation():
    q = random_quaternions(6, generator=gen(2), dtype=torch.float64) * (1 + 5e-4)
    R = quaternion_to_rotation_matrix(q)
    torch.testing.assert_close(R, quaternion_to_rotation_matrix(q / q.norm(dim=-1, keepdim=True)))


def test_quaternion_multiply_composes_rotations():
    a = random_quaternions(7, generator=gen(3), dtype=torch.float64)
    b = random_quaternions(7, generator=gen(4), dtype=torch.float64)
    Ra, Rb = quaternion_to_rotation_matrix(a), quaternion_to_rotation_matrix(b)
    torch.testing.assert_close(quaternion_to_rotation_matrix(quaternion_multiply(a, b)), Ra @ Rb)


@pytest.mark.parametrize(
    "axis,angle",
    [([1, 0, 0], 0.0), ([1, 0, 0], math.pi), ([0, 1, 0], math.pi), ([0, 0, 1], math.pi),
     ([1, 1, 0], math.pi), ([1, -2, 3], 2.5), ([0.3, 0.1, -1], -1.0)],
)
def test_rotation_matrix_to_quaternion_round_trip(axis, angle):
    q = axis_angle_quaternion(axis, angle)
    R = quaternion_to_rotation_matrix(q)
    q_back = rotation_matrix_to_quaternion(R)
    torch.testing.assert_close(quaternion_to_rotation_matrix(q_back), R)
    assert q_back[0] >= 0
    # Same rotation, so the same unit quaternion up to sign (the sign is ambiguous for half turns).
    assert min(float((q_back - q).abs().max()), float((q_back + q).abs().max())) < 1e-12


def test_rotation_matrix_to_quaternion_batch_canonical():
    q = random_quaternions(50, generator=gen(5), dtype=torch.float64)
    q_neg = -q
    q_back = rotation_matrix_to_quaternion(quaternion_to_rotation_matrix(q_neg))
    torch.testing.assert_close(q_back, q)  # random_quaternions are canonical (w >= 0)
    assert (q_back[:, 0] >= 0).all()


def test_rotation_matrix_to_quaternion_gradcheck():
    R = quaternion_to_rotation_matrix(axis_angle_quaternion([1, 2, 3], 1.1)).clone().requires_grad_(True)
    assert torch.autograd.gradcheck(rotation_matrix_to_quaternion, (R,))


def test_rotation_matrix_to_quaternion_rejects_reflections():
    with pytest.raises(ValueError, match="determinant"):
        rotation_matrix_to_quaternion(torch.diag(torch.tensor([1.0, 1.0, -1.0])))
    with pytest.raises(ValueError, match="R\\^T R = I"):
        rotation_matrix_to_quaternion(2 * torch.eye(3))


def test_standardize_quaternion_signs():
    q = torch.tensor([[-0.5, 0.5, 0.5, 0.5], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, -1.0], [0.5, -0.5, 0.5, 0.5]])
    # w < 0 flips everything; w = 0 makes the first non-zero of x, y, z positive; w > 0 is kept.
    expected = torch.tensor([[0.5, -0.5, -0.5, -0.5], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0],
                             [0.5, -0.5, 0.5, 0.5]])
    torch.testing.assert_close(standardize_quaternion(q), expected)


def test_random_quaternions_unit_canonical_and_deterministic():
    q1 = random_quaternions(3, 4, generator=gen(7))
    q2 = random_quaternions(3, 4, generator=gen(7))
    assert q1.shape == (3, 4, 4)
    assert torch.equal(q1, q2)
    assert not torch.equal(q1, random_quaternions(3, 4, generator=gen(8)))
    torch.testing.assert_close(q1.norm(dim=-1), torch.ones(3, 4))
    assert (q1[..., 0] >= 0).all()


def test_quaternion_errors():
    with pytest.raises(ValueError, match="zero-length"):
        quaternion_to_rotation_matrix(torch.zeros(4))
    with pytest.raises(ValueError, match="normalise"):
        quaternion_to_rotation_matrix(torch.tensor([1.0, 1.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="shape \\(..., 4\\)"):
        quaternion_to_rotation_matrix(torch.ones(3))
