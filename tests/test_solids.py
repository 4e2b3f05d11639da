import math

import numpy as np
import pytest
import trimesh

from cuboidlib.solids import (
    Capsule,
    Cylinder,
    Ellipsoid,
    Hexahedron,
    RoundedBox,
    bar,
    box,
    rotation_x,
    rotation_y,
    sample_union_surface,
    union_sdf,
)

R = rotation_x(0.3) @ rotation_y(-0.7)


def _wing():
    # Tapered swept wing half: root chord 0.4 at x = 0, tip chord 0.2 at x = 1 swept back by 0.3.
    c = np.empty((8, 3))
    for i in range(8):
        tip, top, le = i & 1, (i >> 1) & 1, (i >> 2) & 1
        chord, t = (0.2, 0.02) if tip else (0.4, 0.04)
        z_le = -0.3 if tip else 0.0
        c[i] = (1.0 if tip else 0.0, t / 2 if top else -t / 2, z_le if le else z_le - chord)
    return Hexahedron(c, 1)


SOLIDS = {
    "box": box([0.1, 0.2, 0.3], [0.5, 0.2, 0.3], R, 0),
    "wing": _wing(),
    "mirrored wing": Hexahedron(_wing().corners * [-1, 1, 1], 1),
    "rounded box": RoundedBox([0, 0.1, 0], R, [0.3, 0.05, 0.2], 0.08, 2),
    "cylinder": Cylinder([0.2, 0, 0], R, 0.15, 0.4, 3),
    "capsule": Capsule([0, 0, 0], [0.3, 0.5, -0.2], 0.1, 0),
    "sphere capsule": Capsule([0, 0, 0], [0, 0, 0], 0.2, 0),
    "ellipsoid": Ellipsoid([0, 0.3, 0], R, [0.5, 0.15, 0.25], 1),
}


def _shell_area(solid, n=400_000, delta=2e-3, seed=0):
    """Monte-Carlo surface area from the volume of the shell |sdf| < delta (independent of area())."""
    pts, _ = solid.sample(2000, np.random.default_rng(seed))
    lo, hi = pts.min(0) - 2 * delta, pts.max(0) + 2 * delta
    x = lo + np.random.default_rng(seed + 1).random((n, 3)) * (hi - lo)
    frac = (np.abs(solid.sdf(x)) < delta).mean()
    return frac * np.prod(hi - lo) / (2 * delta)


@pytest.mark.parametrize("name", ["box", "wing", "rounded box", "cylinder", "capsule"])
def test_area_matches_the_volume_of_a_thin_shell_around_the_sdf_zero_set(name):
    s = SOLIDS[name]
    assert s.area() == pytest.approx(_shell_area(s), rel=0.03)


def test_closed_form_areas():
    assert SOLIDS["box"].area() == pytest.approx(8 * (0.5 * 0.2 + 0.2 * 0.3 + 0.5 * 0.3))
    assert SOLIDS["cylinder"].area() == pytest.approx(2 * math.pi * 0.15 * 0.8 + 2 * math.pi * 0.15**2)
    assert SOLIDS["sphere capsule"].area() == pytest.approx(4 * math.pi * 0.2**2)
    assert Ellipsoid([0, 0, 0], np.eye(3), [0.3, 0.3, 0.3], 0).area() == pytest.approx(4 * math.pi * 0.09, rel=1e-6)
    # A fine tessellation of the ellipsoid gives its area to ~1e-4.
    ico = trimesh.creation.icosphere(subdivisions=6)
    fine = trimesh.Trimesh(ico.vertices * [0.5, 0.15, 0.25], ico.faces)
    assert SOLIDS["ellipsoid"].area() == pytest.approx(fine.area, rel=1e-3)


@pytest.mark.parametrize("name", list(SOLIDS))
def test_samples_lie_on_the_surface_with_unit_outward_normals(name):
    s = SOLIDS[name]
    p, n = s.sample(3000, np.random.default_rng(2))
    assert p.shape == n.shape == (3000, 3)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    assert np.abs(s.sdf(p)).max() < 1e-9
    eps = 1e-4
    assert (s.sdf(p + eps * n) > 0).all(), "normals must point out of the solid"
    assert (s.sdf(p - eps * n) < 0).all()


@pytest.mark.parametrize("name", list(SOLIDS))
def test_mesh_is_closed_outward_and_close_to_the_analytic_area(name):
    s = SOLIDS[name]
    m = s.mesh()
    assert m.is_watertight
    assert m.volume > 0, "faces must wind outward"
    assert m.area == pytest.approx(s.area(), rel=0.05)


def test_box_faces_receive_points_in_proportion_to_their_area():
    b = box([0, 0, 0], [1.0, 2.0, 3.0], np.eye(3), 0)
    p, n = b.sample(60000, np.random.default_rng(3))
    # faces normal to x have area 4*2*3 each, to y 4*1*3, to z 4*1*2; total 88.
    frac = np.array([(np.abs(n[:, a]) > 0.5).mean() for a in range(3)])
    np.testing.assert_allclose(frac, np.array([48, 24, 16]) / 88, atol=0.01)


def test_cylinder_and_capsule_split_points_between_caps_and_side_by_area():
    c = Cylinder([0, 0, 0], np.eye(3), 0.5, 1.0, 0)
    _, n = c.sample(40000, np.random.default_rng(4))
    # caps 2 * pi * 0.25, side 2 * pi * 0.5 * 2
    assert (np.abs(n[:, 2]) > 0.5).mean() == pytest.approx(0.5 / 2.5, abs=0.01)
    cap = Capsule([0, 0, 0], [0, 0, 2.0], 0.5, 0)
    p, _ = cap.sample(40000, np.random.default_rng(5))
    on_caps = (p[:, 2] < 0) | (p[:, 2] > 2.0)  # hemispheres: 4 pi 0.25, side: 2 pi 0.5 2
    assert on_caps.mean() == pytest.approx(1 / 3, abs=0.01)


def test_ellipsoid_sampling_is_area_uniform():
    e = Ellipsoid([0, 0, 0], np.eye(3), [1.0, 0.3, 0.5], 0)
    p, _ = e.sample(60000, np.random.default_rng(6))
    ico = trimesh.creation.icosphere(subdivisions=6)
    fine = trimesh.Trimesh(ico.vertices * [1.0, 0.3, 0.5], ico.faces)
    cap = fine.triangles_center[:, 0] > 0.6  # the elongated tip carries less area per direction
    expected = fine.area_faces[cap].sum() / fine.area
    assert (p[:, 0] > 0.6).mean() == pytest.approx(expected, abs=0.006)


def test_rounded_box_points_split_between_flat_faces_and_rounded_pieces():
    rb = RoundedBox([0, 0, 0], np.eye(3), [1.0, 0.5, 0.25], 0.2, 0)
    p, n = rb.sample(60000, np.random.default_rng(7))
    flat = (np.abs(n) > 1 - 1e-12).any(axis=1)
    flat_area = 8 * (1.0 * 0.5 + 0.5 * 0.25 + 1.0 * 0.25)
    assert flat.mean() == pytest.approx(flat_area / rb.area(), abs=0.01)
    assert rb.area() == pytest.approx(_shell_area(rb), rel=0.03)


@pytest.mark.parametrize("name", list(SOLIDS))
def test_mapping_scales_the_signed_distance(name):
    s = SOLIDS[name]
    c, k = np.array([0.3, -0.2, 0.1]), 2.5
    x = np.random.default_rng(8).normal(size=(200, 3)) * 0.5
    m = s.mapped(c, k)
    assert m.area() == pytest.approx(s.area() / k**2, rel=1e-6)
    np.testing.assert_array_equal(np.sign(m.sdf((x - c) / k)), np.sign(s.sdf(x)))
    if name != "ellipsoid":  # exact distances scale exactly
        np.testing.assert_allclose(m.sdf((x - c) / k), s.sdf(x) / k, atol=1e-12)


def test_bar_connects_its_end_points():
    a, b = np.array([0.0, 0.0, 0.0]), np.array([0.2, 1.0, 0.1])
    for round_section in (False, True):
        s = bar(a, b, 0.05, 0, round_section)
        # the end centres lie on the surface, the midpoint deep inside
        np.testing.assert_allclose(s.sdf(np.stack([a, b])), 0.0, atol=1e-12)
        assert s.sdf(((a + b) / 2)[None])[0] == pytest.approx(-0.025)


def test_union_of_overlapping_boxes_is_sampled_like_one_box():
    # [0, 2] x [0, 1]^2 and [1, 3] x [0, 1]^2 overlap and share coplanar faces; their union is
    # [0, 3] x [0, 1]^2 with area 14, of which the top face (y = 1) is 3.
    a = box([1.0, 0.5, 0.5], [1.0, 0.5, 0.5], np.eye(3), 0)
    b = box([2.0, 0.5, 0.5], [1.0, 0.5, 0.5], np.eye(3), 1)
    p, n, idx = sample_union_surface([a, b], 40000, np.random.default_rng(9))
    assert p.shape == (40000, 3) and idx.shape == (40000,)
    assert np.abs(union_sdf([a, b], p)).max() < 1e-9
    assert not ((p[:, 0] > 1e-9) & (p[:, 0] < 3 - 1e-9) & (np.abs(n[:, 0]) > 0.5)).any(), "internal faces"
    assert (n[:, 1] > 0.5).mean() == pytest.approx(3 / 14, abs=0.01)
    # points on the shared top patch x in [1, 2] are not doubled
    top = n[:, 1] > 0.5
    assert ((p[top, 0] > 1) & (p[top, 0] < 2)).mean() == pytest.approx(1 / 3, abs=0.02)


def test_a_solid_inside_another_contributes_no_points():
    outer = box([0, 0, 0], [1.0, 1.0, 1.0], np.eye(3), 0)
    inner = Ellipsoid([0, 0, 0], np.eye(3), [0.5, 0.4, 0.3], 1)
    _, _, idx = sample_union_surface([inner, outer], 2000, np.random.default_rng(10))
    assert (idx == 1).all()
