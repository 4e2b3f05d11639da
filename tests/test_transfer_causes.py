"""Tests of experiments/transfer_causes.py and its shape_changes.py: the perturbations do what they say, its label-transfer recount is the
library's, its statistics read the procedural shapes right, and the README shows the table of its results."""

from __future__ import annotations

import importlib.util
import json
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from cuboidlib.dataset import ShapeSet
from cuboidlib.evaluation import label_transfer_split, segmentation_scores
from cuboidlib.geometry import Cuboids
from cuboidlib.results import AbstractionBatch
from cuboidlib.shapes import make_shape
from cuboidlib.solids import union_sdf

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "experiments" / "transfer_causes.py"


@pytest.fixture(scope="module")
def tc():
    spec = importlib.util.spec_from_file_location("transfer_causes", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up while they are made
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(SCRIPT.parent))
    yield module
    sys.modules.pop(spec.name, None)


@pytest.fixture(scope="module")
def sc(tc):
    """experiments/shape_changes.py, as transfer_causes imported it (one copy of its classes)."""
    return sys.modules["shape_changes"]


# The script perturbs the committed networks' test shapes: generator version 1 (the version their configs mean).


def _change(sc, name):
    return next(c for c in sc.CHANGES if c.name == name)


def _own_distance(solids, points, index):
    return np.array([abs(float(solids[i].sdf(p[None])[0])) for p, i in zip(points, index)])


def test_every_face_samples_the_faces_inside_the_union_too(sc):
    shape = make_shape("airplane", 3, 512, 0, version=1)  # wing roots and the fin's root lie inside the fuselage
    rng = np.random.default_rng(0)
    p, nn, idx = sc.sample_every_face(shape.parts, 2000, rng)
    assert p.shape == (2000, 3) and np.allclose(np.linalg.norm(nn, axis=1), 1, atol=1e-6)
    assert _own_distance(shape.parts, p, idx).max() < 1e-6  # on its own solid's surface
    inside = union_sdf([s for s in shape.parts], p) < -1e-4  # ... and some of them inside another solid
    assert 0.02 < inside.mean() < 0.5
    out = _change(sc, "every_face").apply(shape, rng)
    assert (out.labels == np.array([s.label for s in shape.parts])[out.instances]).all()
    assert out.reference is shape.points


@pytest.mark.parametrize("name", ["resampled", "density_ramp4", "density_triangles", "nose_propeller",
                                  "wing_span1.3", "tail_x1.4"])
def test_resampling_changes_keep_to_the_outer_surface(sc, name):
    shape = make_shape("airplane", 5, 256, 0, version=1)
    out = _change(sc, name).apply(shape, np.random.default_rng(1))
    assert out.points.shape == (256, 3) and out.labels.shape == (256,) and out.instances.shape == (256,)
    if name in ("resampled", "density_ramp4", "density_triangles"):
        assert np.abs(union_sdf(shape.parts, out.points)).max() < 1e-6
        assert (out.labels == np.array([s.label for s in shape.parts])[out.instances]).all()


def test_density_ramp_is_four_times_denser_at_one_end(sc):
    shape = make_shape("table", 0, 256, 0)
    rng = np.random.default_rng(0)
    direction = np.random.default_rng(0).standard_normal(3)  # the first draw of the same generator: _ramp's direction
    direction /= np.linalg.norm(direction)
    out = sc._thinned(shape.parts, 4000, rng, lambda p: 1.0 + 3.0 * (p @ direction - (p @ direction).min())
                      / np.ptp(p @ direction))
    plain = sc._outer(shape.parts, 4000, np.random.default_rng(1)).points
    t, t0 = out.points @ direction, plain @ direction
    lo, hi = np.quantile(t0, [0.25, 0.75])
    ratio = ((t > hi).mean() / (t0 > hi).mean()) / ((t < lo).mean() / (t0 < lo).mean())
    assert 2.0 < ratio < 4.5


def test_stretch_keeps_normals_perpendicular_to_the_surface(sc):
    rng = np.random.default_rng(0)
    n = rng.standard_normal((50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t = np.cross(n, rng.standard_normal((50, 3)))  # tangents
    shape = make_shape("chair", 0, 50, 0)
    shape.normals = n
    out = sc._stretch(1, 1.25)(shape, rng)
    a = np.diag([1.0, 1.25, 1.0])
    assert np.allclose(out.points, shape.points @ a.T) and np.allclose(out.reference, out.points)
    assert np.abs(np.einsum("ij,ij->i", out.normals, t @ a.T)).max() < 1e-9
    assert np.allclose(np.linalg.norm(out.normals, axis=1), 1)


def test_tilt_turns_by_the_angle_either_way(sc):
    shape = make_shape("chair", 1, 64, 0)
    signs = set()
    for seed in range(8):
        out = sc._tilt(sc.rotation_x, 10)(shape, np.random.default_rng(seed))
        r = np.linalg.lstsq(shape.points, out.points, rcond=None)[0].T
        angle = math.degrees(math.atan2(r[2, 1], r[1, 1]))
        assert abs(abs(angle) - 10) < 1e-6
        signs.add(angle > 0)
    assert signs == {True, False}


def test_thigh_labels_move_body_points_over_the_hips_to_the_legs(sc):
    shape = make_shape("animal", 2, 1024, 0, version=1)
    out = sc._thigh_labels(shape, np.random.default_rng(0))
    changed = out.labels != shape.labels
    assert changed.any() and (shape.labels[changed] == 0).all() and (out.labels[changed] == 2).all()
    assert out.points is shape.points and out.normals is shape.normals
    body = shape.points[shape.labels == 0]
    assert shape.points[changed, 1].max() <= body[:, 1].min() + 0.6 * np.ptp(body[:, 1]) + 1e-9


@pytest.mark.parametrize("angle", [60, -75, None])
def test_turned_tail_points_at_its_angle_and_is_long_enough(sc, angle):
    for index in range(6):
        shape = make_shape("animal", index, 256, 0, version=1)
        before = [s for s in shape.parts if s.label == 3]
        parts = sc.turned_tail(shape.parts, angle, ground=-10.0)  # no ground in the way
        tails = [s for s in parts if s.label == 3]
        assert len(parts) == len(shape.parts) and np.allclose(tails[0].a, before[0].a)
        v, v0 = tails[-1].b - tails[0].a, before[-1].b - before[0].a
        turned = math.degrees(math.atan2(v[1], -v[2]))
        assert turned == pytest.approx(math.degrees(math.atan2(v0[1], -v0[2])) if angle is None else angle, abs=1e-6)
        length = 2 * shape.parts[0].radii[2]
        assert np.linalg.norm(v) == pytest.approx(max(np.linalg.norm(v0), 0.3 * length))
        ground = float(shape.points[:, 1].min())
        low = min(min(c.a[1], c.b[1]) - c.radius for c in
                  [s for s in sc.turned_tail(shape.parts, -75, ground) if s.label == 3])
        assert low >= ground - 1e-9


def test_tail_hanging_is_seen(sc):
    for index in range(6):
        shape = make_shape("animal", index, 2048, 0, version=1)
        out = _change(sc, "tail_hanging").apply(shape, np.random.default_rng(0))
        tail = out.points[out.labels == 3]
        root = next(s for s in shape.parts if s.label == 3).a
        assert len(tail) >= 5 and tail[:, 1].min() < root[1] - 0.1


def test_nose_propeller_replaces_the_engines_at_the_nose(tc, sc):
    shape = make_shape("airplane", 4, 1024, 0, version=1)  # this one has engines under its wings
    assert (shape.labels == 3).sum() > 20
    out = sc._nose_propeller(shape, np.random.default_rng(0))
    engine = out.points[out.labels == 3]
    assert len(engine) > 0 and engine[:, 2].min() > out.points[out.labels == 0][:, 2].max() - 0.05
    assert tc.engine_layout(out.points, out.labels) == "nose1"


def test_engine_layout_reads_the_procedural_structures(tc):
    expected = {"engines0": "none", "engines2": "wing2", "engines4": "wing4", "engines2-rear": "rear2"}
    agree = total = 0
    for index in range(24):
        shape = make_shape("airplane", index, 1024, 0, version=1)
        kind = shape.structure.split("+")[0]
        total += 1
        agree += tc.engine_layout(shape.points, shape.labels) == expected[kind]
    assert agree >= 0.8 * total


def test_transfer_miou_is_the_librarys(tc):
    g = torch.Generator().manual_seed(0)
    seg = torch.randint(0, 6, (20, 64), generator=g)
    labels = torch.randint(0, 4, (20, 64), generator=g)
    labels[:, :16] = seg[:, :16] % 4  # some agreement
    shapes = ShapeSet(torch.zeros(20, 64, 3), torch.zeros(20, 64, 3), labels, torch.arange(20), None, 4)
    cub = Cuboids(torch.zeros(20, 6, 3), torch.tensor([1.0, 0, 0, 0]).repeat(20, 6, 1), torch.full((20, 6, 3), 0.1),
                  torch.ones(20, 6, dtype=torch.bool))
    pred = AbstractionBatch(cub, seg)
    counts = tc.slot_part_counts(shapes, seg, 6)
    labelled, scored = (t.numpy() for t in label_transfer_split(20, 0.2, 0))
    assert tc.transfer_miou(counts, labelled, scored) == pytest.approx(segmentation_scores(shapes, pred)["miou"])
    level, delta = tc.bootstrap(counts, counts, draws=50)
    assert level > 0 and delta == 0


def test_readme_shows_the_tables_of_the_results(tc):
    doc = json.loads((ROOT / "experiments" / "results" / "transfer_causes.json").read_text())
    assert doc["settings"]["shapes"] >= 50 and set(doc["categories"]) == {"chair", "table", "airplane", "animal"}
    for data in doc["categories"].values():
        assert "real" in data and data["rows"]["clean"]["miou_delta"] == 0
    readme = (ROOT / "experiments" / "README.md").read_text()
    blocks = {"causes": tc.table(doc), "causes-airplane": tc.parts_table(doc, "airplane"),
              "causes-animal": tc.parts_table(doc, "animal"), "causes-stats": tc.stats_table(doc)}
    for name, lines in blocks.items():
        block = re.search(rf"<!-- {name}:start -->\n(.*?)\n<!-- {name}:end -->", readme, re.S)
        assert block is not None, name
        assert block.group(1).strip() == "\n".join(lines), name


def test_readme_shows_the_generator_versions_table_and_version_2_moves_towards_the_real_meshes(tc):
    doc = json.loads((ROOT / "experiments" / "results" / "transfer_causes_generator.json").read_text())
    readme = (ROOT / "experiments" / "README.md").read_text()
    block = re.search(r"<!-- generator:start -->\n(.*?)\n<!-- generator:end -->", readme, re.S)
    assert block is not None and block.group(1).strip() == "\n".join(doc["table"])
    assert tc.generator_table(doc["found"]) == doc["table"]
    stats = doc["found"]["animal"]["stats"]
    median = {k: {v: np.nanmedian(stats[k][v]) for v in ("real", "v1", "v2")} for k in stats}
    for key in ("leg_labels_up_the_body", "tail_angle_deg", "tail_length_over_body_length", "share_body"):
        assert abs(median[key]["v2"] - median[key]["real"]) < abs(median[key]["v1"] - median[key]["real"]), key
    layouts = doc["found"]["airplane"]["layouts"]
    assert "nose1" not in layouts["v1"] and 0.15 < layouts["v2"]["nose1"] / sum(layouts["v2"].values()) < 0.35


def test_generator_stats_reads_both_versions(tc):
    doc = json.loads((ROOT / "experiments" / "results" / "transfer_causes.json").read_text())
    found = tc.generator_stats(doc, 5)
    assert set(found) == {"airplane", "animal"}
    for category, data in found.items():
        for values in data["stats"].values():
            assert len(values["v1"]) == len(values["v2"]) == 5 and len(values["real"]) >= 2
    lines = tc.generator_table(found)
    assert len(lines) == 2 + sum(len(d["stats"]) for d in found.values()) + 1


def test_buried_finds_the_points_inside_other_solids_and_the_share_is_thinned(sc):
    shape = make_shape("airplane", 3, 512, 0, version=1)
    rng = np.random.default_rng(0)
    p, _, idx = sc.sample_every_face(shape.parts, 3000, rng)
    inside = sc.buried(shape.parts, p, idx)
    assert np.array_equal(inside, union_sdf(shape.parts, p) < -1e-4)  # only another solid can hold a point inside
    out = sc._every_face_at_share(shape, rng, 0.05)
    assert out.inside.mean() == pytest.approx(0.05, abs=1 / 512)
    assert np.array_equal(out.inside, sc.buried(shape.parts, out.points, out.instances))
    full = sc._every_face_at_share(shape, rng, 1.0)  # at most what every-face sampling gives
    assert full.inside.mean() == pytest.approx(inside.mean(), abs=0.03)


def test_enclosed_share_tells_interior_points_from_outer_ones(tc, sc):
    shape = make_shape("airplane", 3, 2048, 0, version=1)
    rng = np.random.default_rng(0)
    p, _, idx = sc.sample_every_face(shape.parts, 2048, rng)
    inside = sc.buried(shape.parts, p, idx)
    order = np.argsort(~inside)  # interior points first: the estimate reads the first 512
    assert tc.enclosed_share(shape.points) < 0.03
    assert tc.enclosed_share(p[order]) > 0.15


def test_landing_gear_adds_wheels_below_the_fuselage(sc):
    shape = make_shape("airplane", 1, 1024, 0, version=1)  # no engines
    out = sc._landing_gear(shape, np.random.default_rng(0))
    axis, _, rf = sc._fuselage(shape)
    below = out.points[:, 1] < axis[1] - 1.3 * rf
    assert below.sum() > 5 and (out.labels[below & (np.abs(out.points[:, 0] - axis[0]) < 2.5 * rf)] == 0).all()


def test_thicker_fuselage_keeps_its_length(sc):
    for index in range(4):  # capsule and cylinder fuselages
        shape = make_shape("airplane", index, 2048, 0, version=1)
        out = sc._fuselage_scaled(1.4)(shape, np.random.default_rng(0))
        before, after = shape.points[shape.labels == 0], out.points[out.labels == 0]
        assert np.ptp(after[:, 2]) == pytest.approx(np.ptp(before[:, 2]), rel=0.03)
        assert np.ptp(after[:, 1]) == pytest.approx(1.4 * np.ptp(before[:, 1]), rel=0.08)
