import math

import pytest
import torch

from cuboidlib.metrics import (
    ChamferConvention,
    cuboid_chamfer_distance,
    mean_iou,
    part_concision,
    normal_consistency,
    normal_consistency_terms,
    number_of_existing_cuboids,
    part_confusion,
    part_ious,
    reassigned_fraction,
    segment_box_distance,
    transfer_part_labels,
)
from cuboidlib.rotations import quaternion_multiply, quaternion_to_rotation_matrix, random_quaternions

ID = torch.tensor([[[1.0, 0.0, 0.0, 0.0]]])


def unit_cube(half=0.5):
    return torch.zeros(1, 1, 3), ID.clone(), torch.full((1, 1, 3), half)


# ---------------------------------------------------------------- Chamfer distance


def test_chamfer_far_point_matches_the_analytic_value():
    # All input points at p = (2, 0, 0); one cube of half size a = 0.5 at the origin.
    # points -> cuboids: the nearest surface point is (a, 0, 0): (2 - a)^2 = 2.25.
    # cuboids -> points: E|s - p|^2 = E|s|^2 + |p|^2 (E[s] = 0), and E|s|^2 = a^2 + 2 a^2 / 3 = 5/12.
    points = torch.tensor([[[2.0, 0.0, 0.0]]]).expand(1, 64, 3)
    g = torch.Generator().manual_seed(0)
    total = cuboid_chamfer_distance(points, *unit_cube(), convention=ChamferConvention(n_samples=20000), generator=g)
    assert total.shape == (1,)
    assert float(total) == pytest.approx(2.25 + 4 + 5 / 12, abs=0.03)


def test_chamfer_of_points_on_the_surface_is_small_and_decreases_with_samples():
    from cuboidlib.geometry import sample_cuboid_surfaces

    g = torch.Generator().manual_seed(1)
    points = sample_cuboid_surfaces(*unit_cube(), 2048, generator=g).points
    coarse = cuboid_chamfer_distance(points, *unit_cube(), convention=ChamferConvention(n_samples=256), generator=g)
    fine = cuboid_chamfer_distance(points, *unit_cube(), convention=ChamferConvention(n_samples=8192), generator=g)
    assert float(fine) < float(coarse) < 1e-2


def test_chamfer_conventions_relate_as_documented():
    points = torch.tensor([[[2.0, 0.0, 0.0]]]).expand(1, 8, 3)
    cube = (torch.zeros(1, 1, 3), ID.clone(), torch.full((1, 1, 3), 1e-4))  # nearly a point at the origin
    def cd(**kw):
        g = torch.Generator().manual_seed(3)
        return float(cuboid_chamfer_distance(points, *cube, convention=ChamferConvention(n_samples=64, **kw), generator=g))

    assert cd() == pytest.approx(2 * 4.0, rel=1e-3)  # squared L2, both directions summed
    assert cd(norm="l2") == pytest.approx(2 * 2.0, rel=1e-3)
    assert cd(norm="l1") == pytest.approx(2 * 2.0, rel=1e-3)  # the offset is along one axis
    assert cd(directions="mean") == pytest.approx(4.0, rel=1e-3)
    assert cd(scale=1000) == pytest.approx(8000.0, rel=1e-3)


def test_chamfer_ignores_cuboids_that_do_not_exist():
    points = torch.tensor([[[2.0, 0.0, 0.0]]]).expand(1, 16, 3)
    centers = torch.tensor([[[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]])
    quats = ID.expand(1, 2, 4).clone()
    half = torch.full((1, 2, 3), 0.01)
    g = torch.Generator().manual_seed(0)
    both = cuboid_chamfer_distance(points, centers, quats, half, convention=ChamferConvention(n_samples=512), generator=g)
    only_far = cuboid_chamfer_distance(
        points, centers, quats, half, exists=torch.tensor([[False, True]]),
        convention=ChamferConvention(n_samples=512), generator=g,
    )
    assert float(only_far) < 1e-3 < float(both)


def test_convention_describe_states_everything():
    text = ChamferConvention(scale=1000).describe()
    for word in ("squared L2", "mean", "sum", "x1000", "4096"):
        assert word in text


@pytest.mark.parametrize(
    "kwargs, match",
    [({"norm": "l3"}, "norm"), ({"directions": "max"}, "directions"), ({"scale": 0}, "scale"), ({"n_samples": 0}, "n_samples")],
)
def test_bad_conventions_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ChamferConvention(**kwargs)


def test_chamfer_rejects_bad_points():
    with pytest.raises(ValueError, match="points"):
        cuboid_chamfer_distance(torch.zeros(4, 3), *unit_cube())


# ---------------------------------------------------------------- normal consistency


def _face_centre_points(n=200):
    """Points near the centres of the +x and +y faces of the unit cube, with their normals."""
    g = torch.Generator().manual_seed(0)
    uv = (torch.rand(n, 2, generator=g) - 0.5) * 0.4
    px = torch.stack([torch.full((n,), 0.5), uv[:, 0], uv[:, 1]], dim=1)
    py = torch.stack([uv[:, 0], torch.full((n,), 0.5), uv[:, 1]], dim=1)
    nx = torch.tensor([1.0, 0, 0]).expand(n, 3)
    ny = torch.tensor([0, 1.0, 0]).expand(n, 3)
    return torch.cat([px, py])[None], torch.cat([nx, ny])[None]


def test_normal_consistency_is_one_for_matching_normals_of_either_sign():
    points, normals = _face_centre_points()
    g = torch.Generator().manual_seed(0)
    assert float(normal_consistency(points, normals, *unit_cube(), generator=g)) == pytest.approx(1.0, abs=1e-6)
    assert float(normal_consistency(points, -normals, *unit_cube(), generator=g)) == pytest.approx(1.0, abs=1e-6)


def test_normal_consistency_of_perpendicular_normals_is_zero_and_random_is_about_half():
    points, normals = _face_centre_points()
    g = torch.Generator().manual_seed(0)
    perpendicular = torch.roll(normals, 1, dims=-1)  # +x -> +y and +y -> +z: both perpendicular to the face
    assert float(normal_consistency(points, perpendicular, *unit_cube(), generator=g)) == pytest.approx(0.0, abs=1e-6)
    random = torch.nn.functional.normalize(torch.randn(points.shape, generator=g), dim=-1)
    assert float(normal_consistency(points, random, *unit_cube(), generator=g)) == pytest.approx(0.5, abs=0.06)


def test_two_way_normal_consistency_sees_the_inner_faces_of_stacked_slabs():
    from cuboidlib.geometry import sample_cuboid_surfaces

    cube = unit_cube()
    surface = sample_cuboid_surfaces(*cube[:3], 4000, generator=torch.Generator().manual_seed(0))
    points, normals = surface.points, surface.normals
    both = normal_consistency(points, normals, *cube, generator=torch.Generator().manual_seed(1), directions="both")
    assert float(both) > 0.95, "a cube against its own surface: about 1 (below only near the edges)"
    # four slabs of height 1/4 stacked to fill the cube (the degenerate solution of Fig. 9): from the points
    # everything looks right, but the six inner horizontal faces have no points with vertical normals near them
    centers = torch.tensor([[0.0, -0.375 + 0.25 * k, 0.0] for k in range(4)])[None]
    quats = torch.tensor([1.0, 0, 0, 0]).expand(1, 4, 4)
    halves = torch.tensor([0.5, 0.125, 0.5]).expand(1, 4, 3)
    kw = dict(generator=torch.Generator().manual_seed(1))
    one_way = float(normal_consistency(points, normals, centers, quats, halves, **kw))
    two_way = float(normal_consistency(points, normals, centers, quats, halves, directions="both", **kw))
    assert one_way > 0.85 and two_way < one_way - 0.1, (one_way, two_way)
    from_points, from_cuboids = normal_consistency_terms(points, normals, centers, quats, halves,
                                                         generator=torch.Generator().manual_seed(1))
    assert float(from_points) == pytest.approx(one_way, abs=1e-6)  # the same samples, one search for both terms
    same_samples = normal_consistency(points, normals, centers, quats, halves, directions="both",
                                      generator=torch.Generator().manual_seed(1))
    assert float(0.5 * (from_points + from_cuboids)) == pytest.approx(float(same_samples), abs=1e-6)
    assert float(from_cuboids) < 0.7, "the slabs' inner faces, seen from the cuboids"
    with pytest.raises(ValueError, match="directions must be 'points' or 'both'"):
        normal_consistency(points, normals, *cube, directions="cuboids")


def test_normal_consistency_rejects_mismatched_normals():
    points, normals = _face_centre_points()
    with pytest.raises(ValueError, match="normals"):
        normal_consistency(points, normals[:, :10], *unit_cube())


# ---------------------------------------------------------------- N_AC, label transfer, mIoU


def test_number_of_existing_cuboids():
    exists = torch.tensor([[True, False, True], [True, True, True]])
    assert float(number_of_existing_cuboids(exists)) == pytest.approx(2.5)
    with pytest.raises(ValueError, match=r"\(B, M\)"):
        number_of_existing_cuboids(torch.ones(3, dtype=torch.bool))


def test_transfer_part_labels_takes_the_majority_part_per_cuboid():
    seg = torch.tensor([[0, 0, 0, 1, 1, 2], [0, 1, 1, 1, 2, 2]])
    gt = torch.tensor([[1, 1, 0, 0, 0, 1], [1, 0, 0, 1, 1, 1]])
    # cuboid 0: parts [1, 1, 0, 1] -> 1; cuboid 1: [0, 0, 0, 0, 1] -> 0; cuboid 2: [1, 1, 1] -> 1; cuboid 3: none.
    assert transfer_part_labels(seg, gt, num_cuboids=4, num_parts=2).tolist() == [1, 0, 1, -1]


def test_transfer_part_labels_rejects_bad_input():
    with pytest.raises(ValueError, match="same shape"):
        transfer_part_labels(torch.zeros(2, 3, dtype=torch.long), torch.zeros(2, 4, dtype=torch.long), 2, 2)
    with pytest.raises(ValueError, match="segmentation indices"):
        transfer_part_labels(torch.full((1, 3), 5), torch.zeros(1, 3, dtype=torch.long), 2, 2)
    with pytest.raises(ValueError, match="integer"):
        transfer_part_labels(torch.zeros(1, 3), torch.zeros(1, 3, dtype=torch.long), 2, 2)


def test_mean_iou_by_hand():
    pred = torch.tensor([[0, 0, 1, 1], [1, 1, 1, 0]])
    gt = torch.tensor([[0, 1, 1, 1], [1, 1, 0, 0]])
    # label 0: intersection 1 + 1 = 2, union 2 + 2 = 4 -> 0.5; label 1: intersection 2 + 2 = 4, union 3 + 3 = 6.
    assert mean_iou(pred, gt, num_parts=2) == pytest.approx((0.5 + 4 / 6) / 2)
    # per shape: shape 0: label 0: 1/2, label 1: 2/3; shape 1: label 0: 1/2, label 1: 2/3.
    assert mean_iou(pred, gt, num_parts=2, per_shape=True) == pytest.approx((0.5 + 2 / 3) / 2)
    assert mean_iou(gt, gt, num_parts=2) == 1.0


def test_mean_iou_counts_unlabelled_predictions_as_wrong_and_absent_labels_per_shape_as_one():
    gt = torch.tensor([[0, 0, 0, 0]])
    assert mean_iou(torch.tensor([[0, 0, -1, -1]]), gt, num_parts=2) == pytest.approx(0.5)
    assert mean_iou(torch.tensor([[0, 0, 0, 0]]), gt, num_parts=2, per_shape=True) == 1.0
    assert math.isclose(mean_iou(torch.tensor([[1, 1, 1, 1]]), gt, num_parts=2), 0.0)


# ---------------------------------------------------------------- per-part IoU


def test_part_ious_by_hand_and_mean_iou_is_their_mean():
    pred = torch.tensor([[0, 0, 1, 1, -1]])
    gt = torch.tensor([[0, 1, 1, 1, 2]])
    # label 0: inter 1, union 2; label 1: inter 2, union 3; label 2: inter 0, union 1; label 3 absent
    iou = part_ious(pred, gt, 4)
    torch.testing.assert_close(iou[:3], torch.tensor([0.5, 2 / 3, 0.0], dtype=torch.float64))
    assert math.isnan(iou[3])
    assert mean_iou(pred, gt, 4) == pytest.approx((0.5 + 2 / 3 + 0.0) / 3)


# ---------------------------------------------------------------- agreement of segmentation and boxes


def test_segment_box_distance_by_hand():
    # Box 0: half sizes 1 at the origin; box 1: half sizes (0.5, 0.5, 0.5) at (5, 0, 0).
    centers = torch.tensor([[[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]]])
    quats = torch.tensor([[[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]]])
    half = torch.tensor([[[1.0, 1.0, 1.0], [0.5, 0.5, 0.5]]])
    points = torch.tensor([[[0.5, 0.0, 0.0], [3.0, 0.0, 0.0], [5.0, 2.5, 0.0], [5.0, 0.0, 0.0]]])
    seg = torch.tensor([[0, 0, 1, 0]])
    # inside -> 0; (3,0,0) 2 outside box 0; (5,2.5,0) 2 above box 1; (5,0,0) sqrt(4^2) = 4 outside box 0
    d = segment_box_distance(points, seg, centers, quats, half)
    torch.testing.assert_close(d, torch.tensor([(0 + 2 + 2 + 4) / 4]))
    # a corner point: distance to the corner, not to a face
    corner = segment_box_distance(torch.tensor([[[2.0, 2.0, 2.0]]]), torch.tensor([[0]]), centers, quats, half)
    torch.testing.assert_close(corner, torch.tensor([math.sqrt(3.0)]))


def test_part_confusion_by_hand_and_its_diagonal_is_the_iou_intersection():
    gt = torch.tensor([[0, 0, 1, 1, 2], [0, 1, 1, 2, 2]])
    pred = torch.tensor([[0, 1, 1, 1, 2], [0, -1, 1, 1, 2]])  # -1: a cuboid without a label, not counted
    expected = torch.tensor([[2, 1, 0],
                             [0, 3, 0],
                             [0, 1, 2]])
    assert torch.equal(part_confusion(pred, gt, 3), expected)
    iou = part_ious(pred, gt, 3)
    union = expected.sum(dim=0) + expected.sum(dim=1) - expected.diag()
    union[1] += 1  # the unlabelled point of part 1 is in its union, not in the matrix
    torch.testing.assert_close(iou, expected.diag().double() / union.double())
    with pytest.raises(ValueError, match="same shape"):
        part_confusion(pred[:, :3], gt, 3)


def test_reassigned_fraction_by_hand():
    # Shape 0: points 0-2 allocated most to cuboid 0, point 3 to cuboid 1; only cuboid 0 exists -> 1/4.
    # Shape 1: every point's most allocated cuboid exists -> 0.
    W = torch.tensor([[[0.9, 0.1], [0.8, 0.2], [0.6, 0.4], [0.3, 0.7]],
                      [[0.1, 0.9], [0.2, 0.8], [0.6, 0.4], [0.3, 0.7]]])
    exists = torch.tensor([[True, False], [True, True]])
    torch.testing.assert_close(reassigned_fraction(W, exists), torch.tensor([0.25, 0.0]))
    # no cuboid exists: every point is reassigned
    torch.testing.assert_close(reassigned_fraction(W[:1], torch.tensor([[False, False]])), torch.tensor([1.0]))


@pytest.mark.parametrize("exists, match", [
    (torch.tensor([[1, 0]]), "bool"),
    (torch.tensor([[True, False, True]]), "shape"),
])
def test_reassigned_fraction_rejects_bad_existence(exists, match):
    with pytest.raises(ValueError, match=match):
        reassigned_fraction(torch.rand(1, 5, 2), exists)


def test_reassigned_fraction_rejects_bad_allocation():
    with pytest.raises(ValueError, match="allocation"):
        reassigned_fraction(torch.rand(5, 2), torch.tensor([[True, False]]))


def test_segment_box_distance_is_invariant_to_a_rigid_motion():
    g = torch.Generator().manual_seed(3)
    points = torch.randn(2, 50, 3, generator=g)
    centers = torch.randn(2, 4, 3, generator=g)
    quats = random_quaternions(2, 4, generator=g)
    half = torch.rand(2, 4, 3, generator=g) + 0.1
    seg = torch.randint(0, 4, (2, 50), generator=g)
    q = random_quaternions(1, 1, generator=g)
    R = quaternion_to_rotation_matrix(q)[0, 0]
    t = torch.tensor([0.3, -2.0, 1.0])
    moved = segment_box_distance(points @ R.T + t, seg, centers @ R.T + t, quaternion_multiply(q.expand(2, 4, 4), quats),
                                 half)
    torch.testing.assert_close(moved, segment_box_distance(points, seg, centers, quats, half), atol=1e-5, rtol=1e-5)


def test_segment_box_distance_rejects_bad_segmentations():
    centers, quats, half = unit_cube()
    points = torch.zeros(1, 3, 3)
    with pytest.raises(ValueError, match="segmentation indices must lie in"):
        segment_box_distance(points, torch.tensor([[0, 1, 0]]), centers, quats, half)
    with pytest.raises(ValueError, match="segmentation must be integer indices of shape"):
        segment_box_distance(points, torch.zeros(1, 3), centers, quats, half)
    with pytest.raises(ValueError, match="segmentation must be integer indices of shape"):
        segment_box_distance(points, torch.tensor([[0, 0]]), centers, quats, half)


def test_part_concision_by_hand():
    # one shape: two legs (instances 0 and 1, part 1) under one cuboid, a seat (instance 2, part 0) cut in two
    gt = torch.tensor([[1] * 8 + [0] * 10])
    inst = torch.tensor([[0] * 4 + [1] * 4 + [2] * 10])
    seg = torch.tensor([[0] * 8 + [1] * 5 + [2] * 5])
    c = part_concision(seg, gt, inst, 2)
    torch.testing.assert_close(c["cuboids_per_instance"], torch.tensor([2.0, 1.0], dtype=torch.float64))
    torch.testing.assert_close(c["instances_per_cuboid"], torch.tensor([1.0, 2.0], dtype=torch.float64))


def test_part_concision_counts_only_shares_of_at_least_the_threshold_and_nan_for_absent_parts():
    # a leg of 10 points: 8 in cuboid 0, 2 (20 %) in cuboid 1, so 2 cuboids at share 0.2 and 1 at share 0.25
    gt = torch.tensor([[1] * 10])
    inst = torch.zeros(1, 10, dtype=torch.long)
    seg = torch.tensor([[0] * 8 + [1] * 2])
    assert part_concision(seg, gt, inst, 3)["cuboids_per_instance"][1] == 2.0
    c = part_concision(seg, gt, inst, 3, share=0.25)
    assert c["cuboids_per_instance"][1] == 1.0
    assert c["cuboids_per_instance"][0].isnan() and c["instances_per_cuboid"][2].isnan()


def test_part_concision_is_invariant_to_relabelling_cuboids_and_instances():
    g = torch.Generator().manual_seed(0)
    gt = torch.randint(0, 3, (4, 200), generator=g)
    inst = gt * 5 + torch.randint(0, 5, (4, 200), generator=g)  # each instance within one part
    seg = torch.randint(0, 7, (4, 200), generator=g)
    a = part_concision(seg, gt, inst, 3)
    b = part_concision(torch.randperm(7, generator=g)[seg], gt, torch.randperm(15, generator=g)[inst], 3)
    for key in a:
        torch.testing.assert_close(a[key], b[key])


@pytest.mark.parametrize("kwargs, match", [
    ({"instances": torch.zeros(1, 5, dtype=torch.long)}, "same shape"),
    ({"instances": -torch.ones(1, 4, dtype=torch.long)}, "non-negative"),
    ({"share": 0.0}, "share must be"),
    ({"num_parts": 1}, "part_labels must lie"),
    ({"segmentation": torch.zeros(1, 4)}, "integer indices"),
])
def test_part_concision_rejects_bad_input(kwargs, match):
    args = {"segmentation": torch.zeros(1, 4, dtype=torch.long), "part_labels": torch.tensor([[0, 1, 1, 0]]),
            "instances": torch.zeros(1, 4, dtype=torch.long), "num_parts": 2}
    with pytest.raises(ValueError, match=match):
        part_concision(**{**args, **kwargs})
