"""Tests for cuboidlib.geometry: frames, faces, corners, meshes, surface sampling."""

import math

import numpy as np
import pytest
import torch

from cuboidlib.geometry import (
    CORNER_SIGNS,
    CUBOID_TRIANGLES,
    FACE_NORMALS,
    FACE_TANGENTS,
    Cuboids,
    cuboid_corners,
    cuboid_face_areas,
    cuboid_face_normals,
    cuboids_to_trimesh,
    directions_to_local,
    directions_to_world,
    local_to_world,
    sample_cuboid_surfaces,
    validate_cuboids,
    world_to_local,
)
from cuboidlib.rotations import quaternion_to_rotation_matrix, random_quaternions


def gen(seed=0):
    return torch.Generator().manual_seed(seed)


def random_cuboids(b, m, seed=0, dtype=torch.float32):
    g = gen(seed)
    centers = torch.randn(b, m, 3, generator=g, dtype=dtype)
    quats = random_quaternions(b, m, generator=g, dtype=dtype)
    half = 0.2 + torch.rand(b, m, 3, generator=g, dtype=dtype)
    return centers, quats, half


def axis_angle_quaternion(axis, angle):
    axis = torch.tensor(axis, dtype=torch.float64)
    axis = axis / axis.norm()
    return torch.cat([torch.tensor([math.cos(angle / 2)], dtype=torch.float64), math.sin(angle / 2) * axis])


# ---------------------------------------------------------------------------------------------
# Local frames
# ---------------------------------------------------------------------------------------------


def test_world_to_local_known_values():
    centers = torch.tensor([[[1.0, 2.0, 3.0]]])
    quats = axis_angle_quaternion([0, 0, 1], math.pi / 2).float()[None, None]
    # Local x is world y, local y is world -x. A point 2 units along world y from the centre
    # therefore has local coordinates (2, 0, 0); one 1 unit along world -x has (0, 1, 0).
    points = torch.tensor([[[1.0, 4.0, 3.0], [0.0, 2.0, 3.0], [1.0, 2.0, 3.0]]])
    local = world_to_local(points, centers, quats)
    assert local.shape == (1, 3, 1, 3)
    torch.testing.assert_close(local[0, :, 0], torch.tensor([[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]]))


def test_world_local_round_trip_and_directions():
    c, q, _ = random_cuboids(2, 3, seed=9, dtype=torch.float64)
    p = torch.randn(2, 5, 3, generator=gen(10), dtype=torch.float64)
    local = world_to_local(p, c, q)
    torch.testing.assert_close(local_to_world(local, c, q), p[:, :, None].expand(2, 5, 3, 3))
    d = torch.randn(2, 5, 3, generator=gen(11), dtype=torch.float64)
    d_local = directions_to_local(d, q)
    torch.testing.assert_close(d_local.norm(dim=-1), d.norm(dim=-1)[..., None].expand(2, 5, 3))
    torch.testing.assert_close(directions_to_world(d_local, q), d[:, :, None].expand(2, 5, 3, 3))
    # Directions ignore translation: the difference of two points transforms as a direction.
    torch.testing.assert_close(local[:, 1] - local[:, 0], directions_to_local(p[:, 1:2] - p[:, 0:1], q)[:, 0])


def test_world_to_local_broadcasts_batch_of_one():
    c, q, _ = random_cuboids(3, 2, seed=12)
    p = torch.randn(1, 4, 3, generator=gen(13))
    out = world_to_local(p, c, q)
    assert out.shape == (3, 4, 2, 3)
    torch.testing.assert_close(out, world_to_local(p.expand(3, 4, 3), c, q))
    out2 = world_to_local(p.expand(3, 4, 3), c[:1], q[:1])
    torch.testing.assert_close(out2, world_to_local(p.expand(3, 4, 3), c[:1].expand(3, 2, 3), q[:1].expand(3, 2, 4)))
    with pytest.raises(ValueError, match="batch size 2 but the cuboids have 3"):
        world_to_local(torch.zeros(2, 4, 3), c, q)


# ---------------------------------------------------------------------------------------------
# Faces, corners, areas
# ---------------------------------------------------------------------------------------------


def test_face_constants_are_consistent():
    expected = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]
    assert torch.equal(FACE_NORMALS, torch.tensor(expected, dtype=torch.float32))
    u, v = FACE_TANGENTS[:, 0], FACE_TANGENTS[:, 1]
    torch.testing.assert_close(torch.linalg.cross(u, v), FACE_NORMALS)
    assert torch.equal(CORNER_SIGNS[0], torch.tensor([-1.0, -1.0, -1.0]))
    assert torch.equal(CORNER_SIGNS[1], torch.tensor([1.0, -1.0, -1.0]))
    assert torch.equal(CORNER_SIGNS[7], torch.tensor([1.0, 1.0, 1.0]))
    # Each face's two triangles use exactly the 4 corners on that face, wound outwards.
    for f in range(6):
        axis, sign = f // 2, FACE_NORMALS[f, f // 2]
        tri = CUBOID_TRIANGLES[2 * f : 2 * f + 2]
        assert (CORNER_SIGNS[tri.flatten(), axis] == sign).all()
        assert len(set(tri.flatten().tolist())) == 4
        a, b, c = CORNER_SIGNS[tri[0]]
        normal = torch.linalg.cross(b - a, c - a)
        torch.testing.assert_close(normal / normal.norm(), FACE_NORMALS[f])


def test_world_face_normals_are_signed_rotation_columns():
    _, q, _ = random_cuboids(2, 3, seed=14)
    R = quaternion_to_rotation_matrix(q)
    normals = cuboid_face_normals(q)
    assert normals.shape == (2, 3, 6, 3)
    for f in range(6):
        torch.testing.assert_close(normals[:, :, f], (1 if f % 2 == 0 else -1) * R[..., f // 2])


def test_corners_lie_on_three_faces_each():
    c, q, s = random_cuboids(2, 4, seed=15, dtype=torch.float64)
    corners = cuboid_corners(c, q, s)
    assert corners.shape == (2, 4, 8, 3)
    # In the local frame every corner has |l_i| = s_i on every axis, with the documented signs.
    R = quaternion_to_rotation_matrix(q)
    local = torch.einsum("bmji,bmkj->bmki", R, corners - c[:, :, None])
    torch.testing.assert_close(local, CORNER_SIGNS.double() * s[:, :, None])
    # Edge from corner 0 to corner 1 runs along local x with length 2 s_x.
    torch.testing.assert_close((corners[:, :, 1] - corners[:, :, 0]).norm(dim=-1), 2 * s[..., 0])


def test_face_areas():
    areas = cuboid_face_areas(torch.tensor([1.0, 2.0, 3.0]))
    # +-x faces span 2*2 by 2*3, +-y faces 2*1 by 2*3, +-z faces 2*1 by 2*2.
    torch.testing.assert_close(areas, torch.tensor([24.0, 24.0, 12.0, 12.0, 8.0, 8.0]))
    assert cuboid_face_areas(torch.ones(2, 5, 3)).shape == (2, 5, 6)


# ---------------------------------------------------------------------------------------------
# Meshes
# ---------------------------------------------------------------------------------------------


def test_trimesh_volume_watertight_and_outward():
    c, q, s = random_cuboids(1, 3, seed=16, dtype=torch.float64)
    mesh = cuboids_to_trimesh(c[0], q[0], s[0])
    assert len(mesh.faces) == 36 and len(mesh.vertices) == 24
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(float((8 * s[0].prod(-1)).sum()), rel=1e-9)
    parts = cuboids_to_trimesh(c[0], q[0], s[0], split=True)
    assert len(parts) == 3
    for m, part in enumerate(parts):
        assert part.is_watertight
        assert part.volume == pytest.approx(8 * float(s[0, m].prod()), rel=1e-9)  # positive: outward
        # Triangles 2f and 2f + 1 face along the world normal of face f.
        normals = cuboid_face_normals(q[0, m][None, None])[0, 0].numpy()
        np.testing.assert_allclose(part.face_normals[0::2], normals, atol=1e-9)
        np.testing.assert_allclose(part.face_normals[1::2], normals, atol=1e-9)


def test_trimesh_exists_and_colors_from_numpy():
    c, q, s = (x[0].numpy() for x in random_cuboids(1, 3, seed=17))
    colors = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    mesh = cuboids_to_trimesh(c, q, s, exists=np.array([True, False, True]), colors=colors)
    assert len(mesh.faces) == 24
    assert mesh.volume == pytest.approx(8 * (s[0].prod() + s[2].prod()), rel=1e-5)
    fc = mesh.visual.face_colors
    assert (fc[:12] == [255, 0, 0, 255]).all() and (fc[12:] == [0, 0, 255, 255]).all()
    parts = cuboids_to_trimesh(c, q, s, exists=[False, True, False], colors=colors, split=True)
    assert len(parts) == 1 and (parts[0].visual.face_colors == [0, 255, 0, 255]).all()
    assert len(cuboids_to_trimesh(c, q, s, exists=[False, False, False]).faces) == 0


def test_trimesh_errors():
    c, q, s = random_cuboids(1, 2, seed=18)
    with pytest.raises(ValueError, match="ONE shape"):
        cuboids_to_trimesh(c, q, s)
    with pytest.raises(ValueError, match="colors must have shape"):
        cuboids_to_trimesh(c[0], q[0], s[0], colors=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="\\[0, 1\\]"):
        cuboids_to_trimesh(c[0], q[0], s[0], colors=np.full((2, 3), 2.0))


# ---------------------------------------------------------------------------------------------
# Surface sampling
# ---------------------------------------------------------------------------------------------


def _local_samples(samples, c, q, s):
    """Local coordinates, local normals and sizes of each sample in its own cuboid's frame."""
    idx = samples.cuboid_index
    R = quaternion_to_rotation_matrix(q)

    def pick(x):
        index = idx.reshape(*idx.shape, *[1] * (x.dim() - 2)).expand(*idx.shape, *x.shape[2:])
        return torch.gather(x, 1, index)

    R_i, c_i, s_i = pick(R), pick(c), pick(s)
    local = torch.einsum("bnji,bnj->bni", R_i, samples.points - c_i)
    local_n = torch.einsum("bnji,bnj->bni", R_i, samples.normals)
    return local, local_n, s_i


def test_samples_lie_on_surfaces_with_outward_normals():
    c, q, s = random_cuboids(2, 4, seed=19, dtype=torch.float64)
    samples = sample_cuboid_surfaces(c, q, s, 500, generator=gen(20))
    assert samples.points.shape == (2, 500, 3) and samples.normals.shape == (2, 500, 3)
    assert samples.cuboid_index.shape == (2, 500) and samples.cuboid_index.dtype == torch.long
    local, local_n, s_i = _local_samples(samples, c, q, s)
    ratio = local.abs() / s_i
    assert (ratio <= 1 + 1e-9).all()  # inside the box ...
    torch.testing.assert_close(ratio.amax(dim=-1), torch.ones(2, 500, dtype=torch.float64))  # ... on its surface
    # The local normal is +-e_a where the point sits on the face l_a = +-s_a (outward).
    torch.testing.assert_close(samples.normals.norm(dim=-1), torch.ones(2, 500, dtype=torch.float64))
    axis = local_n.abs().argmax(dim=-1, keepdim=True)
    torch.testing.assert_close(local_n.abs().amax(dim=-1), torch.ones(2, 500, dtype=torch.float64))
    on_axis = torch.gather(local, -1, axis)
    torch.testing.assert_close(on_axis, torch.gather(local_n, -1, axis) * torch.gather(s_i, -1, axis))


def test_sampling_is_area_weighted_and_uniform_on_faces():
    # Two axis-aligned cuboids of very different sizes in one shape.
    c = torch.tensor([[[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]])
    q = torch.tensor([[[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]]])
    s = torch.tensor([[[0.5, 1.0, 1.5], [0.2, 0.3, 0.1]]])
    n = 40000
    samples = sample_cuboid_surfaces(c, q, s, n, generator=gen(21))
    local, local_n, s_i = _local_samples(samples, c, q, s)
    face = (local_n == FACE_NORMALS[:, None, None]).all(-1).float().argmax(0)  # (1, n) face 0..5
    category = (samples.cuboid_index * 6 + face)[0]
    observed = torch.bincount(category, minlength=12).double()
    # Expected counts from the areas written out by hand: +-x faces 4 s_y s_z, +-y 4 s_x s_z, +-z 4 s_x s_y.
    areas = []
    for sx, sy, sz in s[0].double().tolist():
        areas += [4 * sy * sz] * 2 + [4 * sx * sz] * 2 + [4 * sx * sy] * 2
    expected = torch.tensor(areas) / sum(areas) * n
    chi2 = float(((observed - expected) ** 2 / expected).sum())
    assert chi2 < 40.0, f"chi-square {chi2:.1f} with 11 degrees of freedom: face counts do not follow areas"
    # Uniform on each face: the in-face coordinates divided by the half sizes are U(-1, 1),
    # mean 0 and variance 1/3 (checked on every coordinate that is not the face axis).
    u = (local / s_i)[local_n == 0]
    assert abs(float(u.mean())) < 0.02
    assert abs(float(u.var()) - 1 / 3) < 0.01


def test_sampling_honours_exists_and_is_deterministic():
    c, q, s = random_cuboids(2, 4, seed=22)
    exists = torch.tensor([[True, False, True, False], [False, False, False, True]])
    a = sample_cuboid_surfaces(c, q, s, 300, exists=exists, generator=gen(23))
    b = sample_cuboid_surfaces(c, q, s, 300, exists=exists, generator=gen(23))
    other = sample_cuboid_surfaces(c, q, s, 300, exists=exists, generator=gen(24))
    assert torch.equal(a.points, b.points) and torch.equal(a.cuboid_index, b.cuboid_index)
    assert not torch.equal(a.points, other.points)
    assert set(a.cuboid_index[0].tolist()) == {0, 2}
    assert set(a.cuboid_index[1].tolist()) == {3}
    with pytest.raises(ValueError, match="no cuboid in shape 1"):
        sample_cuboid_surfaces(c, q, s, 10, exists=torch.tensor([[True] * 4, [False] * 4]))
    with pytest.raises(ValueError, match="n_points must be a positive integer"):
        sample_cuboid_surfaces(c, q, s, 0)


def test_sampling_is_differentiable_reparameterised():
    c, q, s = random_cuboids(1, 2, seed=25, dtype=torch.float64)
    for t in (c, q, s):
        t.requires_grad_(True)

    def f(c, q, s):
        samples = sample_cuboid_surfaces(c, q, s, 8, generator=gen(26))
        return samples.points, samples.normals

    assert torch.autograd.gradcheck(f, (c, q, s))


# ---------------------------------------------------------------------------------------------
# Validation and the container
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "change,match",
    [
        (lambda c, q, s: (c[..., :2], q, s), "centers must have shape \\(B, M, 3\\)"),
        (lambda c, q, s: (c, q[:, :1], s), "size M of"),
        (lambda c, q, s: (c, q * 2, s), "unit vectors.*normalise"),
        (lambda c, q, s: (c, q * 0, s), "zero-length"),
        (lambda c, q, s: (c, q, -s), "half_sizes must be positive"),
        (lambda c, q, s: (c, q, s * 0), "half_sizes must be positive"),
        (lambda c, q, s: (c.index_fill(1, torch.tensor([1]), float("nan")), q, s), "centers contains .* NaN"),
        (lambda c, q, s: (c[:, :0], q[:, :0], s[:, :0]), "M = 0"),
    ],
)
def test_validate_cuboids_errors(change, match):
    c, q, s = random_cuboids(2, 3, seed=27)
    with pytest.raises(ValueError, match=match):
        validate_cuboids(*change(c, q, s))


def test_validate_cuboids_converts_and_checks_exists():
    c, q, s = random_cuboids(2, 3, seed=28)
    out = validate_cuboids(c.double(), q, s.numpy(), exists=[[1, 0, 1], [0, 1, 1]])
    assert all(t.dtype == torch.float64 for t in out[:3])
    assert out[3].dtype == torch.bool and out[3].tolist() == [[True, False, True], [False, True, True]]
    with pytest.raises(TypeError, match="threshold"):
        validate_cuboids(c, q, s, exists=torch.full((2, 3), 0.7))
    with pytest.raises(ValueError, match="exists must have shape"):
        validate_cuboids(c, q, s, exists=torch.ones(2, 4, dtype=torch.bool))


def test_cuboids_container():
    c, q, s = random_cuboids(2, 3, seed=29)
    exists = torch.tensor([[True, True, False], [True, False, False]])
    cub = Cuboids(c, q, s, exists)
    assert cub.batch_size == 2 and cub.num_cuboids == 3
    assert torch.equal(cub.existing(), exists)
    assert Cuboids(c, q, s).existing().all()
    torch.testing.assert_close(cub.corners(), cuboid_corners(c, q, s))
    torch.testing.assert_close(cub.face_normals(), cuboid_face_normals(q))
    torch.testing.assert_close(cub.rotation_matrices(), quaternion_to_rotation_matrix(q))
    assert cub.to(dtype=torch.float64).centers.dtype == torch.float64
    assert cub.to(dtype=torch.float64).exists.dtype == torch.bool
    mesh = cub.to_trimesh(1)
    assert mesh.volume == pytest.approx(8 * float(s[1, 0].prod()), rel=1e-5)
    assert len(cub.to_trimesh(0, split=True)) == 2
    with pytest.raises(IndexError, match="out of range"):
        cub.to_trimesh(2)
    samples = cub.sample_surface(100, generator=gen(30))
    assert set(samples.cuboid_index[1].tolist()) == {0}
    assert not cub.detach().centers.requires_grad
    with pytest.raises(ValueError, match="half_sizes must be positive"):
        Cuboids(c, q, -s)
