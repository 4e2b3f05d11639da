"""Tests of cuboidlib.fitting: per-shape fitting of cuboids by gradient descent on the paper's losses.

The fits here are small (a few hundred points, a few cuboids, 100-200 steps) so the file stays fast.
Expected outcomes come from the geometry of the inputs (points sampled on known boxes), not from
earlier runs of the fit.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cuboidlib.abstraction import AbstractionBatch
from cuboidlib.distance import point_to_cuboid_distance
from cuboidlib.losses import compactness_loss, reconstruction_loss
from cuboidlib.metrics import cuboid_chamfer_distance
from cuboidlib.normalization import normalize
from cuboidlib.fitting import FitConfig, FitResult, _optimise, fit_cuboids, initial_cuboids
from cuboidlib.geometry import Cuboids, sample_cuboid_surfaces, world_to_local

IDENTITY = [1.0, 0.0, 0.0, 0.0]


def _box_cloud(centers, half_sizes, n: int, seed: int = 0, dtype=torch.float32):
    """Points (1, n, 3) and outward normals sampled on axis-aligned boxes, and the box index (1, n)."""
    c = torch.tensor([centers], dtype=dtype)
    s = torch.tensor([half_sizes], dtype=dtype)
    q = torch.tensor([[IDENTITY] * len(centers)], dtype=dtype)
    g = torch.Generator().manual_seed(seed)
    return sample_cuboid_surfaces(c, q, s, n, generator=g)


@pytest.fixture(scope="module")
def one_box():
    return _box_cloud([[0.1, 0.2, -0.3]], [[0.4, 0.2, 0.1]], 400)


@pytest.fixture(scope="module")
def two_boxes():
    # two boxes 0.5 apart (no contact), different sizes
    return _box_cloud([[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0]], [[0.2, 0.3, 0.2], [0.25, 0.1, 0.15]], 600, seed=1)


@pytest.fixture(scope="module")
def two_box_fit(two_boxes):
    points, normals, _ = two_boxes
    return fit_cuboids(points, normals, FitConfig(num_cuboids=6, steps=200))


def _inside_depth(points: torch.Tensor, cuboids: Cuboids) -> torch.Tensor:
    """(B, N, M) how far each point lies inside each cuboid (<= 0 outside or on the surface)."""
    local = world_to_local(points, cuboids.centers, cuboids.quaternions)
    return (cuboids.half_sizes[:, None] - local.abs()).amin(dim=-1)


# ----------------------------------------------------------------------------------------------
# FitConfig
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"loss": {"distance": "chamfer"}}, "distance must be one of"),
        ({"loss": {"allocation": "hard"}}, "allocation must be one of"),
        ({"init": "grid"}, "init must be one of"),
        ({"num_cuboids": 0}, "num_cuboids must be a positive integer"),
        ({"num_cuboids": 2.5}, "num_cuboids must be a positive integer"),
        ({"steps": -1}, "steps must be a non-negative integer"),
        ({"lr": 0.0}, "lr must be a finite positive number"),
        ({"lr_logits": float("nan")}, "lr_logits must be a finite positive number"),
        ({"loss": {"sigma_s": -0.1}}, "sigma_s must be a finite non-negative number"),
        ({"loss": {"lambda_compact": float("inf")}}, "lambda_compact must be a finite non-negative number"),
        ({"loss": {"eps_ext": 1.0}}, r"eps_ext must lie in \[0, 1\)"),
        ({"beta2": 1.0}, r"beta2 must lie in \[0, 1\)"),
        ({"seed": -1}, "seed must be a non-negative integer"),
        ({"restarts": 0}, "restarts must be a positive integer"),
    ],
)
def test_fit_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        FitConfig(**kwargs)


def test_fit_config_replace_changes_one_field_and_validates():
    config = FitConfig().replace(loss={"distance": "nearest_surface"}, steps=5)
    assert (config.loss.distance, config.steps, config.num_cuboids) == ("nearest_surface", 5, FitConfig().num_cuboids)
    assert config.loss.compactness_average, "the other loss settings are kept"
    with pytest.raises(ValueError, match="steps"):
        FitConfig().replace(steps=-3)


# ----------------------------------------------------------------------------------------------
# k-means and the initialisation
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("init", ["kmeans", "random"])
def test_initial_cuboids_start_near_the_points_with_identity_rotations(two_boxes, init):
    points = two_boxes.points
    config = FitConfig(num_cuboids=5, init=init)
    centers, quaternions, half_sizes, logits = initial_cuboids(points, config, torch.Generator().manual_seed(0))
    assert centers.shape == (1, 5, 3) and half_sizes.shape == (1, 5, 3) and logits.shape == (1, 600, 5)
    assert torch.equal(quaternions, torch.tensor(IDENTITY).expand(1, 5, 4))
    assert (half_sizes > 0).all()
    # every initial centre lies inside the bounding box of the cloud
    assert (centers >= points.amin(dim=1)[:, None] - 1e-6).all() and (centers <= points.amax(dim=1)[:, None] + 1e-6).all()
    # the initial allocation prefers the nearest centre
    nearest = torch.cdist(points, centers).argmin(dim=-1)
    assert torch.equal(logits.argmax(dim=-1), nearest)


# ----------------------------------------------------------------------------------------------
# What the fit returns
# ----------------------------------------------------------------------------------------------


def test_fit_result_shapes_and_invariants(two_boxes, two_box_fit):
    r = two_box_fit
    assert isinstance(r, FitResult) and isinstance(r.cuboids, Cuboids)
    assert r.cuboids.centers.shape == (1, 6, 3) and r.cuboids.quaternions.shape == (1, 6, 4)
    assert r.labels.shape == (1, 600) and r.labels.dtype == torch.long
    assert r.W.shape == (1, 600, 6) and r.portions.shape == (1, 6)
    torch.testing.assert_close(r.W.sum(dim=-1), torch.ones(1, 600))
    torch.testing.assert_close(r.portions, r.W.mean(dim=1))
    torch.testing.assert_close(r.cuboids.quaternions.norm(dim=-1), torch.ones(1, 6))
    assert (r.cuboids.half_sizes > 0).all()
    # existence read-out: w_m > eps_ext (Sec. 3.4.3), and labels only name existing cuboids
    assert torch.equal(r.exists, r.portions > r.config.loss.eps_ext)
    assert r.exists.gather(1, r.labels).all()
    assert set(r.history) == {"total", "reconstruction", "compactness", "existing"}
    assert all(len(v) == 200 for v in r.history.values())
    assert r.elapsed_s > 0 and r.converged.shape == (1,)


def test_two_separated_boxes_are_recovered(two_boxes, two_box_fit):
    points, normals, box = two_boxes
    r = two_box_fit
    # every existing cuboid serves one box only, and the points of each box go to cuboids inside its half
    for m in torch.nonzero(r.exists[0]).flatten().tolist():
        owners = box[0][r.labels[0] == m]
        assert len(set(owners.tolist())) == 1, f"cuboid {m} mixes the two boxes"
    # the fitted cuboids reproduce the surface: Eq. (5) distance of every point to its cuboid is ~0
    d = point_to_cuboid_distance(points, normals, r.cuboids.centers, r.cuboids.quaternions, r.cuboids.half_sizes,
                                 sigma_s=0.0)
    assert d.gather(2, r.labels[..., None]).max() < 1e-3
    # and no existing cuboid sticks out of its box: the union of cuboids = the two boxes
    corners = r.cuboids.corners()[0][r.exists[0]]  # (E, 8, 3)
    lo, hi = corners.amin(dim=1), corners.amax(dim=1)
    box_lo = torch.tensor([[-0.7, -0.3, -0.2], [0.25, -0.1, -0.15]])
    box_hi = torch.tensor([[-0.3, 0.3, 0.2], [0.75, 0.1, 0.15]])
    owner = (lo[:, 0] > 0).long()
    assert (lo >= box_lo[owner] - 0.02).all() and (hi <= box_hi[owner] + 0.02).all()


def test_a_single_box_is_covered_by_cuboids_inside_it(one_box):
    points, normals, _ = one_box
    r = fit_cuboids(points, normals, FitConfig(num_cuboids=4, steps=200))
    corners = r.cuboids.corners()[0][r.exists[0]]
    true_lo, true_hi = torch.tensor([-0.3, 0.0, -0.4]), torch.tensor([0.5, 0.4, -0.2])
    torch.testing.assert_close(corners.amin(dim=(0, 1)), true_lo, atol=0.01, rtol=0)
    torch.testing.assert_close(corners.amax(dim=(0, 1)), true_hi, atol=0.01, rtol=0)
    assert int(r.num_existing()) < 4, "the compactness loss must leave some of the 4 cuboids unused"
    assert bool(r.converged[0])


def test_fit_is_deterministic_given_the_seed(one_box):
    points, normals, _ = one_box
    config = FitConfig(num_cuboids=3, steps=30)
    a, b = fit_cuboids(points, normals, config), fit_cuboids(points, normals, config)
    for x, y in ((a.cuboids.centers, b.cuboids.centers), (a.cuboids.half_sizes, b.cuboids.half_sizes), (a.W, b.W)):
        assert torch.equal(x, y)
    assert a.history == b.history
    c = fit_cuboids(points, normals, config.replace(seed=1))
    assert not torch.equal(a.initial.centers, c.initial.centers)


def test_both_distances_start_from_the_same_cuboids(two_boxes):
    points, normals, _ = two_boxes
    config = FitConfig(num_cuboids=5, steps=3)
    a = fit_cuboids(points, normals, config)
    b = fit_cuboids(points, normals, config.replace(loss={"distance": "nearest_surface", "lambda_compact": 0.0, "sigma_s": 0.0}))
    for name in ("centers", "quaternions", "half_sizes"):
        assert torch.equal(getattr(a.initial, name), getattr(b.initial, name))


def test_zero_steps_returns_the_initial_cuboids(two_boxes):
    points, normals, _ = two_boxes
    r = fit_cuboids(points, normals, FitConfig(num_cuboids=5, steps=0))
    torch.testing.assert_close(r.cuboids.centers, r.initial.centers)
    torch.testing.assert_close(r.cuboids.half_sizes, r.initial.half_sizes)
    assert r.history["total"] == [] and not bool(r.converged[0])


def test_results_are_in_the_input_coordinates(one_box):
    # normalisation inside the fit: scaling and moving the input scales and moves the cuboids
    points, normals, _ = one_box
    p64, n64 = points.double(), normals.double()
    config = FitConfig(num_cuboids=3, steps=40)
    a = fit_cuboids(p64, n64, config)
    shift = torch.tensor([3.0, -1.0, 2.0], dtype=torch.float64)
    b = fit_cuboids(5.0 * p64 + shift, n64, config)
    assert b.cuboids.centers.dtype == torch.float64
    torch.testing.assert_close(b.cuboids.centers, 5.0 * a.cuboids.centers + shift, atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(b.cuboids.half_sizes, 5.0 * a.cuboids.half_sizes, atol=1e-6, rtol=1e-6)
    assert torch.equal(a.labels, b.labels)


def test_single_shape_numpy_input_and_unnormalised_normals(one_box):
    points, normals, _ = one_box
    config = FitConfig(num_cuboids=3, steps=20)
    a = fit_cuboids(points[0].numpy(), normals[0].numpy(), config)  # (N, 3) numpy arrays
    b = fit_cuboids(points, 2.5 * normals, config)  # normals of length 2.5 are normalised
    assert a.labels.shape == (1, 400)
    torch.testing.assert_close(a.cuboids.centers, b.cuboids.centers)


def test_batched_fit_fits_each_shape_independently(one_box, two_boxes):
    p1, n1, _ = one_box
    p2, n2, _ = two_boxes
    points = torch.cat([p1[:, :400], p2[:, :400]])
    normals = torch.cat([n1[:, :400], n2[:, :400]])
    r = fit_cuboids(points, normals, FitConfig(num_cuboids=4, steps=150))
    assert r.cuboids.centers.shape == (2, 4, 3) and r.labels.shape == (2, 400)
    # shape 0 stays within the one box, shape 1 has cuboids on both sides of x = 0
    assert (r.cuboids.centers[0][r.exists[0]][:, 0] > -0.31).all()
    centers_1 = r.cuboids.centers[1][r.exists[1]][:, 0]
    assert (centers_1 < 0).any() and (centers_1 > 0).any()


def test_nearest_allocation_gives_a_one_hot_w(two_boxes):
    points, normals, _ = two_boxes
    r = fit_cuboids(points, normals, FitConfig(num_cuboids=4, steps=20, loss={"allocation": "nearest_cuboid"}))
    assert set(r.W.unique().tolist()) <= {0.0, 1.0}
    torch.testing.assert_close(r.W.sum(dim=-1), torch.ones(1, 600))


def test_the_literal_eq6_weight_merges_more_than_the_averaged_form():
    # Eq. (6) with lambda_1 = 0.1 is M^2 times stronger than the averaged form: it must use no
    # more cuboids, and on three separated boxes strictly fewer (it merges parts).
    points, normals, _ = _box_cloud(
        [[-0.6, 0.0, 0.0], [0.0, 0.0, 0.0], [0.6, 0.0, 0.0]], [[0.1, 0.3, 0.1], [0.1, 0.3, 0.1], [0.1, 0.3, 0.1]], 450
    )
    config = FitConfig(num_cuboids=6, steps=150)
    averaged = fit_cuboids(points, normals, config)
    literal = fit_cuboids(points, normals, config.replace(loss={"compactness_average": False}))
    assert int(averaged.num_existing()) >= 3
    assert int(literal.num_existing()) < int(averaged.num_existing())


def test_final_loss_is_the_loss_of_the_returned_cuboids_and_allocation(two_boxes):
    # on an already normalised cloud the fit's coordinates are the input's, so the loss can be recomputed
    points, normals, _ = two_boxes
    points, _, _ = normalize(points)
    config = FitConfig(num_cuboids=5, steps=60)
    r = fit_cuboids(points, normals, config)
    c = r.cuboids
    d = point_to_cuboid_distance(points, normals, c.centers, c.quaternions, c.half_sizes, sigma_s=0.0)
    expected = reconstruction_loss(r.W, d) + 0.1 * compactness_loss(r.portions, average_over_cuboids=True)
    torch.testing.assert_close(r.final_loss, expected, atol=1e-6, rtol=1e-4)


def test_restarts_keep_the_fit_with_the_lowest_final_loss(one_box, two_boxes):
    points = torch.cat([one_box.points[:, :400], two_boxes.points[:, :400]])
    normals = torch.cat([one_box.normals[:, :400], two_boxes.normals[:, :400]])
    config = FitConfig(num_cuboids=4, steps=40, restarts=3)
    r = fit_cuboids(points, normals, config)
    assert r.cuboids.centers.shape == (2, 4, 3) and r.final_loss.shape == (2,) and len(r.history["total"]) == 40
    # the same optimisation, run by hand on the three copies of each shape
    p, _, _ = normalize(points)
    rows = _optimise(p.repeat_interleave(3, dim=0), normals.repeat_interleave(3, dim=0), config, False)
    per_restart = rows["final_loss"].view(2, 3)
    assert not torch.equal(per_restart[:, 0], per_restart[:, 1]), "restarts must start differently"
    torch.testing.assert_close(r.final_loss, per_restart.amin(dim=1))


def test_progress_bar_is_shown_when_asked(one_box, capsys):
    points, normals, _ = one_box
    fit_cuboids(points, normals, FitConfig(num_cuboids=2, steps=3), progress=True)
    assert "fitting cuboids" in capsys.readouterr().err
    fit_cuboids(points, normals, FitConfig(num_cuboids=2, steps=3), progress=False)
    assert capsys.readouterr().err == ""


# ----------------------------------------------------------------------------------------------
# Bad inputs and failures
# ----------------------------------------------------------------------------------------------


def _good():
    g = torch.Generator().manual_seed(0)
    points = torch.rand(1, 50, 3, generator=g)
    normals = torch.nn.functional.normalize(torch.randn(1, 50, 3, generator=g), dim=-1)
    return points, normals


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda p, n: (p[0, :, :2], n), r"points \(or \(N, 3\) for one shape\) must have shape"),
        (lambda p, n: (p, n[:, :40]), "normals must have the shape of points"),
        (lambda p, n: (p[:, :0], n[:, :0]), r"points is empty \(N = 0\)"),
        (lambda p, n: (p.index_put((torch.tensor([0]), torch.tensor([3]), torch.tensor([1])), torch.tensor(float("nan"))),
                       n), "points contains 1 NaN"),
        (lambda p, n: (p, n.index_put((torch.tensor([0]), torch.tensor([7])), torch.zeros(3))),
         "normals contains zero-length vectors"),
        (lambda p, n: (p[:, :5], n[:, :5]), "fewer than num_cuboids"),
        (lambda p, n: (torch.ones_like(p), n), "all identical"),
    ],
)
def test_bad_inputs_are_rejected_with_clear_messages(edit, match):
    points, normals = edit(*_good())
    with pytest.raises(ValueError, match=match):
        fit_cuboids(points, normals, FitConfig(num_cuboids=8, steps=1))


def test_identical_points_are_rejected_without_normalisation_too():
    points, normals = _good()
    with pytest.raises(ValueError, match="all identical"):
        fit_cuboids(torch.ones_like(points), normals, FitConfig(num_cuboids=2, steps=1, normalize=False))


def test_config_must_be_a_fit_config():
    with pytest.raises(TypeError, match="config must be a FitConfig"):
        fit_cuboids(*_good(), config={"steps": 3})


@pytest.mark.parametrize("distance", ["normal", "nearest_surface"])
def test_divergence_is_reported_with_the_step(one_box, distance):
    points, normals, _ = one_box
    with pytest.raises(FloatingPointError, match=r"diverged at step \d+.*lower lr"):
        fit_cuboids(points, normals, FitConfig(num_cuboids=3, steps=20, lr=1e4, loss={"distance": distance}))


def test_numpy_and_torch_inputs_agree():
    points, normals = _good()
    config = FitConfig(num_cuboids=3, steps=5)
    a = fit_cuboids(np.asarray(points), np.asarray(normals), config)
    b = fit_cuboids(points, normals, config)
    assert torch.equal(a.W, b.W)


# ----------------------------------------------------------------------------------------------
# Refinement: the fit started from given cuboids and allocation
# ----------------------------------------------------------------------------------------------


def _rough_start(points: torch.Tensor, labels: torch.Tensor) -> AbstractionBatch:
    """A deliberately loose start for two boxes in slots 0 and 2 of M = 4 (slots 1 and 3 absent)."""
    centers = torch.tensor([[[-0.45, 0.05, 0.0], [0.0, 0.0, 0.0], [0.55, -0.05, 0.0], [0.0, 0.5, 0.0]]])
    half = torch.tensor([[[0.3, 0.35, 0.3], [0.1, 0.1, 0.1], [0.3, 0.2, 0.2], [0.1, 0.1, 0.1]]])
    quats = torch.tensor([[IDENTITY] * 4])
    exists = torch.tensor([[True, False, True, False]])
    return AbstractionBatch(Cuboids(centers, quats, half, exists), labels=torch.where(labels == 0, 0, 2))


def test_refinement_keeps_the_start_slots_and_tightens_the_cuboids(two_boxes):
    points, normals, labels = two_boxes
    start = _rough_start(points, labels)
    config = FitConfig(num_cuboids=9, steps=150, lr=0.003, normalize=False)  # num_cuboids follows the start: M = 4
    refined = fit_cuboids(points, normals, config, start=start)
    assert refined.cuboids.num_cuboids == 4 and refined.config.num_cuboids == 4
    assert refined.exists.tolist() == [[True, False, True, False]], "absent slots stay absent"
    assert torch.equal(refined.labels, start.labels), "well separated boxes keep their segmentation"
    torch.testing.assert_close(refined.initial.centers, start.cuboids.centers)
    chamfer = lambda c: float(cuboid_chamfer_distance(points, c.centers, c.quaternions, c.half_sizes, c.exists,  # noqa: E731
                                                      generator=torch.Generator().manual_seed(0)))
    assert chamfer(refined.cuboids) < 0.3 * chamfer(start.cuboids)
    # the boxes are found again: centres within 0.03 of the true ones
    torch.testing.assert_close(refined.cuboids.centers[0, [0, 2]], torch.tensor([[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0]]),
                               atol=0.03, rtol=0)


def test_refinement_from_labels_in_other_units_works_in_the_points_coordinates(two_boxes):
    points, normals, labels = two_boxes
    start = _rough_start(points, labels)
    scaled = AbstractionBatch(Cuboids(100 * start.cuboids.centers + 7, start.cuboids.quaternions,
                                      100 * start.cuboids.half_sizes, start.cuboids.exists), labels=start.labels)
    refined = fit_cuboids(100 * points + 7, normals, FitConfig(steps=150, lr=0.003), start=scaled)  # normalises
    reference = fit_cuboids(points, normals, FitConfig(steps=150, lr=0.003), start=start)
    torch.testing.assert_close((refined.cuboids.centers - 7) / 100, reference.cuboids.centers, atol=1e-3, rtol=0)


def test_refinement_refuses_a_start_that_does_not_fit_the_points(two_boxes):
    points, normals, labels = two_boxes
    start = _rough_start(points, labels)
    with pytest.raises(ValueError, match="start holds 1 shape"):
        fit_cuboids(points.repeat(2, 1, 1), normals.repeat(2, 1, 1), FitConfig(steps=1), start=start)
    with pytest.raises(ValueError, match="allocation covers"):
        fit_cuboids(points[:, :100], normals[:, :100], FitConfig(steps=1), start=start)
    with pytest.raises(ValueError, match="needs an allocation"):
        fit_cuboids(points, normals, FitConfig(steps=1), start=AbstractionBatch(start.cuboids))
    with pytest.raises(ValueError, match="restarts must be 1"):
        fit_cuboids(points, normals, FitConfig(steps=1, restarts=2), start=start)
    with pytest.raises(TypeError, match="AbstractionBatch"):
        fit_cuboids(points, normals, FitConfig(steps=1), start=start.cuboids)


def test_fit_config_builds_on_the_loss_config_and_refuses_what_only_a_network_uses():
    from cuboidlib.losses import LossConfig

    assert FitConfig().loss == LossConfig(compactness_average=True), "the fit's default is the averaged Eq. (6)"
    assert FitConfig(loss={"sigma_s": 0.0}).loss.compactness_average, "a dict fills in the fit's defaults"
    with pytest.raises(ValueError, match="only training a network uses"):
        FitConfig(loss={"lambda_consistency": 0.2})
    with pytest.raises(ValueError, match="no Chamfer variant"):
        FitConfig(loss={"distance": "chamfer"})
    with pytest.raises(ValueError, match="allocation"):
        FitConfig(loss={"allocation": "soft"})


def test_tightening_on_the_two_sided_distance_lowers_the_chamfer_distance_and_keeps_the_slots():
    from cuboidlib.fitting import tighten_cuboids
    from cuboidlib.thin_shapes import THIN_KINDS, THIN_PER_KIND, thin_shape, thin_structure_set

    points, _ = thin_shape("ladder", 0, n_points=1024)
    assert np.array_equal(points, thin_shape("ladder", 0, n_points=1024)[0]), "the set is fixed"
    p = torch.as_tensor(points)[None]
    start = fit_cuboids(p, torch.as_tensor(thin_shape("ladder", 0, n_points=1024)[1])[None], FitConfig(steps=60)).cuboids
    loose = Cuboids(start.centers, start.quaternions, 1.3 * start.half_sizes, start.exists)
    tight = tighten_cuboids(p, loose, steps=80)
    chamfer = lambda c: float(cuboid_chamfer_distance(p, c.centers, c.quaternions, c.half_sizes, c.exists,  # noqa: E731
                                                      generator=torch.Generator().manual_seed(0))[0])
    assert chamfer(tight) < 0.8 * chamfer(loose)
    assert torch.equal(tight.exists, loose.exists) and tight.centers.shape == loose.centers.shape
    same = tighten_cuboids(p, loose, steps=0)
    assert torch.equal(same.half_sizes, loose.half_sizes)
    with pytest.raises(ValueError, match="steps must be a non-negative integer"):
        tighten_cuboids(p, loose, steps=-1)
    with pytest.raises(ValueError, match="cuboids hold 1 shape"):
        tighten_cuboids(p.repeat(2, 1, 1), loose)
    assert chamfer(tighten_cuboids(p, loose, steps=80, n_samples=512, n_points=512)) < 0.8 * chamfer(loose)
    with pytest.raises(ValueError, match="n_points must be a positive integer or None"):
        tighten_cuboids(p, loose, n_points=0)
    with pytest.raises(TypeError, match="cuboids must be a Cuboids"):
        tighten_cuboids(p, "boxes")
    assert len(thin_structure_set(n_points=64)) == len(THIN_KINDS) * THIN_PER_KIND
    with pytest.raises(ValueError, match="kind must be one of"):
        thin_shape("teapot")
