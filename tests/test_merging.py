"""Merging the pieces of one part (cuboidlib.merging): analytic growths, the greedy loop, invariances, bad inputs."""

import math

import pytest
import torch

from cuboidlib.geometry import Cuboids
from cuboidlib.merging import merge_growth, merge_split_cuboids
from cuboidlib.results import AbstractionBatch
from cuboidlib.rotations import quaternion_multiply, quaternion_to_rotation_matrix, random_quaternions

F64 = dict(dtype=torch.float64)
#: a leg (half sizes 0.02, 0.1, 0.02) cut in two halves end to end, and a whole leg 0.5 away along x
LEGS = [([0, 0.1, 0], [0.02, 0.1, 0.02]), ([0, -0.1, 0], [0.02, 0.1, 0.02]), ([0.5, 0, 0], [0.02, 0.2, 0.02])]


def _batch(boxes, points_per_box=None):
    """Axis-aligned boxes (center, half size) as a batch of one shape; box k holds points_per_box[k] points."""
    centers = torch.tensor([c for c, _ in boxes], **F64)[None]
    half = torch.tensor([h for _, h in boxes], **F64)[None]
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0], **F64).repeat(1, len(boxes), 1)
    counts = points_per_box or [8] * len(boxes)
    labels = torch.arange(len(boxes)).repeat_interleave(torch.tensor(counts))[None]
    return AbstractionBatch(Cuboids(centers, quats, half, torch.ones(1, len(boxes), dtype=torch.bool)), labels)


def _growth(batch, pad=0.0):
    c = batch.cuboids
    return merge_growth(c.centers[0], c.rotation_matrices()[0], c.half_sizes[0], pad)


def test_growth_by_hand():
    growth, frame = _growth(_batch(LEGS))
    # the halves: the box around both, 0.04 x 0.4 x 0.04, is the sum of two 0.04 x 0.2 x 0.04 boxes
    torch.testing.assert_close(growth[0, 1], torch.tensor(0.0, **F64))
    # a half and the far leg: x from -0.02 to 0.52, y from -0.2 to 0.2 (the far leg), z 0.04
    union, own = 0.54 * 0.4 * 0.04, 0.04 * 0.2 * 0.04 + 0.04 * 0.4 * 0.04
    torch.testing.assert_close(growth[0, 2], torch.tensor(union / own - 1, **F64))
    assert torch.equal(growth, growth.T) and growth.diagonal().isinf().all()
    assert frame[0, 1] in (0, 1) and frame[1, 2] in (1, 2)
    # the padding adds to every extent
    padded, _ = _growth(_batch(LEGS), pad=0.01)
    torch.testing.assert_close(padded[0, 1], torch.tensor((0.05 * 0.41 * 0.05) / (2 * 0.05 * 0.21 * 0.05) - 1, **F64))


def test_a_turned_cuboid_is_measured_in_the_frame_that_fits_best():
    # two equal boxes along x, 0.1 apart; the second's long side is its local y, turned a quarter turn about z
    half = 0.5 ** 0.5
    c = Cuboids(torch.tensor([[[0.0, 0, 0], [0.3, 0, 0]]], **F64),
                torch.tensor([[[1.0, 0, 0, 0], [half, 0, 0, half]]], **F64),
                torch.tensor([[[0.1, 0.05, 0.05], [0.05, 0.1, 0.05]]], **F64))
    growth, frame = merge_growth(c.centers[0], c.rotation_matrices()[0], c.half_sizes[0], 0.0)
    # in either frame the box around both spans x in [-0.1, 0.4]: 0.5 x 0.1 x 0.1 against 2 x 0.2 x 0.1 x 0.1
    torch.testing.assert_close(growth[0, 1], torch.tensor(0.5 * 0.1 * 0.1 / (2 * 0.2 * 0.1 * 0.1) - 1, **F64))


def test_two_halves_merge_and_separate_legs_do_not():
    batch = _batch(LEGS, points_per_box=[5, 9, 8])
    merged = merge_split_cuboids(batch)
    # the halves merge into the slot of the one that held more points (slot 1); the far leg stays
    assert merged.cuboids.exists.tolist() == [[False, True, True]]
    assert merged.labels[0, :14].eq(1).all() and merged.labels[0, 14:].eq(2).all()
    torch.testing.assert_close(merged.cuboids.centers[0, 1], torch.zeros(3, **F64))
    torch.testing.assert_close(merged.cuboids.half_sizes[0, 1], torch.tensor([0.02, 0.2, 0.02], **F64))
    torch.testing.assert_close(merged.cuboids.centers[0, 2], batch.cuboids.centers[0, 2])
    assert merged.W is None and merged.exist_probs is None  # they describe the cuboids before merging
    again = merge_split_cuboids(merged)  # nothing is left to merge
    assert torch.equal(again.labels, merged.labels) and torch.equal(again.cuboids.exists, merged.cuboids.exists)


def test_the_threshold_decides():
    batch = _batch([([0, 0.1, 0], [0.02, 0.1, 0.02]), ([0, -0.15, 0], [0.02, 0.1, 0.02])])  # a gap of 0.05
    diagonal = float(torch.tensor([0.04, 0.45, 0.04]).norm())  # pad is a share of the box around all cuboids
    growth = float(_growth(batch, pad=0.01 * diagonal)[0][0, 1])
    assert 0 < growth < 1
    assert merge_split_cuboids(batch, max_growth=growth * 0.99, pad=0.01).cuboids.exists.all()
    assert merge_split_cuboids(batch, max_growth=growth * 1.01, pad=0.01).num_existing().tolist() == [1]
    # a seat and its back (an L) merge only under a very large threshold
    chair = _batch([([0, 0, 0], [0.25, 0.03, 0.25]), ([0, 0.3, -0.22], [0.25, 0.3, 0.03])])
    assert float(_growth(chair, pad=0.01)[0][0, 1]) > 1
    assert merge_split_cuboids(chair).cuboids.exists.all()
    assert merge_split_cuboids(chair, max_growth=100.0).num_existing().tolist() == [1]


def test_rotation_translation_and_scale_do_not_change_the_merges():
    g = torch.Generator().manual_seed(0)
    batch = _batch(LEGS + [([0.5, 0.35, 0.2], [0.02, 0.15, 0.02])], points_per_box=[5, 9, 8, 7])
    base = merge_split_cuboids(batch)
    q = random_quaternions(1, generator=g).double()
    R = quaternion_to_rotation_matrix(q)[0]
    c = batch.cuboids
    scale, shift = 7.5, torch.tensor([1.0, -2.0, 3.0], **F64)
    turned = quaternion_multiply(q.expand(4, 4), c.quaternions[0])[None]
    moved = AbstractionBatch(Cuboids(scale * c.centers @ R.T + shift, turned, scale * c.half_sizes, c.exists),
                             batch.labels)
    out = merge_split_cuboids(moved)
    assert torch.equal(out.labels, base.labels) and torch.equal(out.cuboids.exists, base.cuboids.exists)
    torch.testing.assert_close(out.cuboids.half_sizes, scale * base.cuboids.half_sizes)
    torch.testing.assert_close(out.cuboids.centers, scale * base.cuboids.centers @ R.T + shift)


def test_shapes_merge_independently_and_labels_always_name_existing_cuboids():
    g = torch.Generator().manual_seed(1)
    n, m = 3, 6
    exists = torch.rand(n, m, generator=g) < 0.8
    exists[:, 0] = True
    choices = [torch.nonzero(e)[:, 0] for e in exists]
    labels = torch.stack([ch[torch.randint(0, len(ch), (40,), generator=g)] for ch in choices])
    cuboids = Cuboids(torch.rand(n, m, 3, generator=g), random_quaternions(n * m, generator=g).view(n, m, 4),
                      0.05 + 0.2 * torch.rand(n, m, 3, generator=g), exists)
    batch = AbstractionBatch(cuboids, labels, W=torch.rand(n, 40, m, generator=g))
    out = merge_split_cuboids(batch, max_growth=1.0)
    assert out.cuboids.exists.gather(1, out.labels).all()
    assert not (out.cuboids.exists & ~exists).any()  # a cuboid that did not exist never comes back
    for i in range(n):
        one = merge_split_cuboids(batch.item_batch(i), max_growth=1.0)
        assert torch.equal(one.labels[0], out.labels[i]) and torch.equal(one.cuboids.exists[0], out.cuboids.exists[i])
    assert merge_split_cuboids(batch, max_growth=math.inf).num_existing().tolist() == [1, 1, 1]
    no_labels = merge_split_cuboids(AbstractionBatch(cuboids), max_growth=math.inf)  # cuboids alone merge too
    assert no_labels.labels is None and no_labels.num_existing().tolist() == [1, 1, 1]


def test_bad_inputs_are_named():
    batch = _batch(LEGS)
    c = batch.cuboids
    with pytest.raises(ValueError, match=r"expected centers \(M, 3\), R \(M, 3, 3\) and half_sizes \(M, 3\)"):
        merge_growth(c.centers[0], c.rotation_matrices()[0][:2], c.half_sizes[0], 0.0)
    with pytest.raises(ValueError, match="pad must be a number >= 0"):
        merge_growth(c.centers[0], c.rotation_matrices()[0], c.half_sizes[0], -1.0)
    with pytest.raises(ValueError, match="half_sizes positive"):
        merge_growth(c.centers[0], c.rotation_matrices()[0], 0 * c.half_sizes[0], 0.0)
    with pytest.raises(TypeError, match="AbstractionBatch"):
        merge_split_cuboids(batch.cuboids)
    with pytest.raises(ValueError, match="max_growth must be a number >= 0"):
        merge_split_cuboids(batch, max_growth=-0.1)
    with pytest.raises(ValueError, match="pad must be a number >= 0"):
        merge_split_cuboids(batch, pad=float("nan"))
    with pytest.raises(ValueError, match=r"labels must be \(B, N\) with B = 1"):
        merge_split_cuboids(AbstractionBatch(batch.cuboids, batch.labels[0]))
    gone = AbstractionBatch(Cuboids(c.centers, c.quaternions, c.half_sizes, torch.tensor([[True, False, True]])),
                            batch.labels)
    with pytest.raises(ValueError, match="must name an existing cuboid"):
        merge_split_cuboids(gone)
