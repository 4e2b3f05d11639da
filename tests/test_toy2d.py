"""Tests of cuboidlib.toy2d: 2D rectangles, boundary sampling, point-to-rectangle distances, fitting."""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402

from cuboidlib import toy2d, toy2d_measures  # noqa: E402


def one_rect(cx=0.0, cy=0.0, angle=0.0, hx=2.0, hy=1.0, dtype=torch.float32):
    """A single rectangle as (centers (1, 1, 2), angles (1, 1), half_sizes (1, 1, 2))."""
    return (
        torch.tensor([[[cx, cy]]], dtype=dtype),
        torch.tensor([[angle]], dtype=dtype),
        torch.tensor([[[hx, hy]]], dtype=dtype),
    )


def random_rects(B, K, generator, dtype=torch.float64):
    centers = torch.randn(B, K, 2, generator=generator, dtype=dtype)
    angles = (torch.rand(B, K, generator=generator, dtype=dtype) - 0.5) * 2 * math.pi
    half_sizes = 0.3 + torch.rand(B, K, 2, generator=generator, dtype=dtype)
    return centers, angles, half_sizes


def random_unit(shape, generator, dtype=torch.float64):
    v = torch.randn(*shape, 2, generator=generator, dtype=dtype)
    return v / v.norm(dim=-1, keepdim=True)


def rigid(points, angle, shift):
    """Rotate (B, N, 2) points by angle about the origin, then translate by shift (2,)."""
    R = toy2d.rotation_2d(torch.tensor(angle, dtype=points.dtype))
    return points @ R.T + shift


# ------------------------------------------------------------------------------------------------
# rotation and corners


def test_rotation_2d_is_a_proper_rotation():
    angles = torch.tensor([0.0, 0.3, -2.0, math.pi / 2], dtype=torch.float64)
    R = toy2d.rotation_2d(angles)
    assert R.shape == (4, 2, 2)
    eye = torch.eye(2, dtype=torch.float64).expand(4, 2, 2)
    torch.testing.assert_close(R @ R.transpose(-1, -2), eye)
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(4, dtype=torch.float64))
    # a quarter turn maps the x axis onto the y axis (counter-clockwise)
    x_axis, y_axis = torch.eye(2, dtype=torch.float64)
    torch.testing.assert_close(R[3] @ x_axis, y_axis)


def test_rectangle_corners_axis_aligned_and_rotated():
    corners = toy2d.rectangle_corners(*one_rect(cx=1.0, cy=-1.0, hx=2.0, hy=0.5))
    expected = torch.tensor([[3.0, -1.5], [3.0, -0.5], [-1.0, -0.5], [-1.0, -1.5]])
    torch.testing.assert_close(corners[0, 0], expected)
    # a quarter turn about the centre: local +x now points along world +y
    corners = toy2d.rectangle_corners(*one_rect(angle=math.pi / 2, hx=2.0, hy=0.5))
    expected = torch.tensor([[0.5, 2.0], [-0.5, 2.0], [-0.5, -2.0], [0.5, -2.0]])
    torch.testing.assert_close(corners[0, 0], expected, atol=1e-6, rtol=0)


def test_rectangle_corners_are_counter_clockwise_with_the_right_area():
    g = torch.Generator().manual_seed(0)
    centers, angles, half = random_rects(3, 4, g)
    c = toy2d.rectangle_corners(centers, angles, half)
    x, y = c[..., 0], c[..., 1]
    signed_area = 0.5 * (x * y.roll(-1, dims=-1) - x.roll(-1, dims=-1) * y).sum(dim=-1)
    torch.testing.assert_close(signed_area, 4 * half[..., 0] * half[..., 1])


# ------------------------------------------------------------------------------------------------
# boundary sampling


def local_coords(points, centers, angles):
    """Points (..., 2) into the frame of ONE rectangle given by centers (2,), angle ()."""
    R = toy2d.rotation_2d(angles)
    return (points - centers) @ R


def test_sample_rectangle_boundary_points_lie_on_the_boundary_with_outward_unit_normals():
    g = torch.Generator().manual_seed(1)
    centers, angles, half = random_rects(2, 3, g, dtype=torch.float32)
    pts, nrm = toy2d.sample_rectangle_boundary(centers, angles, half, 500, generator=g)
    assert pts.shape == (2, 3, 500, 2) and nrm.shape == (2, 3, 500, 2)
    torch.testing.assert_close(nrm.norm(dim=-1), torch.ones(2, 3, 500))
    for b in range(2):
        for k in range(3):
            loc = local_coords(pts[b, k], centers[b, k], angles[b, k])
            h = half[b, k]
            nloc = nrm[b, k] @ toy2d.rotation_2d(angles[b, k])
            assert bool((loc.abs() <= h + 1e-4).all())
            # the local normal is one of the four edge normals ...
            torch.testing.assert_close(nloc.abs().sum(-1), torch.ones(500), atol=1e-5, rtol=0)
            assert bool(((nloc.abs() < 1e-5) | ((nloc.abs() - 1).abs() < 1e-5)).all())
            # ... and the point lies on that edge: its coordinate along the normal is the half size
            torch.testing.assert_close((nloc * loc).sum(-1), (nloc.abs() * h).sum(-1), atol=1e-4, rtol=0)


def test_sample_rectangle_boundary_is_uniform_by_length():
    g = torch.Generator().manual_seed(2)
    n = 40000
    pts, nrm = toy2d.sample_rectangle_boundary(*one_rect(hx=2.0, hy=0.5), n, generator=g)
    # the two +-x edges have length 2 * 2 * 0.5 = 2 of the perimeter 10
    share_x = float((nrm[0, 0, :, 0].abs() > 0.5).float().mean())
    assert abs(share_x - 0.2) < 3 * math.sqrt(0.2 * 0.8 / n)
    # along the long edges the position is uniform on [-2, 2]: mean 0, variance 4/3
    top = pts[0, 0][nrm[0, 0, :, 1] > 0.5, 0]
    assert abs(float(top.mean())) < 0.05
    assert abs(float(top.var()) - 4 / 3) < 0.05


def in_l(x):
    """Closed membership of the L = [-1, 0] x [-1, 1] u [0, 1] x [-1, 0], written out by hand."""
    a = (x[:, 0] >= -1) & (x[:, 0] <= 0) & (x[:, 1].abs() <= 1)
    b = (x[:, 0] >= 0) & (x[:, 0] <= 1) & (x[:, 1] >= -1) & (x[:, 1] <= 0)
    return a | b


@pytest.mark.parametrize("phi, shift", [(0.0, (0.0, 0.0)), (0.9, (2.0, -1.0))])
def test_union_boundary_of_an_l_drops_interior_points_and_is_uniform(phi, shift):
    g = torch.Generator().manual_seed(3)
    parts = toy2d.l_shape(torch.float64)
    assert torch.equal(parts.centers, torch.tensor([[[-0.5, 0.0], [0.5, -0.5]]], dtype=torch.float64))
    shift = torch.tensor(shift, dtype=torch.float64)
    R = toy2d.rotation_2d(torch.tensor(phi, dtype=torch.float64))
    moved = (rigid(parts.centers, phi, shift), parts.angles + phi, parts.half_sizes)
    n = 20000
    pts, nrm, labels = toy2d.sample_union_boundary(*moved, n, generator=g)
    assert pts.shape == (1, n, 2) and nrm.shape == (1, n, 2) and labels.shape == (1, n)
    # back in the L's own frame
    p, q = (pts[0] - shift) @ R, nrm[0] @ R
    # no point on the glued edge x = 0, y in (-1, 0)
    glued = (p[:, 0].abs() < 1e-6) & (p[:, 1] < -1e-3) & (p[:, 1] > -1 + 1e-3)
    assert int(glued.sum()) == 0
    # every point is on the boundary of the union: a step out along the normal leaves it, a step in stays
    assert not bool(in_l(p + 1e-3 * q).any())
    assert bool(in_l(p - 1e-3 * q).all())
    # the L's outline has length 8; the +x-facing edges (x = 0 for y in (0, 1) and x = 1) have length 2
    share = float((q[:, 0] > 0.5).float().mean())
    assert abs(share - 0.25) < 3 * math.sqrt(0.25 * 0.75 / n)
    # labels name the part whose edge the point lies on
    assert bool((labels[0][p[:, 0] > 1e-6] == 1).all()) and bool((labels[0][p[:, 0] < -1e-6] == 0).all())
    # the same generator seed gives the same sample
    again = toy2d.sample_union_boundary(*moved, n, generator=torch.Generator().manual_seed(3))
    assert torch.equal(again[0], pts) and torch.equal(again[2], labels)


def test_union_boundary_keeps_one_copy_of_collinear_shared_edges():
    g = torch.Generator().manual_seed(4)
    # two overlapping rectangles with collinear bottom and top edges; the union is [0, 3] x [0, 1]
    parts = toy2d.boxes_to_rectangles([(0.0, 2.0, 0.0, 1.0), (1.0, 3.0, 0.0, 1.0)], torch.float32)
    n = 20000
    pts, nrm, _ = toy2d.sample_union_boundary(*parts, n, generator=g)
    share_bottom = float((nrm[0, :, 1] < -0.5).float().mean())
    # the bottom edge has length 3 of the perimeter 8 (keeping both copies would give 4/10)
    assert abs(share_bottom - 3 / 8) < 3 * math.sqrt(3 / 8 * 5 / 8 / n)
    # the inner vertical edges (x = 1 of the second part, x = 2 of the first) are not on the outline
    inner = (pts[0, :, 0] > 1e-3) & (pts[0, :, 0] < 3 - 1e-3) & ((pts[0, :, 1] - 0.5).abs() < 0.49)
    assert not bool(inner.any())
    # and the bottom edge is covered uniformly: mean x = 1.5, variance 3^2 / 12
    bottom_x = pts[0, nrm[0, :, 1] < -0.5, 0]
    assert abs(float(bottom_x.mean()) - 1.5) < 0.05 and abs(float(bottom_x.var()) - 0.75) < 0.05


@pytest.mark.parametrize(
    "make, parts", [(toy2d.rectangle_shape, 1), (toy2d.l_shape, 2), (toy2d.t_shape, 2), (toy2d.u_shape, 3)]
)
def test_preset_shapes(make, parts):
    shape = make()
    assert shape.centers.shape == (1, parts, 2)
    assert shape.angles.shape == (1, parts)
    assert shape.half_sizes.shape == (1, parts, 2)
    assert bool((shape.half_sizes > 0).all())
    corners = toy2d.rectangle_corners(*shape)
    assert bool((corners.abs() <= 1 + 1e-6).all())
    pts, nrm, labels = toy2d.sample_union_boundary(*shape, 300, generator=torch.Generator().manual_seed(0))
    assert pts.shape == (1, 300, 2)
    # every part owns some boundary points
    assert set(labels[0].tolist()) == set(range(parts))


def test_presets_parts_do_not_overlap():
    for make in (toy2d.l_shape, toy2d.t_shape, toy2d.u_shape):
        shape = make(dtype=torch.float64)
        K = shape.centers.shape[1]
        single = [toy2d.Rectangles(*(t[:, k : k + 1] for t in shape)) for k in range(K)]
        total = sum(float(4 * s.half_sizes.prod()) for s in single)
        # the union area on a fine grid equals the sum of the part areas
        assert abs(_grid_area(shape) - total) < 0.03


def _grid_area(rects, resolution=400, extent=1.5):
    axis = (torch.arange(resolution, dtype=torch.float64) + 0.5) / resolution * 2 * extent - extent
    gy, gx = torch.meshgrid(axis, axis, indexing="ij")
    grid = torch.stack([gx, gy], -1).reshape(1, -1, 2)
    inside = toy2d.inside_rectangles(grid, *(t.to(torch.float64) for t in rects)).any(-1)
    return float(inside.sum()) * (2 * extent / resolution) ** 2


# ------------------------------------------------------------------------------------------------
# distances


def box_sdf_squared(points, centers, angles, half_sizes):
    """Independent reference for the nearest-edge distance of one rectangle (loop-free, classic box SDF).

    Outside: |max(|x| - h, 0)|^2. Inside: (min_i (h_i - |x_i|))^2.
    """
    loc = local_coords(points, centers, angles)
    q = loc.abs() - half_sizes
    outside = q.clamp_min(0).pow(2).sum(-1)
    inside = (-q).amin(-1).pow(2)
    return torch.where((q <= 0).all(-1), inside, outside)


def test_nearest_edge_distance_analytic_cases():
    rect = one_rect(hx=2.0, hy=1.0)
    pts = torch.tensor([[[3.0, 0.0], [0.0, 0.5], [3.0, 2.0], [2.0, 0.3], [-2.5, -1.5], [0.0, 0.0]]])
    d = toy2d.nearest_edge_distance(pts, *rect)
    assert d.shape == (1, 6, 1)
    expected = torch.tensor([1.0, 0.25, 2.0, 0.0, 0.5, 1.0])
    torch.testing.assert_close(d[0, :, 0], expected)


def test_nearest_edge_distance_matches_the_box_formula():
    g = torch.Generator().manual_seed(5)
    centers, angles, half = random_rects(2, 3, g)
    pts = 2 * torch.randn(2, 50, 2, generator=g, dtype=torch.float64)
    d = toy2d.nearest_edge_distance(pts, centers, angles, half)
    for b in range(2):
        for k in range(3):
            torch.testing.assert_close(d[b, :, k], box_sdf_squared(pts[b], centers[b, k], angles[b, k], half[b, k]))


def world_normal_aware(points, normals, offsets, centers, angles, half_sizes):
    """Independent reference: works in world coordinates with the corners of each rectangle."""
    corners = toy2d.rectangle_corners(centers, angles, half_sizes)  # (B, K, 4, 2)
    B, N, _ = points.shape
    K = centers.shape[1]
    out = torch.empty(B, N, K, dtype=points.dtype)
    for b in range(B):
        for k in range(K):
            a = corners[b, k]
            bnd = a.roll(-1, dims=0)
            edge_dir = (bnd - a) / (bnd - a).norm(dim=-1, keepdim=True)
            edge_normal = torch.stack([edge_dir[:, 1], -edge_dir[:, 0]], -1)  # clockwise quarter turn = outward
            for n in range(N):
                e = int((edge_normal @ normals[b, n]).argmax())
                ps = points[b, n] + offsets[b, n] * normals[b, n]
                seg = bnd[e] - a[e]
                t = ((ps - a[e]) @ seg / (seg @ seg)).clamp(0, 1)
                q = a[e] + t * seg
                out[b, n, k] = ((q - points[b, n]) ** 2).sum()
    return out


def test_normal_aware_distance_analytic_cases():
    rect = one_rect(hx=2.0, hy=1.0)
    pts = torch.tensor([[[2.0, 0.3], [2.0, 0.3], [3.0, 2.0], [0.0, 0.5]]])
    nrm = torch.tensor([[[1.0, 0.0], [-1.0, 0.0], [1.0, 0.0], [0.0, -1.0]]])
    d = toy2d.normal_aware_distance(pts, nrm, *rect, sigma_s=0.0)
    # on the +x edge with its normal: 0; same point with the opposite normal: distance to the -x edge;
    # outside the corner with normal +x: to the clamped end of the +x edge (2, 1); inside with normal -y:
    # to the bottom edge
    expected = torch.tensor([0.0, 16.0, 2.0, 2.25])
    torch.testing.assert_close(d[0, :, 0], expected)


def test_normal_aware_distance_zero_only_with_matching_normals_and_sampling_along_a_matching_normal_is_free():
    rect = one_rect(hx=2.0, hy=1.0)
    pts = torch.tensor([[[2.0, 0.3], [-1.0, 1.0]]])
    nrm = torch.tensor([[[1.0, 0.0], [0.0, 1.0]]])
    offsets = torch.tensor([[0.7, -0.4]])
    d = toy2d.normal_aware_distance(pts, nrm, *rect, offsets=offsets)
    torch.testing.assert_close(d, torch.zeros(1, 2, 1))
    # the nearest-edge distance cannot tell the normal apart
    flipped = toy2d.nearest_edge_distance(pts, *rect)
    torch.testing.assert_close(flipped, torch.zeros(1, 2, 1))
    assert float(toy2d.normal_aware_distance(pts, -nrm, *rect, sigma_s=0.0).min()) > 1.0


def test_normal_aware_distance_matches_a_world_space_reference():
    g = torch.Generator().manual_seed(6)
    centers, angles, half = random_rects(2, 3, g)
    pts = 2 * torch.randn(2, 20, 2, generator=g, dtype=torch.float64)
    nrm = random_unit((2, 20), g)
    offsets = 0.3 * torch.randn(2, 20, generator=g, dtype=torch.float64)
    d = toy2d.normal_aware_distance(pts, nrm, centers, angles, half, offsets=offsets)
    torch.testing.assert_close(d, world_normal_aware(pts, nrm, offsets, centers, angles, half))


def test_best_matching_edge():
    angles = torch.tensor([[0.0, math.pi / 2]])
    nrm = torch.tensor([[[1.0, 0.0], [0.0, 1.0], [-0.6, -0.8]]])
    edge = toy2d.best_matching_edge(nrm, angles)
    # rectangle 0 is axis aligned; rectangle 1 is turned a quarter, so its local +x axis is world +y
    # (-0.6, -0.8) is (-0.8, 0.6) in the turned frame: closest to its -x edge
    assert edge.tolist() == [[[0, 3], [1, 0], [3, 2]]]


@pytest.mark.parametrize("theta", [0.2, 0.5, 0.75])
def test_expected_sampled_distance_is_sigma_squared_sin_squared_theta(theta):
    """A point on the +x edge whose normal is tilted by theta: E[d] = sigma_s^2 sin^2(theta).

    theta < pi/4, so the +x edge is still the best-matching one.
    """
    n = 40000
    sigma_s = 0.05
    rect = one_rect(hx=2.0, hy=1.0, dtype=torch.float64)
    pts = torch.tensor([2.0, 0.0], dtype=torch.float64).expand(1, n, 2)
    nrm = torch.tensor([math.cos(theta), math.sin(theta)], dtype=torch.float64).expand(1, n, 2)
    d = toy2d.normal_aware_distance(pts, nrm, *rect, sigma_s=sigma_s, generator=torch.Generator().manual_seed(7))
    expected = sigma_s**2 * math.sin(theta) ** 2
    # the mean of e^2 over n draws has relative standard deviation sqrt(2 / n) (0.7 %)
    assert abs(float(d.mean()) / expected - 1) < 5 * math.sqrt(2 / n)


def test_sampling_offsets_are_shared_by_all_rectangles_and_reproducible():
    g = torch.Generator().manual_seed(8)
    centers, angles, half = random_rects(1, 1, g, dtype=torch.float32)
    twice = tuple(torch.cat([t, t], dim=1) for t in (centers, angles, half))
    pts = torch.randn(1, 30, 2, generator=g)
    nrm = random_unit((1, 30), g, dtype=torch.float32)
    d = toy2d.normal_aware_distance(pts, nrm, *twice, sigma_s=0.2, generator=torch.Generator().manual_seed(9))
    torch.testing.assert_close(d[..., 0], d[..., 1])
    again = toy2d.normal_aware_distance(pts, nrm, *twice, sigma_s=0.2, generator=torch.Generator().manual_seed(9))
    assert torch.equal(d, again)
    # the same draw passed as explicit offsets gives the same distances
    offsets = 0.2 * torch.randn(1, 30, generator=torch.Generator().manual_seed(9))
    torch.testing.assert_close(toy2d.normal_aware_distance(pts, nrm, *twice, offsets=offsets), d)
    # sigma_s = 0 is the unsampled variant
    torch.testing.assert_close(
        toy2d.normal_aware_distance(pts, nrm, *twice, sigma_s=0.0),
        toy2d.normal_aware_distance(pts, nrm, *twice, offsets=torch.zeros(1, 30)),
    )


def test_distances_are_invariant_under_rotating_and_translating_everything():
    g = torch.Generator().manual_seed(10)
    centers, angles, half = random_rects(2, 3, g)
    pts = 2 * torch.randn(2, 40, 2, generator=g, dtype=torch.float64)
    nrm = random_unit((2, 40), g)
    offsets = 0.2 * torch.randn(2, 40, generator=g, dtype=torch.float64)
    phi, shift = 0.7, torch.tensor([1.5, -3.0], dtype=torch.float64)
    R = toy2d.rotation_2d(torch.tensor(phi, dtype=torch.float64))
    moved = (rigid(pts, phi, shift), nrm @ R.T, rigid(centers, phi, shift), angles + phi, half)
    d1 = toy2d.nearest_edge_distance(pts, centers, angles, half)
    d2 = toy2d.nearest_edge_distance(moved[0], *moved[2:])
    torch.testing.assert_close(d1, d2)
    n1 = toy2d.normal_aware_distance(pts, nrm, centers, angles, half, offsets=offsets)
    n2 = toy2d.normal_aware_distance(*moved, offsets=offsets)
    torch.testing.assert_close(n1, n2)


def test_distances_work_in_float32_and_float64_and_broadcast_over_batch():
    g = torch.Generator().manual_seed(11)
    centers, angles, half = random_rects(3, 2, g)
    pts = torch.randn(3, 7, 2, generator=g, dtype=torch.float64)
    nrm = random_unit((3, 7), g)
    d64 = toy2d.nearest_edge_distance(pts, centers, angles, half)
    d32 = toy2d.nearest_edge_distance(pts.float(), centers.float(), angles.float(), half.float())
    assert d64.dtype == torch.float64 and d32.dtype == torch.float32 and d64.shape == (3, 7, 2)
    torch.testing.assert_close(d32, d64.float(), atol=1e-5, rtol=1e-4)
    # each batch element is computed independently
    single = toy2d.normal_aware_distance(pts[1:2], nrm[1:2], centers[1:2], angles[1:2], half[1:2], sigma_s=0.0)
    full = toy2d.normal_aware_distance(pts, nrm, centers, angles, half, sigma_s=0.0)
    torch.testing.assert_close(full[1:2], single)


def test_gradcheck_nearest_edge_distance():
    g = torch.Generator().manual_seed(12)
    centers, angles, half = random_rects(1, 2, g)
    pts = 1.5 * torch.randn(1, 6, 2, generator=g, dtype=torch.float64)
    inputs = tuple(t.clone().requires_grad_() for t in (pts, centers, angles, half))
    assert torch.autograd.gradcheck(toy2d.nearest_edge_distance, inputs)


def test_gradcheck_normal_aware_distance():
    g = torch.Generator().manual_seed(13)
    centers, angles, half = random_rects(1, 2, g)
    pts = 1.5 * torch.randn(1, 6, 2, generator=g, dtype=torch.float64)
    nrm = random_unit((1, 6), g)
    offsets = 0.3 * torch.randn(1, 6, generator=g, dtype=torch.float64)
    inputs = tuple(t.clone().requires_grad_() for t in (pts, centers, angles, half, offsets))

    def f(p, c, a, h, o):
        return toy2d.normal_aware_distance(p, nrm, c, a, h, offsets=o)

    assert torch.autograd.gradcheck(f, inputs)


# ------------------------------------------------------------------------------------------------
# bad inputs


def test_bad_inputs_raise_clear_errors():
    rect = one_rect()
    pts = torch.zeros(1, 4, 2)
    nrm = torch.tensor([[1.0, 0.0]]).expand(1, 4, 2)
    with pytest.raises(ValueError, match="points must have shape"):
        toy2d.nearest_edge_distance(torch.zeros(1, 4, 3), *rect)
    with pytest.raises(ValueError, match="points is empty"):
        toy2d.nearest_edge_distance(torch.zeros(1, 0, 2), *rect)
    with pytest.raises(ValueError, match="centers contains 1 NaN"):
        toy2d.nearest_edge_distance(pts, torch.tensor([[[float("nan"), 0.0]]]), *rect[1:])
    with pytest.raises(ValueError, match="half_sizes must be non-negative"):
        toy2d.nearest_edge_distance(pts, *rect[:2], torch.tensor([[[1.0, -1.0]]]))
    with pytest.raises(ValueError, match="size B"):
        toy2d.nearest_edge_distance(torch.zeros(2, 4, 2), *rect)
    with pytest.raises(ValueError, match="size K"):
        toy2d.nearest_edge_distance(pts, rect[0], torch.zeros(1, 2), rect[2])
    with pytest.raises(ValueError, match="zero-length"):
        toy2d.normal_aware_distance(pts, torch.zeros(1, 4, 2), *rect)
    with pytest.raises(ValueError, match="normals must hold unit vectors"):
        toy2d.normal_aware_distance(pts, 2 * nrm, *rect)
    with pytest.raises(ValueError, match="offsets must have shape"):
        toy2d.normal_aware_distance(pts, nrm, *rect, offsets=torch.zeros(1, 3))
    with pytest.raises(ValueError, match="sigma_s must be a finite non-negative"):
        toy2d.normal_aware_distance(pts, nrm, *rect, sigma_s=-0.1)
    with pytest.raises(ValueError, match="n must be a positive integer"):
        toy2d.sample_rectangle_boundary(*rect, 0)
    with pytest.raises(ValueError, match="half_sizes must be positive"):
        toy2d.sample_union_boundary(*rect[:2], torch.tensor([[[1.0, 0.0]]]), 10)
    with pytest.raises(TypeError, match="centers must be a tensor"):
        toy2d.rectangle_corners("abc", *rect[1:])
    with pytest.raises(ValueError, match="points must have shape"):
        toy2d.inside_rectangles(torch.zeros(1, 3, 3), *rect)
    with pytest.raises(ValueError, match="normals must hold unit vectors"):
        toy2d.best_matching_edge(2 * nrm, rect[1])
    with pytest.raises(ValueError, match="step must be in"):
        toy2d.sample_union_boundary(*rect, 10, step=0.5)


def test_fit_rectangles_rejects_bad_arguments():
    pts, nrm, _ = toy2d.sample_union_boundary(*toy2d.rectangle_shape(), 32, generator=torch.Generator().manual_seed(0))
    with pytest.raises(ValueError, match='distance must be "nearest" or "normal"'):
        toy2d.fit_rectangles(pts, nrm, 2, distance="closest")
    with pytest.raises(ValueError, match='assignment must be "min" or "soft"'):
        toy2d.fit_rectangles(pts, nrm, 2, assignment="hard")
    with pytest.raises(ValueError, match="normals .* are required"):
        toy2d.fit_rectangles(pts, None, 2, distance="normal")
    with pytest.raises(ValueError, match="K must be a positive integer"):
        toy2d.fit_rectangles(pts, nrm, 0)
    with pytest.raises(ValueError, match="steps must be a positive integer"):
        toy2d.fit_rectangles(pts, nrm, 2, steps=0)
    with pytest.raises(ValueError, match="compactness_weight must be a finite non-negative"):
        toy2d.fit_rectangles(pts, nrm, 2, compactness_weight=-1.0)
    with pytest.raises(ValueError, match="init_size must be"):
        toy2d.fit_rectangles(pts, nrm, 2, init_size=(0.5, 0.1))
    with pytest.raises(ValueError, match="size N"):
        toy2d.fit_rectangles(pts, nrm[:, :10], 2)
    with pytest.raises(ValueError, match="points contains 1 NaN"):
        bad = pts.clone()
        bad[0, 3, 1] = float("nan")
        toy2d.fit_rectangles(bad, nrm, 2)


# ------------------------------------------------------------------------------------------------
# fitting


@pytest.fixture(scope="module")
def rectangle_points():
    pts, nrm, _ = toy2d.sample_union_boundary(*toy2d.rectangle_shape(), 128, generator=torch.Generator().manual_seed(0))
    return pts.repeat(4, 1, 1), nrm.repeat(4, 1, 1)  # four random starts of the same shape


def test_fit_rectangles_outputs_and_determinism(rectangle_points):
    pts, nrm = rectangle_points
    a = toy2d.fit_rectangles(pts, nrm, 3, steps=20, seed=5)
    b = toy2d.fit_rectangles(pts, nrm, 3, steps=20, seed=5)
    c = toy2d.fit_rectangles(pts, nrm, 3, steps=20, seed=6)
    for x, y in zip(a, b):
        assert torch.equal(x, y)
    assert not torch.equal(a.centers, c.centers)
    assert a.centers.shape == (4, 3, 2) and a.angles.shape == (4, 3) and a.half_sizes.shape == (4, 3, 2)
    assert a.W.shape == (4, 128, 3) and a.portions.shape == (4, 3) and a.history.shape == (20, 4)
    torch.testing.assert_close(a.W.sum(-1), torch.ones(4, 128))
    torch.testing.assert_close(a.portions, a.W.mean(1))
    assert bool((a.half_sizes > 0).all())
    # the four batch elements start from different random rectangles
    assert not torch.equal(a.centers[0], a.centers[1])
    hard = toy2d.fit_rectangles(pts, None, 3, distance="nearest", assignment="min", steps=5)
    assert set(hard.W.unique().tolist()) <= {0.0, 1.0}


def test_every_method_starts_from_the_same_random_rectangles(rectangle_points):
    pts, nrm = rectangle_points
    frozen = dict(steps=2, lr=0.0, logit_lr=0.0, bias_lr=0.0, seed=11)
    starts = [
        toy2d.fit_rectangles(pts, nrm, 3, distance=d, assignment=a, sigma_s=s, **frozen)
        for d, a, s in (
            ("nearest", "min", 0.0), ("normal", "soft", 0.0), ("normal", "soft", 0.3), ("nearest", "soft", 0.0)
        )
    ]
    for other in starts[1:]:
        assert torch.equal(starts[0].centers, other.centers)
        assert torch.equal(starts[0].angles, other.angles)
        torch.testing.assert_close(starts[0].half_sizes, other.half_sizes)
    # the start lies in the bounding box of the points with half sizes in init_size x 1 (half extent = 1)
    assert bool((starts[0].centers.abs() <= torch.tensor([1.0, 0.6]) + 1e-6).all())
    assert bool((starts[0].half_sizes >= 0.1 - 1e-6).all() and (starts[0].half_sizes <= 0.4 + 1e-6).all())


def test_small_fit_normal_soft_finds_one_rectangle_nearest_min_finds_several(rectangle_points):
    pts, nrm = rectangle_points
    truth = toy2d.Rectangles(*(t.repeat(4, *([1] * (t.dim() - 1))) for t in toy2d.rectangle_shape()))
    soft = toy2d.fit_rectangles(pts, nrm, 4, distance="normal", assignment="soft", steps=300, seed=0)
    used = toy2d_measures.used_rectangles(soft.portions)
    assert int((used.sum(-1) == 1).sum()) >= 3  # one rectangle for (almost) every start
    assert bool((toy2d_measures.union_iou(soft.rectangles, truth, used) > 0.95).all())
    assert bool((toy2d_measures.thin_fraction(soft.half_sizes, used, 0.6) == 0).all())
    hard = toy2d.fit_rectangles(pts, nrm, 4, distance="nearest", assignment="min", steps=300, seed=0)
    used = toy2d_measures.used_rectangles(hard.portions)
    # the one-sided loss reaches ~0 although no start ends with a single rectangle
    assert bool((hard.history[-1] < 1e-3).all())
    assert bool((used.sum(-1) >= 2).all())
    assert float(toy2d_measures.union_iou(hard.rectangles, truth, used).mean()) < 0.95
    assert float(toy2d_measures.thin_fraction(hard.half_sizes, used, 0.6).mean()) > 0


# ------------------------------------------------------------------------------------------------
# measures and drawing


def test_used_rectangles_aspect_ratios_and_thin_fraction():
    used = toy2d_measures.used_rectangles(torch.tensor([[0.5, 0.04, 0.46]]))
    assert used.tolist() == [[True, False, True]]
    half = torch.tensor([[[0.05, 1.0], [0.5, 0.5], [0.01, 0.3]], [[0.2, 0.4], [0.3, 0.3], [1.0, 1.0]]])
    torch.testing.assert_close(toy2d_measures.aspect_ratios(half), torch.tensor([[20.0, 1.0, 30.0], [2.0, 1.0, 1.0]]))
    used = torch.tensor([[True, True, False], [True, True, False]])
    # thickness = 2 * short half size: 0.1, 1.0, (0.02 unused) | 0.4, 0.6
    torch.testing.assert_close(toy2d_measures.thin_fraction(half, used, 0.2), torch.tensor([0.5, 0.0]))
    torch.testing.assert_close(toy2d_measures.thin_fraction(half, used, torch.tensor([0.2, 0.5])), torch.tensor([0.5, 0.5]))
    torch.testing.assert_close(toy2d_measures.thin_fraction(half, torch.zeros(2, 3, dtype=torch.bool), 0.2), torch.zeros(2))
    with pytest.raises(ValueError, match="half_sizes must be positive"):
        toy2d_measures.aspect_ratios(torch.zeros(1, 1, 2))
    with pytest.raises(ValueError, match="used must have shape"):
        toy2d_measures.thin_fraction(half, used[:, :2], 0.2)


def test_union_iou_known_overlaps():
    unit = toy2d.boxes_to_rectangles([(0.0, 1.0, 0.0, 1.0)])
    shifted = toy2d.boxes_to_rectangles([(0.5, 1.5, 0.0, 1.0)])
    far = toy2d.boxes_to_rectangles([(-1.4, -1.0, -1.4, -1.0)])
    assert float(toy2d_measures.union_iou(unit, unit)) == pytest.approx(1.0)
    assert float(toy2d_measures.union_iou(unit, shifted, resolution=300)) == pytest.approx(1 / 3, abs=0.01)
    assert float(toy2d_measures.union_iou(unit, far)) == 0.0
    # a rectangle masked out as unused does not count
    both = toy2d.Rectangles(*(torch.cat([a, b], dim=1) for a, b in zip(unit, far)))
    assert float(toy2d_measures.union_iou(both, unit, used_a=torch.tensor([[True, False]]))) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="same batch size"):
        toy2d_measures.union_iou(unit, toy2d.Rectangles(*(t.repeat(2, *([1] * (t.dim() - 1))) for t in unit)))


def test_orientation_error_is_modulo_a_quarter_turn():
    angles = torch.tensor([[0.0, math.pi / 2, math.pi / 8, -math.pi / 8, math.pi / 4 + 0.1]], dtype=torch.float64)
    expected = [0.0, 0.0, math.pi / 8, math.pi / 8, math.pi / 4 - 0.1]
    for k, e in enumerate(expected):
        used = torch.zeros(1, 5, dtype=torch.bool)
        used[0, k] = True
        assert float(toy2d_measures.orientation_error(angles, used)) == pytest.approx(e, abs=1e-9)
    both = torch.tensor([[True, False, True, False, False]])
    assert float(toy2d_measures.orientation_error(angles, both)) == pytest.approx(math.pi / 16)
    assert float(toy2d_measures.orientation_error(angles + 0.3, both, reference=0.3)) == pytest.approx(math.pi / 16)


def test_stack_rectangles_pads_with_absent_rectangles():
    rects, present = toy2d.stack_rectangles([toy2d.l_shape(), toy2d.u_shape(), toy2d.rectangle_shape()])
    assert rects.centers.shape == (3, 3, 2) and rects.angles.shape == (3, 3) and rects.half_sizes.shape == (3, 3, 2)
    assert present.tolist() == [[True, True, False], [True, True, True], [True, False, False]]
    torch.testing.assert_close(rects.half_sizes[0, :2], toy2d.l_shape().half_sizes[0])
    assert float(rects.half_sizes[2, 1:].abs().sum()) == 0.0
    with pytest.raises(ValueError, match="must hold one shape"):
        toy2d.stack_rectangles([toy2d.Rectangles(*(t.repeat(2, *([1] * (t.dim() - 1))) for t in toy2d.l_shape()))])


def test_boxes_to_rectangles_checks_its_input():
    r = toy2d.boxes_to_rectangles([(-1.0, 3.0, 0.0, 1.0)])
    torch.testing.assert_close(r.centers, torch.tensor([[[1.0, 0.5]]]))
    torch.testing.assert_close(r.half_sizes, torch.tensor([[[2.0, 0.5]]]))
    with pytest.raises(ValueError, match="xmin < xmax"):
        toy2d.boxes_to_rectangles([(1.0, -1.0, 0.0, 1.0)])
    with pytest.raises(ValueError, match="boxes must be a non-empty list"):
        toy2d.boxes_to_rectangles([(1.0, 2.0)])


def test_draw_abstraction_draws_points_normals_and_rectangles():
    shape = toy2d.u_shape()
    pts, nrm, labels = toy2d.sample_union_boundary(*shape, 50, generator=torch.Generator().manual_seed(0))
    fig, ax = plt.subplots()
    used = torch.tensor([True, True, False])
    toy2d_measures.draw_abstraction(ax, pts[0], nrm[0], tuple(t[0] for t in shape), used=used, labels=labels[0], title="U")
    assert len(ax.lines) == 3  # one closed outline per rectangle (the unused one dotted)
    assert ax.lines[2].get_linestyle() == ":"
    assert len(ax.collections) == 2  # the points and the normal arrows
    assert ax.get_title() == "U"
    plt.close(fig)


def test_draw_abstraction_can_leave_out_the_unused_rectangles():
    shape = toy2d.u_shape()
    fig, ax = plt.subplots()
    used = torch.tensor([True, False, True])
    toy2d_measures.draw_abstraction(ax, rectangles=tuple(t[0] for t in shape), used=used, show_unused=False)
    assert len(ax.lines) == 2  # the two used outlines only
    assert all(line.get_linestyle() == "-" for line in ax.lines)
    assert ax.lines[1].get_color() == plt.cm.tab10(2)  # each keeps the colour of its index
    plt.close(fig)
