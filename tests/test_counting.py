"""The fit's count chosen by the Chamfer distance (cuboidlib.counting): splits, merges, their bookkeeping and checks."""

import math

import pytest
import torch

from cuboidlib.counting import CountConfig, choose_count
from cuboidlib.fitting import FitConfig, fit_cuboids
from cuboidlib.geometry import sample_cuboid_surfaces
from cuboidlib.normalization import normalize
from cuboidlib.shapes import make_shape

IDENTITY = torch.tensor([1.0, 0.0, 0.0, 0.0])


def _box_points(center, half, n, seed):
    g = torch.Generator().manual_seed(seed)
    return sample_cuboid_surfaces(torch.tensor([[center]], dtype=torch.float32), IDENTITY[None, None],
                                  torch.tensor([[half]], dtype=torch.float32), n, generator=g).points[0]


def _slots(m, boxes):
    """M slots: the given (center, half) boxes first (existing), the rest free."""
    centers, halves = torch.zeros(m, 3), torch.full((m, 3), 0.01)
    for i, (c, h) in enumerate(boxes):
        centers[i], halves[i] = torch.tensor(c), torch.tensor(h)
    exists = torch.arange(m) < len(boxes)
    return centers, IDENTITY.repeat(m, 1), halves, exists


def _two_legs(seed=0):
    """Two separated thin boxes ("legs"), 300 surface points each, in a shape of diagonal about 1."""
    a = _box_points((-0.3, 0.0, 0.0), (0.04, 0.3, 0.04), 300, seed)
    b = _box_points((0.3, 0.0, 0.0), (0.04, 0.3, 0.04), 300, seed + 1)
    return torch.cat([a, b])


def test_one_cuboid_over_two_separate_legs_is_split_into_one_each():
    points = _two_legs()
    centers, quats, halves, exists = _slots(4, [((0.0, 0.0, 0.0), (0.34, 0.3, 0.04))])
    labels = torch.zeros(len(points), dtype=torch.long)
    c, q, s, e, new, record = choose_count(points, centers, quats, halves, exists, labels)
    assert int(e.sum()) == 2 and (record.before, record.after, record.splits) == (1, 2, 1)
    assert record.chamfer_after < 0.1 * record.chamfer_before
    assert torch.equal(new[:300].unique(), new[:300][:1]) and torch.equal(new[300:].unique(), new[300:][:1])
    assert int(new[0]) != int(new[300]), "each leg its own cuboid"
    torch.testing.assert_close(s[e].sort(dim=0).values, torch.tensor([[0.04, 0.3, 0.04]] * 2), atol=0.01, rtol=0)


def test_one_box_cut_into_two_slots_is_merged_back():
    points = _box_points((0.0, 0.0, 0.0), (0.3, 0.1, 0.2), 600, 3)
    left = points[:, 0] < 0
    centers, quats, halves, exists = _slots(4, [((-0.15, 0.0, 0.0), (0.15, 0.1, 0.2)), ((0.15, 0.0, 0.0), (0.15, 0.1, 0.2))])
    labels = torch.where(left, 0, 1)
    c, q, s, e, new, record = choose_count(points, centers, quats, halves, exists, labels)
    assert (record.before, record.after, record.merges, record.splits) == (2, 1, 1, 0)
    assert new.unique().numel() == 1 and bool(e[new[0]])
    torch.testing.assert_close(s[e][0], torch.tensor([0.3, 0.1, 0.2]), atol=0.01, rtol=0)
    assert record.chamfer_after <= record.chamfer_before * (1 + CountConfig().merge_tolerance)


@pytest.mark.parametrize("seed", range(2))
def test_the_record_adds_up_and_every_point_keeps_an_existing_cuboid(seed):
    shape = make_shape("table", 10 + seed, n_points=1024)
    p, _, _ = normalize(torch.as_tensor(shape.points, dtype=torch.float32))
    fit = fit_cuboids(p, torch.as_tensor(shape.normals), FitConfig(steps=60, seed=seed))
    c = fit.cuboids
    out = choose_count(p, c.centers[0], c.quaternions[0], c.half_sizes[0], c.exists[0], fit.labels[0],
                       CountConfig(seed=seed))
    *_, exists, labels, record = out
    assert record.after == record.before + record.splits - record.merges == int(exists.sum())
    assert bool(exists[labels].all())
    assert record.chamfer_after <= record.chamfer_before * (1 + CountConfig().merge_tolerance)
    again = choose_count(p, c.centers[0], c.quaternions[0], c.half_sizes[0], c.exists[0], fit.labels[0],
                         CountConfig(seed=seed))
    assert all(torch.equal(x, y) for x, y in zip(out[:5], again[:5])), "deterministic"
    torch.testing.assert_close(torch.linalg.vector_norm(out[1], dim=-1), torch.ones(out[1].shape[0]))


def test_the_fit_with_the_chamfer_count_keeps_the_legs_the_paper_rule_drops():
    shape = make_shape("table", 18, n_points=2048)  # four round legs
    p, _, _ = normalize(torch.as_tensor(shape.points, dtype=torch.float32))
    n = torch.as_tensor(shape.normals)
    portion = fit_cuboids(p, n, FitConfig(steps=150))
    chamfer = fit_cuboids(p, n, FitConfig(steps=150, count="chamfer"))
    assert portion.count is None and len(chamfer.count) == 1
    record = chamfer.count[0]
    assert record.before == int(portion.exists.sum()) and record.after == int(chamfer.exists.sum()) > record.before
    assert record.chamfer_after < 0.7 * record.chamfer_before
    torch.testing.assert_close(chamfer.W.sum(dim=-1), torch.ones(1, 2048))
    assert torch.equal(chamfer.W.argmax(dim=-1), chamfer.labels)


def test_bad_settings_and_inputs_are_refused_by_name():
    with pytest.raises(ValueError, match="merge_tolerance < min_gain"):
        CountConfig(min_gain=0.01, merge_tolerance=0.02)
    with pytest.raises(ValueError, match="min_gain"):
        CountConfig(min_gain=math.nan)
    with pytest.raises(ValueError, match="search_points must be an integer >= 1"):
        CountConfig(search_points=0)
    with pytest.raises(ValueError, match="count must be one of"):
        FitConfig(count="share")
    points = _two_legs()
    centers, quats, halves, exists = _slots(4, [((0.0, 0.0, 0.0), (0.34, 0.3, 0.04))])
    with pytest.raises(ValueError, match="existing slot"):
        choose_count(points, centers, quats, halves, exists, torch.full((len(points),), 2))
    with pytest.raises(ValueError, match="labels must be"):
        choose_count(points, centers, quats, halves, exists, torch.zeros(5, dtype=torch.long))
    with pytest.raises(TypeError, match="CountConfig"):
        choose_count(points, centers, quats, halves, exists, torch.zeros(len(points), dtype=torch.long), {"min_gain": 0.1})
