"""Tests for cuboidlib.distance: the paper's point-to-cuboid distance (Eq. 5) and its baselines."""

import math

import numpy as np
import pytest
import torch

from cuboidlib.distance import (
    chamfer_distance,
    chamfer_distance_to_cuboids,
    nearest_neighbors,
    nearest_surface_distance,
    point_to_cuboid_distance,
)
from cuboidlib.geometry import sample_cuboid_surfaces
from cuboidlib.rotations import quaternion_multiply, quaternion_to_rotation_matrix, random_quaternions


def gen(seed=0):
    return torch.Generator().manual_seed(seed)


def random_cuboids(b, m, seed=0, dtype=torch.float64):
    g = gen(seed)
    return (
        torch.randn(b, m, 3, generator=g, dtype=dtype),
        random_quaternions(b, m, generator=g, dtype=dtype),
        0.3 + torch.rand(b, m, 3, generator=g, dtype=dtype),
    )


def random_points(b, n, seed=0, dtype=torch.float64, scale=1.5):
    g = gen(seed)
    p = scale * torch.randn(b, n, 3, generator=g, dtype=dtype)
    nrm = torch.randn(b, n, 3, generator=g, dtype=dtype)
    return p, nrm / nrm.norm(dim=-1, keepdim=True)


# An axis-aligned box at the origin with half sizes (1, 2, 3): faces at x = +-1, y = +-2, z = +-3.
BOX = (
    torch.zeros(1, 1, 3, dtype=torch.float64),
    torch.tensor([[[1.0, 0.0, 0.0, 0.0]]], dtype=torch.float64),
    torch.tensor([[[1.0, 2.0, 3.0]]], dtype=torch.float64),
)


def box_distance(point, normal, offset=None, sigma_s=0.0):
    p = torch.tensor([[point]], dtype=torch.float64)
    n = torch.tensor([[normal]], dtype=torch.float64)
    n = n / n.norm(dim=-1, keepdim=True)
    e = None if offset is None else torch.tensor([[offset]], dtype=torch.float64)
    return float(point_to_cuboid_distance(p, n, *BOX, sigma_s=sigma_s, offsets=e)[0, 0, 0])


# ---------------------------------------------------------------------------------------------
# A reference written independently in world coordinates with explicit loops
# ---------------------------------------------------------------------------------------------


def world_faces(center, quat, half):
    """The six faces of one cuboid in world space: (centre, outward normal, (u, hu), (v, hv))."""
    R = quaternion_to_rotation_matrix(torch.as_tensor(quat)).numpy()
    faces = []
    for axis in range(3):
        others = [i for i in range(3) if i != axis]
        for sign in (1.0, -1.0):
            n = sign * R[:, axis]
            faces.append(
                (center + half[axis] * n, n, (R[:, others[0]], half[others[0]]), (R[:, others[1]], half[others[1]]))
            )
    return faces


def closest_on_face(x, face):
    """Closest point of a face rectangle to x: project onto the plane, clamp along both edges."""
    fc, _, (u, hu), (v, hv) = face
    a = np.clip(np.dot(x - fc, u), -hu, hu)
    b = np.clip(np.dot(x - fc, v), -hv, hv)
    return fc + a * u + b * v


def reference_p2c(points, normals, offsets, centers, quats, halves):
    B, N, M = points.shape[0], points.shape[1], centers.shape[1]
    out = np.zeros((B, N, M))
    for b in range(B):
        for m in range(M):
            faces = world_faces(centers[b, m], quats[b, m], halves[b, m])
            for n in range(N):
                p, nrm = points[b, n], normals[b, n]
                face = max(faces, key=lambda f: float(np.dot(f[1], nrm)))  # most similar normal
                q = closest_on_face(p + offsets[b, n] * nrm, face)
                out[b, n, m] = np.sum((q - p) ** 2)
    return out


def reference_nearest(points, centers, quats, halves):
    B, N, M = points.shape[0], points.shape[1], centers.shape[1]
    out = np.zeros((B, N, M))
    for b in range(B):
        for m in range(M):
            faces = world_faces(centers[b, m], quats[b, m], halves[b, m])
            for n in range(N):
                p = points[b, n]
                out[b, n, m] = min(np.sum((closest_on_face(p, f) - p) ** 2) for f in faces)
    return out


# ---------------------------------------------------------------------------------------------
# point_to_cuboid_distance: analytic cases
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("offset", [None, 0.0, 0.3, -0.7])
def test_point_on_face_with_face_normal_is_zero(offset):
    # (0.3, -0.5, 3) lies on the +z face; whatever the offset along +z, q is the point itself.
    assert box_distance([0.3, -0.5, 3.0], [0, 0, 1], offset) == 0.0
    assert box_distance([1.0, 0.4, -2.5], [1, 0, 0], offset) == 0.0


@pytest.mark.parametrize("offset", [None, 0.4])
def test_point_on_face_with_opposite_normal_is_not_zero(offset):
    # Normal -z selects the -z face at z = -3: the distance is the box's full height squared.
    assert box_distance([0.3, -0.5, 3.0], [0, 0, -1], offset) == pytest.approx(36.0)


def test_outside_inside_edge_and_corner_cases():
    # Outside above the +z face: q = (0.3, -0.5, 3), d = 2^2, whatever the offset along z.
    assert box_distance([0.3, -0.5, 5.0], [0, 0, 1]) == pytest.approx(4.0)
    assert box_distance([0.3, -0.5, 5.0], [0, 0, 1], offset=-1.3) == pytest.approx(4.0)
    # Outside beyond an edge: the face rectangle is clamped, q = (1, 0, 3), d = 1 + 4.
    assert box_distance([2.0, 0.0, 5.0], [0, 0, 1]) == pytest.approx(5.0)
    # Near a corner with the +z face most similar: q = (1, 2, 3), d = 1 + 1 + 1.
    assert box_distance([2.0, 3.0, 4.0], [0.6, 0.48, 0.64]) == pytest.approx(3.0)
    # Inside: normal +x gives q = (1, 0.5, 1), d = 0.25; normal -z gives q = (0.5, 0.5, -3), d = 16.
    assert box_distance([0.5, 0.5, 1.0], [1, 0, 0]) == pytest.approx(0.25)
    assert box_distance([0.5, 0.5, 1.0], [0, 0, -1]) == pytest.approx(16.0)
    # Inside, sampled along a tilted normal (+y face chosen): p^s = p + 0.5 (0.6, 0.8, 0) =
    # (0.8, 0.9, 1), q = (0.8, 2, 1), so d = 0.3^2 + 1.5^2.
    assert box_distance([0.5, 0.5, 1.0], [0.6, 0.8, 0], offset=0.5) == pytest.approx(0.09 + 2.25)


@pytest.mark.parametrize("theta_deg", [0.0, 20.0, 40.0])
def test_tilted_normal_gives_offset_times_sine_squared(theta_deg):
    # p on the +z face, normal tilted by theta towards +x: p^s = p + e (sin, 0, cos), q keeps x = e sin
    # and z = 3, so d = (e sin theta)^2 exactly (far from the face's edges).
    t = math.radians(theta_deg)
    for e in (-0.2, 0.1, 0.35):
        d = box_distance([0.0, 0.5, 3.0], [math.sin(t), 0, math.cos(t)], offset=e)
        assert d == pytest.approx((e * math.sin(t)) ** 2, abs=1e-15)


def test_expected_sampled_distance_is_sigma_squared_sine_squared():
    # E[d] = sigma_s^2 sin^2 theta for a point on a face tilted by theta, checked by Monte Carlo on a
    # rotated, translated cuboid (the statement is frame independent).
    sigma, theta, n = 0.05, math.radians(30.0), 200_000
    c, q, _ = random_cuboids(1, 1, seed=1)
    s = torch.tensor([[[1.0, 1.2, 0.8]]], dtype=torch.float64)
    R = quaternion_to_rotation_matrix(q)[0, 0]
    point = c[0, 0] + R @ torch.tensor([0.1, -0.2, 0.8], dtype=torch.float64)  # on the +z face
    normal = R @ torch.tensor([math.sin(theta), 0.0, math.cos(theta)], dtype=torch.float64)
    p, nrm = point.expand(1, n, 3), normal.expand(1, n, 3)
    d = point_to_cuboid_distance(p, nrm, c, q, s, sigma_s=sigma, generator=gen(2))
    expected = sigma**2 * math.sin(theta) ** 2
    std_error = math.sqrt(2) * expected / math.sqrt(n)  # d = e^2 sin^2: Var = 2 sigma^4 sin^4
    assert abs(float(d.mean()) - expected) < 5 * std_error
    # The unsampled variant gives 0 for the same tilted point.
    assert float(point_to_cuboid_distance(p[:, :5], nrm[:, :5], c, q, s, sigma_s=0.0).abs().max()) < 1e-24


# ---------------------------------------------------------------------------------------------
# point_to_cuboid_distance: agreement with the reference, invariance, gradients
# ---------------------------------------------------------------------------------------------


def test_matches_world_space_reference():
    c, q, s = random_cuboids(2, 3, seed=3)
    p, nrm = random_points(2, 40, seed=4)
    e = 0.3 * torch.randn(2, 40, generator=gen(5), dtype=torch.float64)
    d = point_to_cuboid_distance(p, nrm, c, q, s, offsets=e)
    ref = reference_p2c(p.numpy(), nrm.numpy(), e.numpy(), c.numpy(), q.numpy(), s.numpy())
    np.testing.assert_allclose(d.numpy(), ref, rtol=1e-10, atol=1e-12)


def test_invariant_to_rotating_and_translating_everything():
    c, q, s = random_cuboids(2, 4, seed=6)
    p, nrm = random_points(2, 30, seed=7)
    e = 0.05 * torch.randn(2, 30, generator=gen(8), dtype=torch.float64)
    g = random_quaternions(generator=gen(9), dtype=torch.float64)
    G = quaternion_to_rotation_matrix(g)
    shift = torch.tensor([0.7, -2.0, 1.3], dtype=torch.float64)
    moved = (p @ G.T + shift, nrm @ G.T, c @ G.T + shift, quaternion_multiply(g, q), s)
    before = point_to_cuboid_distance(p, nrm, c, q, s, offsets=e)
    after = point_to_cuboid_distance(*moved, offsets=e)
    torch.testing.assert_close(after, before)
    torch.testing.assert_close(
        nearest_surface_distance(moved[0], *moved[2:]), nearest_surface_distance(p, c, q, s)
    )


def _away_from_kinks(p, nrm, e, c, q, s, margin=1e-3):
    """True when no face choice is near a tie and no clamp is near its bound (gradcheck-safe)."""
    R = quaternion_to_rotation_matrix(q)
    local_p = torch.einsum("bmji,bnmj->bnmi", R, p[:, :, None, :] - c[:, None])
    local_n = torch.einsum("bmji,bnj->bnmi", R, nrm)
    top2 = local_n.abs().topk(2, dim=-1).values
    ps = local_p + e[:, :, None, None] * local_n
    return bool((top2[..., 0] - top2[..., 1] > margin).all() and ((ps.abs() - s[:, None]).abs() > margin).all())


def test_gradcheck_float64():
    c, q, s = random_cuboids(2, 3, seed=10)
    p, nrm = random_points(2, 6, seed=11)
    e = 0.2 * torch.randn(2, 6, generator=gen(12), dtype=torch.float64)
    assert _away_from_kinks(p, nrm, e, c, q, s)
    inputs = tuple(t.clone().requires_grad_(True) for t in (p, nrm, c, q, s))
    assert torch.autograd.gradcheck(lambda *a: point_to_cuboid_distance(*a, offsets=e), inputs)
    assert torch.autograd.gradcheck(lambda *a: point_to_cuboid_distance(*a, sigma_s=0.0), inputs)


def test_gradient_flows_to_half_sizes_through_the_face_plane():
    # p above the +z face with normal +z: d = (p_z - s_z)^2, so dd/ds_z = -2 (p_z - s_z).
    c, q, s = (t.clone().requires_grad_(True) for t in BOX)
    p = torch.tensor([[[0.2, 0.1, 3.5]]], dtype=torch.float64)
    n = torch.tensor([[[0.0, 0.0, 1.0]]], dtype=torch.float64)
    point_to_cuboid_distance(p, n, c, q, s, sigma_s=0.0).sum().backward()
    torch.testing.assert_close(s.grad, torch.tensor([[[0.0, 0.0, -1.0]]], dtype=torch.float64))
    torch.testing.assert_close(c.grad, torch.tensor([[[0.0, 0.0, -1.0]]], dtype=torch.float64))


# ---------------------------------------------------------------------------------------------
# point_to_cuboid_distance: shapes, sampling, reproducibility
# ---------------------------------------------------------------------------------------------


def test_shapes_and_broadcasting():
    c, q, s = random_cuboids(3, 4, seed=13, dtype=torch.float32)
    p, nrm = random_points(3, 7, seed=14, dtype=torch.float32)
    e = 0.05 * torch.randn(3, 7, generator=gen(15))
    d = point_to_cuboid_distance(p, nrm, c, q, s, offsets=e)
    assert d.shape == (3, 7, 4) and d.dtype == torch.float32 and (d >= 0).all()
    mixed = point_to_cuboid_distance(p, nrm, c.double(), q.double(), s.double(), offsets=e)
    assert mixed.dtype == torch.float64  # dtypes are promoted, as torch does
    torch.testing.assert_close(mixed.float(), d)
    # One point cloud against three sets of cuboids, and one set of cuboids against three clouds.
    d1 = point_to_cuboid_distance(p[:1], nrm[:1], c, q, s, offsets=e[:1])
    torch.testing.assert_close(d1, point_to_cuboid_distance(p[:1].expand(3, 7, 3), nrm[:1].expand(3, 7, 3), c, q, s,
                                                            offsets=e[:1].expand(3, 7)))
    d2 = point_to_cuboid_distance(p, nrm, c[:1], q[:1], s[:1], offsets=e)
    torch.testing.assert_close(d2, point_to_cuboid_distance(p, nrm, c[:1].expand(3, 4, 3), q[:1].expand(3, 4, 4),
                                                            s[:1].expand(3, 4, 3), offsets=e))
    # Each pair only depends on its point and its cuboid.
    single = point_to_cuboid_distance(
        p[1:2, 2:3], nrm[1:2, 2:3], c[1:2, 3:], q[1:2, 3:], s[1:2, 3:], offsets=e[1:2, 2:3]
    )
    torch.testing.assert_close(single[0, 0, 0], d[1, 2, 3])


def test_sigma_zero_vs_positive_and_reproducible_offsets():
    c, q, s = random_cuboids(2, 3, seed=16)
    p, nrm = random_points(2, 50, seed=17)
    d0 = point_to_cuboid_distance(p, nrm, c, q, s, sigma_s=0.0)
    torch.testing.assert_close(d0, point_to_cuboid_distance(p, nrm, c, q, s, offsets=torch.zeros(2, 50)))
    d_a = point_to_cuboid_distance(p, nrm, c, q, s, sigma_s=0.1, generator=gen(18))
    d_b = point_to_cuboid_distance(p, nrm, c, q, s, sigma_s=0.1, generator=gen(18))
    assert torch.equal(d_a, d_b)
    assert not torch.equal(d_a, d0)
    assert not torch.equal(d_a, point_to_cuboid_distance(p, nrm, c, q, s, sigma_s=0.1, generator=gen(19)))
    # The documented recipe reproduces a generator-driven call exactly with explicit offsets.
    offsets = 0.1 * torch.randn(2, 50, generator=gen(18), dtype=torch.float64)
    assert torch.equal(point_to_cuboid_distance(p, nrm, c, q, s, offsets=offsets), d_a)


# ---------------------------------------------------------------------------------------------
# Bad inputs
# ---------------------------------------------------------------------------------------------


def _good():
    c, q, s = random_cuboids(2, 3, seed=20)
    p, nrm = random_points(2, 5, seed=21)
    return dict(points=p, normals=nrm, centers=c, quaternions=q, half_sizes=s)


@pytest.mark.parametrize(
    "name,value,match",
    [
        ("points", torch.zeros(5, 3), "points must have shape \\(B, N, 3\\)"),
        ("points", torch.zeros(2, 0, 3), "points is empty"),
        ("normals", torch.ones(2, 4, 3) / math.sqrt(3), "normals has shape .* they must match"),
        ("normals", torch.zeros(2, 5, 3), "normals contains zero-length"),
        ("normals", torch.ones(2, 5, 3), "normals must hold unit vectors"),
        ("points", torch.full((2, 5, 3), float("nan")), "points contains .* NaN"),
        ("quaternions", torch.zeros(2, 3, 4), "quaternions contains zero-length"),
        ("quaternions", torch.ones(2, 3, 4), "quaternions must hold unit vectors.*normalise"),
        ("half_sizes", -torch.ones(2, 3, 3), "half_sizes must be positive"),
        ("centers", torch.zeros(2, 4, 3), "size M"),
        ("centers", torch.zeros(3, 3, 3), "size B"),
    ],
)
def test_bad_inputs_raise_clear_errors(name, value, match):
    args = _good()
    args[name] = value.double()
    with pytest.raises(ValueError, match=match):
        point_to_cuboid_distance(**args)


def test_bad_sigma_offsets_and_batch():
    args = _good()
    with pytest.raises(ValueError, match="sigma_s must be a finite non-negative"):
        point_to_cuboid_distance(**args, sigma_s=-0.1)
    with pytest.raises(ValueError, match="offsets must have shape \\(B, N\\)"):
        point_to_cuboid_distance(**args, offsets=torch.zeros(2, 4))
    with pytest.raises(ValueError, match="offsets contains"):
        point_to_cuboid_distance(**args, offsets=torch.full((2, 5), float("inf")))
    c, q, s = random_cuboids(3, 3, seed=22)
    with pytest.raises(ValueError, match="batch size 2 but the cuboids have 3"):
        point_to_cuboid_distance(args["points"], args["normals"], c, q, s)


# ---------------------------------------------------------------------------------------------
# nearest_surface_distance
# ---------------------------------------------------------------------------------------------


def test_nearest_surface_analytic():
    points = torch.tensor([[[0.3, -0.5, 5.0], [2.0, 3.0, 4.0], [0.5, 0.5, 1.0], [0.0, 0.0, 0.0], [1.0, 0.3, 0.2]]],
                          dtype=torch.float64)
    d = nearest_surface_distance(points, *BOX)[0, :, 0]
    # Above a face: 2^2; beyond a corner: 1 + 1 + 1; inside: nearest face x = 1 at 0.5, so 0.25
    # (not 0); at the centre: nearest faces x = +-1, so 1; on a face: 0.
    torch.testing.assert_close(d, torch.tensor([4.0, 3.0, 0.25, 1.0, 0.0], dtype=torch.float64))


def test_nearest_surface_matches_reference_and_lower_bounds_p2c():
    c, q, s = random_cuboids(2, 3, seed=23)
    p, nrm = random_points(2, 40, seed=24, scale=1.0)
    d = nearest_surface_distance(p, c, q, s)
    ref = reference_nearest(p.numpy(), c.numpy(), q.numpy(), s.numpy())
    np.testing.assert_allclose(d.numpy(), ref, rtol=1e-10, atol=1e-12)
    # The normal-aware distance with sigma_s = 0 measures to one particular face: never smaller.
    assert (point_to_cuboid_distance(p, nrm, c, q, s, sigma_s=0.0) >= d - 1e-12).all()


def test_nearest_surface_gradcheck_and_shapes():
    c, q, s = random_cuboids(1, 2, seed=25)
    p = torch.tensor([[[0.05, 0.1, 0.02], [3.0, -1.0, 0.5], [0.4, 2.0, -1.0]]], dtype=torch.float64) + c[:, :1]
    inputs = tuple(t.clone().requires_grad_(True) for t in (p, c, q, s))
    assert torch.autograd.gradcheck(nearest_surface_distance, inputs)
    assert nearest_surface_distance(p.expand(4, 3, 3), c, q, s).shape == (4, 3, 2)
    with pytest.raises(ValueError, match="half_sizes must be positive"):
        nearest_surface_distance(p, c, q, -s)


# ---------------------------------------------------------------------------------------------
# Chamfer distances
# ---------------------------------------------------------------------------------------------


def brute_chamfer(a, b):
    d = ((a[:, :, None] - b[:, None]) ** 2).sum(-1)
    return d.min(2).values.mean(1), d.min(1).values.mean(1)


def test_chamfer_convention_by_hand():
    a = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    b = torch.tensor([[[0.0, 0.0, 0.0]]])
    total, ab, ba = chamfer_distance(a, b, return_directions=True)
    # a -> b: mean(0, 1) = 0.5 (squared distances); b -> a: 0. Sum of both directions: 0.5.
    torch.testing.assert_close(ab, torch.tensor([0.5]))
    torch.testing.assert_close(ba, torch.tensor([0.0]))
    torch.testing.assert_close(total, torch.tensor([0.5]))
    x, y = torch.tensor([[[1.0, 2.0, 3.0]]]), torch.tensor([[[2.0, 0.0, 3.0]]])
    torch.testing.assert_close(chamfer_distance(x, y), torch.tensor([10.0]))  # 2 * (1 + 4)
    assert float(chamfer_distance(a, a)) == 0.0


@pytest.mark.parametrize("chunk_size", [None, 1, 7])
def test_chamfer_matches_brute_force(chunk_size):
    g = gen(26)
    a = torch.randn(3, 50, 3, generator=g, dtype=torch.float64)
    b = torch.randn(3, 37, 3, generator=g, dtype=torch.float64) + 0.2
    total, ab, ba = chamfer_distance(a, b, chunk_size=chunk_size, return_directions=True)
    ref_ab, ref_ba = brute_chamfer(a, b)
    torch.testing.assert_close(ab, ref_ab)
    torch.testing.assert_close(ba, ref_ba)
    torch.testing.assert_close(total, ref_ab + ref_ba)
    # Broadcasting a batch of one.
    torch.testing.assert_close(chamfer_distance(a[:1], b), chamfer_distance(a[:1].expand(3, 50, 3), b))


def test_nearest_neighbors_and_chamfer_gradients():
    g = gen(27)
    a = torch.randn(2, 9, 3, generator=g, dtype=torch.float64)
    b = torch.randn(2, 6, 3, generator=g, dtype=torch.float64)
    dist, index = nearest_neighbors(a, b, chunk_size=4)
    full = ((a[:, :, None] - b[:, None]) ** 2).sum(-1)
    assert torch.equal(index, full.argmin(-1))
    torch.testing.assert_close(dist, full.min(-1).values)
    inputs = (a.clone().requires_grad_(True), b.clone().requires_grad_(True))
    assert torch.autograd.gradcheck(chamfer_distance, inputs)


def test_chamfer_errors():
    with pytest.raises(ValueError, match="a must have shape"):
        chamfer_distance(torch.zeros(4, 3), torch.zeros(1, 4, 3))
    with pytest.raises(ValueError, match="b is empty"):
        chamfer_distance(torch.zeros(1, 4, 3), torch.zeros(1, 0, 3))
    with pytest.raises(ValueError, match="batch sizes 2 .* and 3"):
        chamfer_distance(torch.zeros(2, 4, 3), torch.zeros(3, 4, 3))
    with pytest.raises(ValueError, match="chunk_size must be a positive integer"):
        chamfer_distance(torch.zeros(1, 4, 3), torch.zeros(1, 4, 3), chunk_size=0)


def test_chamfer_to_cuboids():
    c, q, s = random_cuboids(2, 3, seed=28)
    # The cloud drawn with the same generator state as the function's own samples: distance 0.
    points = sample_cuboid_surfaces(c, q, s, 200, generator=gen(29)).points
    total = chamfer_distance_to_cuboids(points, c, q, s, generator=gen(29))
    assert total.shape == (2,) and float(total.abs().max()) == 0.0
    # A single point at distance D from a tiny cuboid: both directions are about D^2.
    tiny = torch.full((1, 1, 3), 1e-4, dtype=torch.float64)
    unit_q = torch.tensor([[[1.0, 0.0, 0.0, 0.0]]], dtype=torch.float64)
    point = torch.tensor([[[0.0, 3.0, 4.0]]], dtype=torch.float64)
    total, p2c, c2p = chamfer_distance_to_cuboids(point, torch.zeros(1, 1, 3, dtype=torch.float64), unit_q, tiny,
                                                  n_samples=50, generator=gen(30), return_directions=True)
    torch.testing.assert_close(p2c, torch.tensor([25.0], dtype=torch.float64), rtol=1e-3, atol=0)
    torch.testing.assert_close(c2p, torch.tensor([25.0], dtype=torch.float64), rtol=1e-3, atol=0)


def test_chamfer_to_cuboids_exists_and_gradients():
    _, q, s = random_cuboids(1, 2, seed=31)
    c = torch.tensor([[[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]], dtype=torch.float64)
    points = sample_cuboid_surfaces(c[:, :1], q[:, :1], s[:, :1], 300, generator=gen(32)).points
    only_first = torch.tensor([[True, False]])
    with_far = chamfer_distance_to_cuboids(points, c, q, s, generator=gen(33))
    without_far = chamfer_distance_to_cuboids(points, c, q, s, exists=only_first, generator=gen(33))
    assert float(without_far) < 0.1 < 10.0 < float(with_far)  # the far cuboid's samples cost ~ 100 each
    inputs = tuple(t.clone().requires_grad_(True) for t in (c, q, s))
    assert torch.autograd.gradcheck(
        lambda c, q, s: chamfer_distance_to_cuboids(points[:, :20], c, q, s, n_samples=15, generator=gen(34)), inputs
    )
