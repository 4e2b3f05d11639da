"""Unusual and hostile inputs: a correct answer or a clear ValueError/TypeError, never a silent wrong one.

The first part keeps one reproduction per reported case; the second runs property-based cases
(Hypothesis) over the public functions, each checked against a float64 reference where one exists.
"""

import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cuboidlib
from cuboidlib import _checks, io
from cuboidlib.applications import (abstract_shapes, generate_shapes, interpolate_codes, latent_distance,
                                    load_trained_model, resolve_checkpoint)
from cuboidlib.baseline import fit_cluster_boxes
from cuboidlib.checkpoint import load_checkpoint, load_model
from cuboidlib.cli import main
from cuboidlib.distance import chamfer_distance
from cuboidlib.export import write_segmented_point_cloud
from cuboidlib.fitting import FitConfig, fit_cuboids, tighten_cuboids
from cuboidlib.metrics import mean_iou, normal_consistency, part_ious
from cuboidlib.normalization import denormalize, normalize
from cuboidlib.normals import MAX_POINTS, estimate_normals
from cuboidlib.shapes import ShapeCollection, make_collection, make_shape
from cuboidlib.train_config import TrainConfig

CHECKPOINTS = Path(__file__).resolve().parents[1] / "data_samples" / "checkpoints"


@pytest.fixture(scope="module")
def chair():
    return make_shape("chair", 2, n_points=512)


# ------------------------------------------------------------------------------ magnitudes


def test_fit_far_beyond_unit_scale_gives_finite_cuboids_in_the_input_frame(chair):
    points = torch.as_tensor(chair.points) * 1e30
    r = fit_cuboids(points, torch.as_tensor(chair.normals), FitConfig(steps=30))
    c = r.cuboids
    assert torch.isfinite(c.centers).all() and torch.isfinite(c.half_sizes).all()
    assert float(c.half_sizes[c.exists].amax()) > 1e28  # in the input's units


def test_normalize_and_denormalize_refuse_what_they_cannot_represent():
    with pytest.raises(ValueError, match="too large for float32"):
        normalize(torch.tensor([[-3e38, -3e38, 0.0], [3e38, 3e38, 0.0]]))
    unit = torch.rand(10, 3)
    with pytest.raises(ValueError, match="scale contains 1 NaN"):
        denormalize(unit, torch.zeros(3), torch.tensor(float("nan")))
    with pytest.raises(ValueError, match="overflow float32"):
        denormalize(unit + 1, torch.zeros(3), torch.tensor(3e38))


def test_writers_refuse_coordinates_and_labels_their_format_cannot_hold(tmp_path, chair):
    big = chair.points.astype(np.float64) * 1e39
    for suffix in (".ply", ".npy"):
        with pytest.raises(ValueError, match="do not fit the float32"):
            io.write_point_cloud(tmp_path / f"big{suffix}", big)
    io.write_point_cloud(tmp_path / "big.txt", big)  # text keeps them, for other tools; cuboidlib reads float32
    with pytest.raises(ValueError, match="big.txt: coordinates up to .* exceed the float32 range"):
        io.read_point_cloud(tmp_path / "big.txt")
    labels = np.zeros(len(chair.points), np.int64)
    labels[0] = 2**40
    with pytest.raises(ValueError, match="labels must lie in"):
        io.write_point_cloud(tmp_path / "l.ply", chair.points, labels=labels)
    labels[0] = 2**25  # exact in int32, not in the float32 of .npy
    io.write_point_cloud(tmp_path / "l.ply", chair.points, labels=labels)
    assert io.read_point_cloud(tmp_path / "l.ply").labels[0] == 2**25
    with pytest.raises(ValueError, match="labels must lie in"):
        io.write_point_cloud(tmp_path / "l.npy", chair.points, chair.normals, labels=labels)
    with pytest.raises(ValueError, match="whole numbers"):
        io.write_point_cloud(tmp_path / "f.ply", chair.points, labels=np.full(len(chair.points), 1.5))


def test_segmented_cloud_with_huge_labels_is_quick_and_bounded(tmp_path, chair):
    labels = np.arange(len(chair.points), dtype=np.int64) * 1_000_003
    start = time.perf_counter()
    write_segmented_point_cloud(tmp_path / "s.ply", chair.points, labels)
    assert time.perf_counter() - start < 5.0  # colours only for the labels present, not for 0 .. max
    labels[0] = 2**31
    with pytest.raises(ValueError, match=r"integers in \[-1, 2\^31\)"):
        write_segmented_point_cloud(tmp_path / "s.ply", chair.points, labels)


# ------------------------------------------------------------------------------ bounded cost


def test_normal_estimation_refuses_clouds_beyond_its_limit():
    with pytest.raises(ValueError, match=rf"at most {MAX_POINTS} \(cuboidlib._checks.MAX_SHAPE_POINTS\): subsample first"):
        estimate_normals(np.random.default_rng(0).random((MAX_POINTS + 1, 3)))


def test_big_clouds_without_normals_load_when_subsampled(tmp_path):
    pts = np.random.default_rng(0).random((MAX_POINTS + 5, 3))
    np.savetxt(tmp_path / "big.xyz", pts)
    with pytest.raises(ValueError, match="subsample first"):
        io.load_point_cloud(tmp_path / "big.xyz")
    pc = io.load_point_cloud(tmp_path / "big.xyz", n_points=300)
    assert pc.points.shape == (300, 3) and np.isfinite(pc.normals).all()


def test_fewer_ok_keeps_a_small_cloud_whole(tmp_path, chair):
    io.write_point_cloud(tmp_path / "c.ply", chair.points, chair.normals)
    with pytest.raises(ValueError, match="fewer than the 4096 asked for"):
        io.load_point_cloud(tmp_path / "c.ply", n_points=4096)
    assert len(io.load_point_cloud(tmp_path / "c.ply", n_points=4096, fewer_ok=True)) == len(chair.points)


def test_a_checkpoint_asking_for_absurd_sizes_is_refused_before_allocating(tmp_path):
    state = load_checkpoint(CHECKPOINTS / "table.pt")
    state["config"]["model"]["latent_dim"] = 10**9
    torch.save(state, tmp_path / "huge.pt")
    start = time.perf_counter()
    with pytest.raises(ValueError, match=r"huge.pt: the stored model config is not usable: .*latent_dim"):
        load_model(tmp_path / "huge.pt")
    assert time.perf_counter() - start < 10.0
    state["config"]["model"].update(latent_dim=8000, global_dim=8000)
    torch.save(state, tmp_path / "wide.pt")
    with pytest.raises(ValueError, match="million parameters"):
        load_model(tmp_path / "wide.pt")


# ------------------------------------------------------------------------------ files and the CLI


@pytest.mark.parametrize(
    "header, message",
    [
        ("element\n", "malformed PLY header line 'element'"),
        ("element vertex abc\nproperty float x\n", "PLY element 'vertex' has count 'abc'; expected a whole number"),
        ("element vertex -3\nproperty float x\n", "PLY element 'vertex' has count '-3'"),
        ("element vertex 2\nproperty float\n", "malformed PLY header line 'property float'"),
        ("element vertex 2\nbogus line\n", "unknown PLY header line 'bogus line'"),
    ],
)
def test_malformed_ply_headers_name_the_file_and_the_line(tmp_path, header, message):
    path = tmp_path / "bad.ply"
    path.write_text(f"ply\nformat ascii 1.0\n{header}end_header\n")
    with pytest.raises(ValueError, match=f"bad.ply: {message}"):
        io.read_point_cloud(path)


def test_a_face_index_out_of_range_is_named(tmp_path):
    path = tmp_path / "faces.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    with pytest.raises(ValueError, match="faces.ply: a face refers to vertex 7, but the mesh has 3 vertices"):
        io.load_mesh_as_point_cloud(path, 100)


def test_cli_errors_are_one_line_naming_the_problem(tmp_path, capsys):
    mesh = str(Path(__file__).resolve().parents[1] / "data_samples" / "meshes" / "chair_0.ply")
    assert main(["abstract", mesh, "--model", "chair", "--device", "bogus", "--out", str(tmp_path / "o")]) == 2
    assert "device must be 'auto', 'cpu' or 'cuda[:i]', got 'bogus'" in capsys.readouterr().err
    config = tmp_path / "c.json"
    config.write_bytes(b"\xff\xfe{}")
    assert main(["train", "--config", str(config), "--out", str(tmp_path / "run")]) == 2
    assert "c.json: not a UTF-8 text file" in capsys.readouterr().err


def test_help_with_a_missing_dependency_says_what_to_install(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "cuboidlib.fitting", None)  # as if a dependency of it were missing
    assert main(["fit", "--help"]) == 1
    err = capsys.readouterr().err
    assert "is not installed" in err and "pip install" in err and "Traceback" not in err


def test_evaluate_takes_committed_names_and_folders_do_not_shadow_them(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "table").mkdir()  # e.g. an earlier output folder, not a training run
    (tmp_path / "table" / "result.json").write_text("{}")
    assert resolve_checkpoint("table") == CHECKPOINTS / "table.pt"
    assert main(["evaluate", "table", "--split", "val", "--samples", "256"]) == 0
    assert capsys.readouterr().out.startswith("table: table, generator version 1, val split")


# ------------------------------------------------------------------------------ misleading checks


def test_half_precision_input_is_fitted_in_float32(chair):
    r = fit_cuboids(torch.as_tensor(chair.points).half(), torch.as_tensor(chair.normals).half(), FitConfig(steps=20))
    assert r.cuboids.centers.dtype == torch.float32 and torch.isfinite(r.cuboids.centers).all()


def test_identical_points_are_refused_by_fitting_and_the_baseline():
    with pytest.raises(ValueError, match="all identical"):
        fit_cuboids(torch.ones(64, 3), torch.randn(64, 3), FitConfig(steps=5, normalize=False))
    with pytest.raises(ValueError, match="all identical"):
        fit_cluster_boxes(torch.ones(64, 3), torch.randn(64, 3), 12)


def test_the_network_refuses_unnormalised_points(chair):
    model, _, _ = load_trained_model("table")  # a network that reads the normals too
    p, n = torch.as_tensor(chair.points), torch.as_tensor(chair.normals)
    abstract_shapes(model, p, normals=n)  # normalised: fine
    for bad, what in ((p * 100, "diagonal 100"), (p + 5, "centre 8.66")):
        with pytest.raises(ValueError, match=f"not normalised like the training shapes .*{what}"):
            abstract_shapes(model, bad, normals=n)


def test_normal_consistency_refuses_zero_normals(chair):
    p = torch.as_tensor(chair.points)[None]
    n = torch.as_tensor(chair.normals)[None].clone()
    n[0, 3] = 0
    cub = (torch.zeros(1, 1, 3), torch.tensor([[[1.0, 0, 0, 0]]]), torch.full((1, 1, 3), 0.3))
    with pytest.raises(ValueError, match="1 have zero length"):
        normal_consistency(p, n, *cub)


def test_iou_refuses_labels_outside_num_parts():
    gt = torch.tensor([[0, 1, 2]])
    with pytest.raises(ValueError, match="part_labels holds label 2, but num_parts = 2"):
        mean_iou(gt, gt, 2)
    with pytest.raises(ValueError, match="num_parts must be a positive integer"):
        mean_iou(gt, gt, 0)
    with pytest.raises(ValueError, match="true part labels are >= 0"):
        part_ious(gt, gt - 1, 3)


def test_a_corrupted_cache_entry_is_regenerated(tmp_path):
    good = make_collection("table", 3, n_points=64, cache_dir=tmp_path)
    (entry,) = tmp_path.glob("*.npz")
    broken = ShapeCollection(good.category, good.points.copy(), good.normals, good.labels, good.structures,
                             good.structure_ids, good.seed)
    broken.points[0, 0, 0] = np.nan
    broken.save(entry)
    with pytest.raises(ValueError, match="NaN or infinite"):
        ShapeCollection.load(entry)
    again = make_collection("table", 3, n_points=64, cache_dir=tmp_path)
    np.testing.assert_array_equal(again.points, good.points)
    ShapeCollection.load(entry)  # rewritten


# ------------------------------------------------------------------------------ property-based cases

FLOATS = st.sampled_from([torch.float32, torch.float64])
MAGNITUDES = st.sampled_from([1e-30, 1e-6, 1.0, 1e3, 1e8, 1e30])
OFFSETS = st.sampled_from([0.0, -1.0, 1e4, 1e12])
HYPOTHESIS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _cloud(seed, n, magnitude, offset, dtype):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(1, n, 3, generator=g, dtype=torch.float64) * magnitude + offset).to(dtype)


@HYPOTHESIS
@given(seed=st.integers(0, 2**16), n=st.integers(1, 50), magnitude=MAGNITUDES, offset=OFFSETS, dtype=FLOATS)
def test_normalize_round_trip_property(seed, n, magnitude, offset, dtype):
    p = _cloud(seed, n, magnitude, offset, dtype)[0]
    wide = p.double()
    spread = float((wide.amax(0) - wide.amin(0)).norm())
    try:
        q, center, scale = normalize(p)
    except ValueError as exc:  # only a cloud without extent (at this precision) may be refused
        assert "all identical" in str(exc)
        assert spread <= 1e-9 * max(1.0, float(wide.abs().max()))
        return
    assert torch.isfinite(q).all() and q.dtype == dtype
    assert float((q.amax(0) - q.amin(0)).norm()) == pytest.approx(1.0, rel=1e-4)
    back = denormalize(q, center, scale)
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    assert float((back.double() - wide).abs().max()) <= tol * max(spread, float(wide.abs().max()))


@HYPOTHESIS
@given(seed=st.integers(0, 2**16), n=st.integers(1, 40), m=st.integers(1, 40), magnitude=MAGNITUDES,
       offset=OFFSETS, dtype=FLOATS)
def test_chamfer_distance_property(seed, n, m, magnitude, offset, dtype):
    a, b = _cloud(seed, n, magnitude, offset, dtype), _cloud(seed + 1, m, magnitude, offset, dtype)
    d = (a.double()[0, :, None] - b.double()[0, None]).square().sum(-1)
    want = float(d.amin(1).mean() + d.amin(0).mean())
    try:
        got = chamfer_distance(a, b)
    except ValueError as exc:  # only when squared distances exceed the dtype's range
        assert "overflow" in str(exc) and float(d.amax()) > torch.finfo(dtype).max / 4
        return
    assert torch.isfinite(got).all()
    # float32 cannot hold squared distances below its smallest normal number (~1e-38)
    floor = torch.finfo(dtype).tiny
    assert float(got) == pytest.approx(want, rel=1e-3, abs=max(1e-6 * magnitude**2, floor))


@HYPOTHESIS
@given(seed=st.integers(0, 2**16), n=st.integers(0, 20), where=st.sampled_from(["a", "b"]),
       bad=st.sampled_from([math.nan, math.inf, -math.inf, "empty"]))
def test_chamfer_distance_refuses_bad_clouds_property(seed, n, where, bad):
    a, b = _cloud(seed, max(n, 1), 1.0, 0.0, torch.float32), _cloud(seed + 1, 5, 1.0, 0.0, torch.float32)
    if bad == "empty":
        a = a[:, :0]
    else:
        a[0, n // 2, 1] = bad
    args = (a, b) if where == "a" else (b, a)
    with pytest.raises(ValueError, match="empty|NaN or infinite"):
        chamfer_distance(*args)


@HYPOTHESIS
@given(seed=st.integers(0, 2**16), shapes=st.integers(1, 4), n=st.integers(1, 30), parts=st.integers(1, 6))
def test_mean_iou_property(seed, shapes, n, parts):
    rng = np.random.default_rng(seed)
    gt = rng.integers(0, parts, (shapes, n))
    pred = rng.integers(-1, parts, (shapes, n))
    ious = []
    for label in range(parts):  # the float64 reference: IoU over all points, mean over labels present
        inter, union = ((pred == label) & (gt == label)).sum(), ((pred == label) | (gt == label)).sum()
        if union:
            ious.append(inter / union)
    assert mean_iou(torch.as_tensor(pred), torch.as_tensor(gt), parts) == pytest.approx(np.mean(ious), abs=1e-12)
    with pytest.raises(ValueError, match="but num_parts"):
        mean_iou(torch.as_tensor(pred), torch.as_tensor(gt + parts), parts)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16), n=st.integers(1, 60), suffix=st.sampled_from([".ply", ".txt", ".npy"]),
       magnitude=st.sampled_from([1e-3, 1.0, 1e6]), offset=st.sampled_from([0.0, 1e4]),
       with_labels=st.booleans())
def test_point_cloud_files_round_trip_property(tmp_path_factory, seed, n, suffix, magnitude, offset, with_labels):
    rng = np.random.default_rng(seed)
    points = rng.random((n, 3)) * magnitude + offset
    normals = rng.normal(size=(n, 3)) + 0.1
    labels = rng.integers(0, 50, n) if with_labels else None
    path = tmp_path_factory.mktemp("rt") / f"cloud{suffix}"
    try:
        io.write_point_cloud(path, points, normals, labels)
    except ValueError as exc:
        assert "identical" in str(exc) and np.ptp(points.astype(np.float32), axis=0).max() == 0
        return
    try:
        pc = io.read_point_cloud(path, normals="file")  # random vectors, not unit ones: normals because we say so
    except ValueError as exc:  # float32 storage may merge all points of a tiny cloud far from 0
        assert "identical" in str(exc)
        return
    np.testing.assert_allclose(pc.points, points, rtol=2e-6 if suffix != ".txt" else 1e-6, atol=1e-6 * magnitude)
    if with_labels:
        np.testing.assert_array_equal(pc.labels, labels)


# ------------------------------------------------------------------------------ files: no silent wrong answers

FAR = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _write_obj(path, vertices, faces):
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(vertices, dtype=np.float64).tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(faces).tolist()]
    path.write_text("\n".join(lines) + "\n")
    return path


def _far_tolerance(offset, scale):
    """float32 on the unit shape, plus what float64 loses of an offset far larger than the shape."""
    return 2e-6 + 8 * np.finfo(np.float64).eps * float(np.abs(offset).max()) / scale


@FAR
@given(seed=st.integers(0, 2**16), offset=st.tuples(*[st.floats(-1e7, 1e7)] * 3),
       log_scale=st.floats(-6, 6), suffix=st.sampled_from([".npy", ".txt", ".ply"]))
def test_far_and_scaled_point_clouds_normalise_to_the_same_shape_property(tmp_path, chair, seed, offset, log_scale,
                                                                          suffix):
    scale = 10.0**log_scale
    unit = chair.points.astype(np.float64)
    moved = unit * scale + np.asarray(offset)
    path = tmp_path / f"far{seed}{suffix}"
    if suffix == ".npy":
        np.save(path, np.concatenate([moved, chair.normals], axis=1))
    elif suffix == ".txt":
        np.savetxt(path, np.concatenate([moved, chair.normals], axis=1), fmt="%.17g")
    else:  # an ASCII PLY of doubles
        header = ("ply\nformat ascii 1.0\nelement vertex %d\nproperty double x\nproperty double y\n"
                  "property double z\nend_header\n" % len(moved))
        path.write_text(header + "\n".join(" ".join(repr(v) for v in row) for row in moved.tolist()) + "\n")
    want, _, _ = normalize(unit)
    got = io.load_point_cloud(path)
    assert got.points.dtype == np.float32
    assert np.abs(got.points - want).max() <= _far_tolerance(offset, scale)
    np.testing.assert_allclose(got.points.astype(np.float64) * got.scale + got.center, moved,
                               atol=_far_tolerance(offset, scale) * got.scale * 2)


@pytest.mark.parametrize("offset,scale", [((5e5, 4e6, 100), 1.0), ((1e7, -1e7, 3e6), 1e-2), ((0, 0, 0), 1e-6),
                                          ((-2e6, 0, 7e6), 1e6)])
def test_a_mesh_in_map_coordinates_samples_the_same_normalised_shape(tmp_path, offset, scale):
    mesh = make_shape("chair", 2, n_points=64).mesh()
    unit = _write_obj(tmp_path / "unit.obj", mesh.vertices, mesh.faces)
    far = _write_obj(tmp_path / "far.obj", mesh.vertices * scale + np.asarray(offset), mesh.faces)
    a, b = io.load_point_cloud(unit, 2048, seed=3), io.load_point_cloud(far, 2048, seed=3)
    assert len(np.unique(b.points[:, 1])) > 1000  # not a handful of float32 values
    assert np.abs(a.points - b.points).max() <= _far_tolerance(offset, scale)


@pytest.mark.parametrize("suffix", [".ply", ".txt", ".xyz", ".pts"])
@pytest.mark.parametrize("row", ["extra", "missing"])
def test_text_rows_of_the_wrong_length_are_refused_in_every_text_format(tmp_path, chair, suffix, row):
    table = np.concatenate([chair.points[:200], chair.normals[:200]], axis=1)
    lines = [" ".join(f"{v:.6f}" for v in r) for r in table]
    lines[40] += " 0.5" if row == "extra" else ""
    if row == "missing":
        lines[41] = lines[41].rsplit(" ", 1)[0]
    if suffix == ".ply":
        header = ["ply", "format ascii 1.0", "element vertex 200"]
        header += [f"property float {n}" for n in ("x", "y", "z", "nx", "ny", "nz")] + ["end_header"]
        lines = header + lines
    path = tmp_path / f"rows{suffix}"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"rows?.*(do not hold the 6 values|different numbers of columns)"):
        io.read_point_cloud(path)
    if suffix == ".ply":  # one extra and one missing value cancel out in the count: still refused, and located
        lines[-160] += " 0.5"
        lines[-150] = lines[-150].rsplit(" ", 1)[0]
        path.write_text("\n".join(lines) + "\n")
        with pytest.raises(ValueError, match="first: line"):
            io.read_point_cloud(path)


@pytest.mark.parametrize("colours", ["unit", "byte"])
@pytest.mark.parametrize("suffix", [".xyz", ".txt", ".npy"])
def test_colour_columns_never_pass_as_normals(tmp_path, chair, colours, suffix):
    rng = np.random.default_rng(0)
    rgb = rng.random((len(chair.points), 3)) if colours == "unit" else rng.integers(0, 256, (len(chair.points), 3))
    table = np.concatenate([chair.points, rgb], axis=1)
    path = tmp_path / f"rgb{suffix}"
    np.save(path, table) if suffix == ".npy" else np.savetxt(path, table)
    with pytest.warns(UserWarning, match=r"columns 4-6 hold .*RGB colours.*normals='file'"):
        pc = io.read_point_cloud(path)
    assert pc.normals is None
    with pytest.warns(UserWarning, match="RGB colours"):
        loaded = io.load_point_cloud(path)
    assert np.abs(np.linalg.norm(loaded.normals, axis=1) - 1).max() < 1e-5  # estimated
    assert io.read_point_cloud(path, normals="file").normals is not None  # the user says so
    np.savetxt(tmp_path / "n.xyz", np.concatenate([chair.points, chair.normals], axis=1))
    np.testing.assert_allclose(io.read_point_cloud(tmp_path / "n.xyz").normals, chair.normals, atol=1e-6)


def test_a_tiny_shape_is_a_shape_and_identical_points_are_named_as_such():
    unit = torch.rand(50, 3, dtype=torch.float64)
    for size in (1e-30, 1e-6, 1e30):
        q, _, scale = normalize(unit * size)
        assert float(scale) == pytest.approx(size * float((unit.amax(0) - unit.amin(0)).norm()))
    with pytest.raises(ValueError, match="all identical: the bounding box has zero size"):
        normalize(torch.ones(5, 3) * 1e-30)
    with pytest.raises(ValueError, match="all identical to float64 precision.*subtract a nearby origin"):
        normalize(unit * 1e-9 + 1e6)


# ------------------------------------------------------------------------------ files: nothing of the user's overwritten

SAMPLE_MESH = Path(__file__).resolve().parents[1] / "data_samples" / "meshes" / "table_0.ply"
FAST_FIT = ["--steps", "2", "--cuboids", "3", "--points", "128", "--quiet"]


def test_no_output_is_an_input_or_lies_inside_one(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["fit", str(SAMPLE_MESH), "--out", str(out), *FAST_FIT]) == 0
    shape = out / "table_0_segmentation.ply"
    before = shape.read_bytes()
    # --overwrite would remove the run's files, the input among them, before reading it
    assert main(["fit", str(shape), "--out", str(out), "--overwrite", *FAST_FIT]) == 2
    err = capsys.readouterr().err
    assert "is the input" in err and "table_0_segmentation.ply" in err
    assert shape.read_bytes() == before
    # an output folder inside (or equal to) an input folder
    data = tmp_path / "data"
    data.mkdir()
    io.write_point_cloud(data / "a.ply", make_shape("chair", 0, n_points=256).points)
    for target in (data, data / "results"):
        assert main(["fit", str(data), "--out", str(target), *FAST_FIT]) == 2
        assert "--out" in capsys.readouterr().err
    assert sorted(p.name for p in data.iterdir()) == ["a.ply"]
    # view: the page may not be a result (or its points), and must be HTML
    result = out / "table_0.json"
    text = result.read_text()
    for page, message in ((result, "is the input"), (out / "page.txt", "must be an .html file"), (out / "view.htm", None)):
        code = main(["view", str(result), "--out", str(page), "--quiet"])
        if message:
            assert code == 2 and message in capsys.readouterr().err
    assert result.read_text() == text
    (out / "table_0_segmentation.html").symlink_to(result)
    assert main(["view", str(result), "--out", str(out / "table_0_segmentation.html"), "--quiet"]) == 2
    assert "is the input" in capsys.readouterr().err and result.read_text() == text


def test_result_file_names_are_unique_not_only_their_stems(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    chair, table = make_shape("chair", 0, n_points=256), make_shape("table", 0, n_points=256)
    io.write_point_cloud(data / "a.ply", chair.points)
    io.write_point_cloud(data / "a_segmentation.ply", table.points)
    out = tmp_path / "out"
    assert main(["fit", str(data / "a.ply"), str(data / "a_segmentation.ply"), "--out", str(out),
                 "--mesh-format", "ply", *FAST_FIT]) == 0
    results = {p.name: json.loads(p.read_text()) for p in out.glob("*.json") if p.name != "cuboidlib-manifest.json"}
    assert len(results) == 2
    points = [r["points_file"] for r in results.values()]
    assert len(set(points)) == 2
    for r in results.values():  # every result's points are its own shape's
        mine = io.read_point_cloud(out / r["points_file"]).points
        source = io.read_point_cloud(data / r["source"]).points
        nearest = np.linalg.norm(mine[:, None] - source[None], axis=-1).min(axis=1)
        assert nearest.max() < 1e-4, r["source"]
    written = json.loads((out / "cuboidlib-manifest.json").read_text())["files"]
    assert len(written) == len(set(written)) == 2 * 3 + 1  # json, ply mesh, segmentation per shape; summary


def test_a_new_training_run_never_overwrites_files_or_writes_through_links(tmp_path):
    from cuboidlib.train import Trainer
    from cuboidlib.train_config import course_config

    config = course_config("chair", n_shapes=8, n_points=64, batch_size=4, max_steps=1, max_minutes=None)
    outside = tmp_path / "outside.csv"
    outside.write_text("precious")
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text('{"mine": true}')
    (run / "log.csv").symlink_to(outside)
    with pytest.raises(FileExistsError, match=r"config.json, log.csv .*symbolic link"):
        Trainer(config, run, quiet=True)
    assert (run / "config.json").read_text() == '{"mine": true}' and outside.read_text() == "precious"
    (run / "config.json").unlink()
    with pytest.raises(FileExistsError, match="log.csv"):
        Trainer(config, run, quiet=True)
    (run / "log.csv").unlink()
    trainer = Trainer(config, run, quiet=True)
    (run / "log.csv").unlink()
    (run / "log.csv").symlink_to(outside)  # a link put there while the run goes
    with pytest.raises(OSError, match="not a symbolic link"):
        trainer.log.write(0, 0, "train", {}, 0.0)
    assert outside.read_text() == "precious"
    again = tmp_path / "again"
    Trainer(config, again, quiet=True)  # the same run started again before its first checkpoint is accepted
    Trainer(config, again, quiet=True)
    with pytest.raises(FileExistsError, match="config.json"):
        Trainer(config.replace(seed=config.seed + 1), again, quiet=True)


def test_written_files_get_the_users_umask(tmp_path):
    from cuboidlib.files import write_text_atomic

    old = os.umask(0o027)
    try:
        path = write_text_atomic(tmp_path / "a.txt", "x")
    finally:
        os.umask(old)
    assert (path.stat().st_mode & 0o777) == 0o640


def test_obj_faces_counting_from_zero_are_refused_not_shifted(tmp_path):
    vertices = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
    (tmp_path / "zero.obj").write_text(vertices + "f 0 1 2\nf 0 2 3\nf 0 3 1\nf 1 3 2\n")
    with pytest.raises(ValueError, match=r"zero.obj: line 5 \('f 0 1 2'\) refers to vertex 0.*start at 1"):
        io.load_mesh_as_point_cloud(tmp_path / "zero.obj", 10)
    (tmp_path / "slashes.obj").write_text(vertices + "vt 0 0\nf 1/1 2/1 3/1\nf 1//1 3//1 4//1\nf 10 2 4\n")
    with pytest.raises(ValueError, match=r"slashes.obj: line 8 \('f 10 2 4'\) refers to vertex 10, but the file "
                       "defines 4 vertices"):
        io.load_mesh_as_point_cloud(tmp_path / "slashes.obj", 10)
    (tmp_path / "good.obj").write_text(vertices + "f 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n")
    assert len(io.load_mesh_as_point_cloud(tmp_path / "good.obj", 10)) == 10


@pytest.mark.parametrize("with_manifest", [True, False])
def test_a_data_folder_never_reads_cuboidlibs_own_results_as_shapes(tmp_path, with_manifest):
    import shutil
    import warnings

    from cuboidlib.dataset import DataConfig, load_shapes

    data = tmp_path / "data"
    data.mkdir()
    for k in range(3):
        shape = make_shape("chair", k, n_points=256)
        io.write_point_cloud(data / f"s{k}.ply", shape.points, shape.normals, shape.labels)
    out = tmp_path / "out"
    assert main(["fit", str(data), "--out", str(out), "--mesh-format", "glb,obj", *FAST_FIT]) == 0
    for f in out.iterdir():
        if with_manifest or f.name != "cuboidlib-manifest.json":
            shutil.copy(f, data / f.name)
    with pytest.warns(UserWarning, match=r"file\(s\) below it are cuboidlib results"):
        shapes = load_shapes(DataConfig(data_dir=str(data), n_points=128))
    assert len(shapes) == 3
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        (data / "cuboidlib-manifest.json").unlink(missing_ok=True)
        for f in data.iterdir():
            if not f.name.startswith("s") or "_" in f.name or f.suffix != ".ply":
                f.unlink()
        assert len(load_shapes(DataConfig(data_dir=str(data), n_points=128))) == 3


# ------------------------------------------------------------------------------ sizes: one limit, checked first


def test_every_path_that_samples_or_allocates_checks_one_size_limit_first(tmp_path, capsys):
    from cuboidlib._checks import MAX_COLLECTION_POINTS, MAX_SHAPE_POINTS, MAX_SHAPES
    from cuboidlib.dataset import DataConfig

    too_many = f"above the limit of {MAX_SHAPE_POINTS:,}"
    start = time.perf_counter()
    with pytest.raises(ValueError, match=too_many):
        io.load_mesh_as_point_cloud(SAMPLE_MESH, 10**9)
    with pytest.raises(ValueError, match=too_many):
        io.load_point_cloud(SAMPLE_MESH, 3_000_000)
    with pytest.raises(ValueError, match="positive number of points, got -5"):
        io.load_mesh_as_point_cloud(SAMPLE_MESH, -5)
    with pytest.raises(ValueError, match=too_many):
        make_shape("chair", 0, n_points=10**9)
    with pytest.raises(ValueError, match=f"above the limit of {MAX_SHAPES:,}"):
        make_collection("chair", 10**9, 16, use_cache=False)
    with pytest.raises(ValueError, match=f"above the limit of {MAX_COLLECTION_POINTS:,}"):
        make_collection("chair", MAX_SHAPES, MAX_SHAPE_POINTS, use_cache=False)
    for field, value in (("n_points", 10**9), ("n_shapes", 10**9)):
        with pytest.raises(ValueError, match=f"TrainConfig.{field} is 1,000,000,000"):
            TrainConfig(**{field: value})
    with pytest.raises(ValueError, match=r"split_fractions\[1\] must be a finite number"):
        DataConfig(split_fractions=(0.7, "0.1", 0.2))
    TrainConfig(n_shapes=2000, n_points=4096)  # the paper's scale
    assert main(["fit", str(SAMPLE_MESH), "--points", "1000000000", "--out", str(tmp_path / "o")]) == 2
    assert too_many in capsys.readouterr().err
    assert main(["generate", "--model", "chair", "--count", "100000000", "--out", str(tmp_path / "g")]) == 2
    assert f"above the limit of {MAX_SHAPES:,}" in capsys.readouterr().err
    assert time.perf_counter() - start < 30  # refused before any work


def test_an_output_folder_is_locked_while_a_run_writes_into_it(tmp_path, capsys):
    from cuboidlib.files import LOCK_FILE

    out = tmp_path / "out"
    out.mkdir()
    (out / LOCK_FILE).write_text(f"{os.getppid()}\n")  # a running process holds it
    assert main(["fit", str(SAMPLE_MESH), "--out", str(out), *FAST_FIT]) == 2
    err = capsys.readouterr().err
    assert f"another cuboidlib run (process {os.getppid()}) is writing there" in err
    assert sorted(p.name for p in out.iterdir()) == [LOCK_FILE]
    (out / LOCK_FILE).write_text("999999999\n")  # left by a run that has ended
    assert main(["fit", str(SAMPLE_MESH), "--out", str(out), *FAST_FIT]) == 0
    assert not (out / LOCK_FILE).exists() and (out / "table_0.json").is_file()
    assert main(["fit", str(tmp_path / "missing.ply"), "--out", str(tmp_path / "new"), *FAST_FIT]) == 2
    assert not (tmp_path / "new").exists()  # a run that wrote nothing leaves no folder


def _glb(doc: dict, binary: bytes) -> bytes:
    import struct

    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(binary), b"BIN\x00") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def test_damaged_glb_files_and_checkpoints_are_named_clearly(tmp_path):
    import trimesh as tm

    good = tm.creation.box().export(file_type="glb")
    length = int.from_bytes(good[12:16], "little")
    doc, binary = json.loads(good[20:20 + length]), good[20 + length + 8:]
    doc["buffers"][0]["byteLength"] = 2**40
    (tmp_path / "huge.glb").write_bytes(_glb(doc, binary))
    with pytest.raises(ValueError, match=r"huge.glb: unreadable mesh: GLB buffer 0 claims 1099511627776 bytes"):
        io.load_mesh_as_point_cloud(tmp_path / "huge.glb", 10)
    (tmp_path / "empty.glb").write_bytes(b"")
    with pytest.raises(ValueError, match="empty.glb: unreadable mesh: an empty or truncated GLB"):
        io.load_mesh_as_point_cloud(tmp_path / "empty.glb", 10)
    (tmp_path / "cut.glb").write_bytes(good[:-7])
    with pytest.raises(ValueError, match="cut.glb: unreadable mesh: the GLB header declares"):
        io.load_mesh_as_point_cloud(tmp_path / "cut.glb", 10)
    state = torch.load(CHECKPOINTS / "chair.pt", weights_only=True)
    bad = dict(state, format_version="2")
    torch.save(bad, tmp_path / "v.pt")
    with pytest.raises(ValueError, match="format_version must be a whole number >= 1, got '2'"):
        load_checkpoint(tmp_path / "v.pt")
    weights = dict(state["model"])
    name = next(k for k, v in weights.items() if v.is_floating_point())
    weights[name] = weights[name].clone().fill_(float("nan"))
    torch.save(dict(state, model=weights), tmp_path / "nan.pt")
    with pytest.raises(ValueError, match=rf"nan.pt: the checkpoint's weights hold NaN.*{name}.*not your input"):
        load_model(tmp_path / "nan.pt")


def test_an_interrupted_training_says_where_resume_continues(tmp_path, monkeypatch, capsys):
    import cuboidlib.cli_train
    from cuboidlib.checkpoint import save_checkpoint

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cuboidlib.cli_train, "_cmd_train", interrupted)
    out = tmp_path / "run"
    assert main(["train", "--out", str(out)]) == 130
    assert "no checkpoint was written" in capsys.readouterr().err
    save_checkpoint(out / "last.pt", {"model": {}}, {}, step=7)
    assert main(["train", "--out", str(out)]) == 130
    assert "--resume continues from step 7" in capsys.readouterr().err


def test_a_checkpoint_never_chooses_a_folder_to_read(tmp_path, capsys):
    state = torch.load(CHECKPOINTS / "chair.pt", weights_only=True)
    torch.save(dict(state, config={**state["config"], "data_dir": "/usr"}), tmp_path / "usr.pt")
    start = time.perf_counter()
    assert main(["evaluate", str(tmp_path / "usr.pt")]) == 2
    err = capsys.readouterr().err
    assert "trained on the data folder /usr" in err and "--data-dir /usr" in err
    assert time.perf_counter() - start < 20  # refused, not scanned


# ------------------------------------------------------------------------------ limits: every one named, arrays as files


LIMIT_NAMES = [name for name in dir(_checks) if isinstance(getattr(_checks, name), _checks.Limit)]
FAST = settings(max_examples=40, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
_NETWORK = {}


def _chair_network():
    if "chair" not in _NETWORK:
        _NETWORK["chair"] = load_trained_model("chair")[0]
    return _NETWORK["chair"]


def _cloud_array(n: int = 64) -> np.ndarray:
    return np.random.default_rng(0).random((n, 3))


#: (what, limit, call with the size): every library entry that samples, allocates or repeats something.
LIBRARY_SIZES = [
    ("FitConfig.num_cuboids", _checks.MAX_CUBOIDS, lambda v: FitConfig(num_cuboids=v)),
    ("FitConfig.restarts", _checks.MAX_RESTARTS, lambda v: FitConfig(restarts=v)),
    ("FitConfig.steps", _checks.MAX_FIT_STEPS, lambda v: FitConfig(steps=v)),
    ("abstract(array, n_points)", _checks.MAX_SHAPE_POINTS,
     lambda v: cuboidlib.abstract(_cloud_array(), None, n_points=v)),
    ("abstract(tensor, n_points)", _checks.MAX_SHAPE_POINTS,
     lambda v: cuboidlib.abstract(torch.as_tensor(_cloud_array()), "chair", n_points=v)),
    ("abstract(PointCloud, n_points)", _checks.MAX_SHAPE_POINTS,
     lambda v: cuboidlib.abstract(io.PointCloud(_cloud_array()), None, n_points=v)),
    ("abstract(file, n_points)", _checks.MAX_SHAPE_POINTS, lambda v: cuboidlib.abstract(SAMPLE_MESH, None, n_points=v)),
    ("abstract(refine)", _checks.MAX_FIT_STEPS, lambda v: cuboidlib.abstract(_cloud_array(), "chair", refine=v)),
    ("generate_shapes", _checks.MAX_SHAPES, lambda v: generate_shapes(_chair_network(), v)),
    ("interpolate_codes", _checks.MAX_SHAPES,
     lambda v: interpolate_codes(_chair_network(), torch.zeros(64), torch.zeros(64), steps=v)),
    ("TrainConfig.num_threads", _checks.MAX_THREADS, lambda v: TrainConfig(num_threads=v)),
    ("make_shape", _checks.MAX_SHAPE_POINTS, lambda v: make_shape("chair", 0, n_points=v)),
]


@FAST
@given(entry=st.sampled_from(LIBRARY_SIZES), excess=st.integers(1, 10**12))
def test_every_library_size_above_its_limit_is_refused_naming_that_limit_property(entry, excess):
    what, limit, call = entry
    start = time.perf_counter()
    with pytest.raises(ValueError) as info:
        call(int(limit) + excess)
    message = str(info.value)
    assert f"above the limit of {limit:,} (cuboidlib._checks.{limit.name})" in message, (what, message)
    assert all(f"_checks.{other}" not in message for other in LIMIT_NAMES if other != limit.name), message
    assert time.perf_counter() - start < 5, f"{what}: refused after work"


#: (option, limit, argv with the value): every size option of the command line.
CLI_SIZES = [
    ("--cuboids", _checks.MAX_CUBOIDS, ["fit", str(SAMPLE_MESH), "--cuboids"]),
    ("--restarts", _checks.MAX_RESTARTS, ["fit", str(SAMPLE_MESH), "--restarts"]),
    ("--steps", _checks.MAX_FIT_STEPS, ["fit", str(SAMPLE_MESH), "--steps"]),
    ("--points", _checks.MAX_SHAPE_POINTS, ["fit", str(SAMPLE_MESH), "--points"]),
    ("--points", _checks.MAX_SHAPE_POINTS, ["abstract", str(SAMPLE_MESH), "--model", "chair", "--points"]),
    ("--refine", _checks.MAX_FIT_STEPS, ["abstract", str(SAMPLE_MESH), "--model", "chair", "--refine"]),
    ("--count", _checks.MAX_SHAPES, ["generate", "--model", "chair", "--count"]),
    ("--steps", _checks.MAX_SHAPES, ["interpolate", str(SAMPLE_MESH), str(SAMPLE_MESH), "--model", "chair",
                                     "--steps"]),
    ("--samples", _checks.MAX_SHAPE_POINTS, ["evaluate", "chair", "--samples"]),
    ("--baseline-boxes", _checks.MAX_CUBOIDS, ["evaluate", "chair", "--baseline", "--baseline-boxes"]),
    ("--threads", _checks.MAX_THREADS, ["train", "--threads"]),
    ("--per-category", _checks.MAX_SHAPES, ["samples", "--per-category"]),
    ("--points", _checks.MAX_SHAPE_POINTS, ["samples", "--points"]),
]


@FAST
@given(entry=st.sampled_from(CLI_SIZES), excess=st.integers(1, 10**12))
def test_every_command_line_size_above_its_limit_is_one_line_naming_that_limit_property(tmp_path, capsys, entry,
                                                                                      excess):
    option, limit, argv = entry
    out = tmp_path / f"out{excess}"
    outputs = {"evaluate": [], "train": ["--out", str(out)]}.get(argv[0], ["--out", str(out)])
    start = time.perf_counter()
    assert main([*argv, str(int(limit) + excess), *outputs]) == 2
    message = capsys.readouterr().err.strip()
    assert message.count("\n") == 0 and f"error: {option} is {int(limit) + excess:,}" in message, message
    assert f"above the limit of {limit:,} (cuboidlib._checks.{limit.name})" in message, message
    assert not out.exists() and time.perf_counter() - start < 5


@FAST
@given(seed=st.one_of(st.integers(_checks.MAX_SEED + 1, 2**300), st.integers(-2**100, -1)),
       entry=st.sampled_from(["abstract_fit", "abstract_network", "FitConfig", "TrainConfig", "tighten", "fit",
                              "generate", "interpolate", "evaluate", "samples"]))
def test_seeds_beyond_what_the_generators_take_are_refused_by_name_property(tmp_path, capsys, seed, entry):
    calls = {
        "abstract_fit": lambda: cuboidlib.abstract(_cloud_array(), None, seed=seed),
        "abstract_network": lambda: cuboidlib.abstract(_cloud_array(), "chair", seed=seed),
        "FitConfig": lambda: FitConfig(seed=seed),
        "TrainConfig": lambda: TrainConfig(seed=seed),
        "tighten": lambda: tighten_cuboids(torch.rand(1, 20, 3), fit_cluster_boxes(torch.rand(20, 3), torch.rand(20, 3),
                                                                                    2).cuboids, seed=seed),
    }
    out = str(tmp_path / "out")
    argv = {"fit": ["fit", str(SAMPLE_MESH), "--out", out, "--seed"],
            "generate": ["generate", "--model", "chair", "--out", out, "--seed"],
            "interpolate": ["interpolate", str(SAMPLE_MESH), str(SAMPLE_MESH), "--model", "chair", "--out", out,
                            "--seed"],
            "evaluate": ["evaluate", "chair", "--seed"], "samples": ["samples", "--out", out, "--seed"]}
    if entry in calls:
        with pytest.raises(ValueError) as info:
            calls[entry]()
        message = str(info.value)
    else:
        try:
            code = main([*argv[entry], str(seed)])
        except SystemExit as exit_:  # argparse's own refusal of a negative seed
            code = exit_.code
        assert code == 2
        message = capsys.readouterr().err
    assert "seed" in message and "Overflow" not in message and "Traceback" not in message, message
    assert seed < 0 or "MAX_SEED" in message, message
    assert not (tmp_path / "out").exists()


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(exponent=st.integers(39, 307), form=st.sampled_from(["array", "tensor", "PointCloud", "file"]),
       offset=st.booleans())
def test_coordinates_the_result_files_cannot_hold_are_refused_at_the_entry_property(tmp_path, exponent, form, offset):
    shape = make_shape("chair", 0, n_points=256)
    size = 10.0**exponent
    points = shape.points.astype(np.float64) * (1.0 if offset else size) + (size if offset else 0.0)
    if offset and np.ptp(points, axis=0).max() == 0:  # a shape lost in float64 is refused as identical points
        return
    given_shape = {"array": lambda: points, "tensor": lambda: torch.as_tensor(points),
                   "PointCloud": lambda: io.PointCloud(shape.points, center=np.full(3, size if offset else 0.0),
                                                       scale=1.0 if offset else size)}.get(form)
    if form == "file":
        np.savetxt(tmp_path / f"far{exponent}.xyz", points)
        given_shape = lambda: tmp_path / f"far{exponent}.xyz"  # noqa: E731
    for model in (None, "chair"):
        with pytest.raises(ValueError, match=r"coordinates reach .* above the limit of 1e\+38 \(cuboidlib._checks."
                                             r"MAX_COORDINATE\)|coordinates up to .* exceed the float32 range"):  # reader
            cuboidlib.abstract(given_shape(), model, up="y")


@pytest.mark.parametrize("exponent", [39, 200, 300])
def test_the_fit_of_float64_points_far_beyond_float32_works_in_their_units(chair, exponent):
    points = torch.as_tensor(chair.points, dtype=torch.float64) * 10.0**exponent
    r = fit_cuboids(points, torch.as_tensor(chair.normals), FitConfig(steps=2, num_cuboids=3))
    half = r.cuboids.half_sizes[r.cuboids.exists]
    assert torch.isfinite(r.cuboids.centers).all() and 10.0**(exponent - 3) < float(half.amax()) < 10.0**exponent


def test_a_shape_at_1e30_is_abstracted_in_its_own_units():
    shape = make_shape("chair", 0, n_points=512)
    result = cuboidlib.abstract(shape.points.astype(np.float64) * 1e30, "chair", up="y")
    sizes = result.numpy()["sizes"]
    assert np.isfinite(sizes).all() and 1e27 < sizes.max() < 2e30


@pytest.mark.parametrize("entry", ["abstract", "fit_cuboids", "abstract_shapes", "normalize", "latent_distance"])
def test_tensors_without_values_are_refused_by_name(entry):
    meta = torch.empty(64, 3, device="meta")
    calls = {"abstract": lambda: cuboidlib.abstract(meta, None),
             "fit_cuboids": lambda: fit_cuboids(meta, meta, FitConfig(steps=1)),
             "abstract_shapes": lambda: abstract_shapes(_chair_network(), meta),
             "normalize": lambda: normalize(meta),
             "latent_distance": lambda: latent_distance(torch.empty(64, device="meta"),
                                                        load_checkpoint(CHECKPOINTS / "chair.pt")["latent_statistics"])}
    with pytest.raises((TypeError, ValueError), match="'meta' device, which holds a shape but no values"):
        calls[entry]()


STATISTICS_DAMAGE = st.sampled_from(["no mean", "no whitening", "empty", "not a dict", "short mean", "flat whitening",
                                     "nan"])


@settings(max_examples=14, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(damage=STATISTICS_DAMAGE)
def test_incomplete_latent_statistics_are_named_at_the_entry_property(tmp_path, damage):
    state = load_checkpoint(CHECKPOINTS / "chair.pt")
    good = state["latent_statistics"]
    bad = {"no mean": {"whitening": good["whitening"]}, "no whitening": {"mean": good["mean"]}, "empty": {},
           "not a dict": [good["mean"]], "short mean": {**good, "mean": good["mean"][:5]},
           "flat whitening": {**good, "whitening": good["whitening"].flatten()},
           "nan": {**good, "mean": good["mean"] * float("nan")}}[damage]
    with pytest.raises(ValueError, match="statistics|latent_statistics"):
        latent_distance(torch.zeros(1, 64), bad)
    torch.save(dict(state, latent_statistics=bad), tmp_path / f"{damage.replace(' ', '_')}.pt")
    with pytest.raises(ValueError, match=rf"{damage.replace(' ', '_')}.pt: latent_statistics"):
        cuboidlib.abstract(_cloud_array(256), tmp_path / f"{damage.replace(' ', '_')}.pt", up="y", check=True)


# ------------------------------------------------------------------------------ one rule: no output is an input


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """Inputs of every writing command: shapes in data/, a checkpoint with its card, configs and a result folder."""
    ws = tmp_path_factory.mktemp("ws")
    (ws / "data").mkdir()
    for name, k in (("shape", 0), ("other", 1)):
        s = make_shape("chair", k, n_points=256)
        io.write_point_cloud(ws / "data" / f"{name}.ply", s.points, s.normals, s.labels)
    (ws / "net.pt").write_bytes((CHECKPOINTS / "chair.pt").read_bytes())
    (ws / "net.json").write_text('{"card": "of net.pt"}\n')
    (ws / "cfg.json").write_text('{"max_steps": 1, "n_shapes": 8, "n_points": 64}\n')
    (ws / "ft.json").write_text('{"max_steps": 1}\n')
    assert main(["fit", str(ws / "data" / "shape.ply"), "--out", str(ws / "res"), *FAST_FIT]) == 0
    (ws / "links").mkdir()
    return ws


def _snapshot(folder: Path) -> dict:
    return {str(p.relative_to(folder)): (os.readlink(p) if p.is_symlink() else p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


#: (argv with OUT for the output, the input OUT names, what the message says): an input named as an output of
#: every command that writes.
NAMED_AS_OUTPUT = [
    (["fit", "data/shape.ply", "--out", "OUT", *FAST_FIT], "data/shape.ply", "is the input"),
    (["fit", "data", "--out", "OUT", *FAST_FIT], "data", "is the input"),
    (["fit", "data", "--out", "OUT", *FAST_FIT], "data/results", "lies inside the input folder"),
    (["fit", "data/shape.ply", "--out", "OUT", "--mesh-format", "ply", *FAST_FIT], "data", "is the input"),
    (["abstract", "data/shape.ply", "--model", "net.pt", "--out", "OUT"], "net.pt", "is the input"),
    (["generate", "--model", "net.pt", "--out", "OUT"], "net.pt", "is the input"),
    (["interpolate", "data/shape.ply", "data/other.ply", "--model", "net.pt", "--out", "OUT"], "data/other.ply",
     "is the input"),
    (["evaluate", "net.pt", "--json", "OUT"], "net.pt", "is the input"),
    (["evaluate", "net.pt", "--json", "OUT"], "net.json", "is the input"),
    (["evaluate", "net.pt", "--data-dir", "data", "--json", "OUT"], "data/scores.json", "lies inside the input folder"),
    (["train", "--config", "cfg.json", "--out", "run", "--release", "OUT"], "cfg.pt", "is the input"),
    (["train", "--config", "cfg.json", "--finetune", "ft.json", "--out", "run", "--release", "OUT"], "ft.pt",
     "is the input"),
    (["train", "--config", "cfg.json", "--out", "OUT"], "cfg.json", "is the input"),
    (["train", "--config", "cfg.json", "--data-dir", "data", "--out", "OUT"], "data/run", "lies inside the input"),
    (["train", "--config", "cfg.json", "--out", "run", "--release", "OUT"], "run/best.pt", "is also the run's best.pt"),
    (["view", "res", "--out", "OUT"], "res/shape.json", "is the input"),
    (["view", "res/shape.json", "--out", "OUT"], "res/shape_segmentation.ply", "is the input"),
]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=st.sampled_from(NAMED_AS_OUTPUT), spelling=st.sampled_from(["relative", "absolute", "dotdot", "link"]))
def test_no_command_writes_over_its_inputs_however_the_output_is_spelled_property(workspace, monkeypatch, capsys,
                                                                                  case, spelling):
    argv, target, says = case
    monkeypatch.chdir(workspace)
    path = workspace / target
    if spelling == "link":
        if not path.exists() or target.endswith(".pt") and "--release" in argv:  # a card is found by its name
            return
        link = workspace / "links" / f"to_{path.name}"
        link.unlink(missing_ok=True)
        link.symlink_to(path)
        spelled = str(link)
    else:
        spelled = {"relative": target, "absolute": str(path),
                   "dotdot": f"links/../{target}"}[spelling]
    before = _snapshot(workspace)
    start = time.perf_counter()
    assert main([a if a != "OUT" else spelled for a in argv]) == 2
    err = capsys.readouterr().err
    assert says in err and "Traceback" not in err and err.count("\n") == 1, err
    assert _snapshot(workspace) == before, "nothing written, created or removed"
    assert time.perf_counter() - start < 10, "refused before any work"


def test_samples_never_replace_existing_files_unless_forced(tmp_path, capsys):
    samples = ["samples", "--out", str(tmp_path), "--per-category", "1", "--points", "64", "--no-figure"]
    assert main(samples) == 0
    capsys.readouterr()
    before = _snapshot(tmp_path)
    assert main(samples) == 2
    err = capsys.readouterr().err
    assert "already holds 9 of the sample files" in err and "--force" in err
    assert _snapshot(tmp_path) == before
    committed = tmp_path / "committed"  # a copy of one committed file: data_samples/ as it is in the repository
    (committed / "meshes").mkdir(parents=True)
    (committed / "meshes" / "chair_0.ply").write_bytes((SAMPLE_MESH.parent / "chair_0.ply").read_bytes())
    assert main(["samples", "--out", str(committed)]) == 2
    assert "chair_0.ply" in capsys.readouterr().err
    assert sorted(p.name for p in committed.rglob("*")) == ["chair_0.ply", "meshes"]
    assert main([*samples, "--force"]) == 0


# ------------------------------------------------------------------------------ markup and formulas in names


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=st.lists(st.sampled_from(["<", ">", '"', "'", "&", "=", ";", "%", " ", "a", "script", "onload"]),
                     min_size=1, max_size=8).map("".join).map(str.strip).filter(lambda s: s not in ("", ".", "..")))
def test_page_links_never_carry_markup_from_a_name_property(workspace, name):
    from html import unescape
    from urllib.parse import unquote

    from cuboidlib.export_view import write_view_html

    two = workspace / "two_results"  # more results than a page holds: pages linked to each other
    if not two.exists():
        two.mkdir()
        for stem in ("a", "b"):
            (two / f"{stem}.json").write_bytes((workspace / "res" / "shape.json").read_bytes())
        (two / "shape_segmentation.ply").write_bytes((workspace / "res" / "shape_segmentation.ply").read_bytes())
    pages = write_view_html(two, workspace / "pages" / f"{name}.html", max_points=50, per_page=1)
    assert len(pages) == 2
    text = pages[0].read_text()
    nav = text[text.index('<p style="font-family:sans-serif">'):]
    nav = nav[:nav.index("</p>")]
    hrefs = nav.split('href="')[1:]
    assert len(hrefs) == 1
    href = hrefs[0][:hrefs[0].index('"')]
    assert unquote(unescape(href)) == pages[1].name
    assert not set(href) & set("<>\"' ") and nav.count("<") == 5, nav  # <p>, <b>, </b>, <a>, </a>: no other markup


@settings(max_examples=60, deadline=None)
@given(value=st.one_of(st.text(max_size=20), st.integers(), st.floats(allow_nan=False), st.none()))
def test_summary_cells_never_start_a_formula_property(value):
    from cuboidlib.cli_shapes import csv_cell

    cell = csv_cell(value)
    text = "" if value is None else str(value)
    assert cell[:1] not in ("=", "+", "-", "@", "\t", "\r")
    assert cell == text or cell == "'" + text


# ------------------------------------------------------------------------------ files: unclear failures made clear


def _zip(name: str, content: bytes) -> bytes:
    import io as bytes_io
    import zipfile

    buffer = bytes_io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr(name, content)
    return buffer.getvalue()


@pytest.mark.parametrize("name", ["s.ply", "s.obj", "s.off", "s.txt", "s.pts", "s.xyz", "s.npy", "s.stl", "s.glb",
                                  "s.seg", "s.json"])
@pytest.mark.parametrize("packing", ["gzip", "zip"])
def test_a_compressed_or_archived_file_is_named_as_such_by_every_reader(tmp_path, chair, name, packing):
    import gzip

    from cuboidlib.config import read_config_file

    content = b"ply\nformat ascii 1.0\n" if name.endswith(".ply") else b"0 0 0\n1 0 0\n0 1 0\n"
    path = tmp_path / name
    path.write_bytes(gzip.compress(content) if packing == "gzip" else _zip(name, content))
    what = "gzip-compressed.*gunzip" if packing == "gzip" else r"a zip archive \(a NumPy .npz file is one\)"
    read = {".seg": io.read_labels, ".json": read_config_file}.get(path.suffix, lambda p: io.load_point_cloud(p, 64))
    with pytest.raises(ValueError, match=f"{name}: is {what}"):
        read(path)


def test_an_npz_archive_named_npy_is_reported_and_skipped_in_a_folder_run(tmp_path, chair, capsys):
    data = tmp_path / "data"
    data.mkdir()
    io.write_point_cloud(data / "good.ply", chair.points, chair.normals)
    np.savez(data / "bad.npz", points=chair.points)
    (data / "bad.npz").rename(data / "bad.npy")
    with pytest.raises(ValueError, match=r"bad.npy: is a zip archive \(a NumPy .npz file is one\), not a NumPy .npy "
                                         r"array; .*np.save the array you want"):
        io.read_point_cloud(data / "bad.npy")
    assert main(["fit", str(data), "--out", str(tmp_path / "out"), *[a for a in FAST_FIT if a != "--quiet"]]) == 1
    err = capsys.readouterr().err
    assert "skipped" in err and "bad.npy: is a zip archive" in err and "Traceback" not in err
    assert (tmp_path / "out" / "good.json").is_file()


@pytest.mark.parametrize("deep", ["[" * 50_000 + "]" * 50_000, '{"a": ' * 50_000 + "1" + "}" * 50_000])
def test_json_nested_too_deeply_is_refused_wherever_json_is_read(tmp_path, capsys, deep):
    from cuboidlib.config import read_config_file
    from cuboidlib.export import read_cuboids_json, read_manifest
    from cuboidlib.files import MANIFEST, result_files_in
    from cuboidlib.release import read_card

    nested = "nested too deeply"
    path = tmp_path / "deep.json"
    path.write_text(deep)
    for read in (read_config_file, read_cuboids_json):
        with pytest.raises(ValueError, match=f"deep.json: the JSON is {nested}"):
            read(path)
    assert main(["train", "--config", str(path), "--out", str(tmp_path / "run")]) == 2
    assert nested in capsys.readouterr().err
    assert main(["view", str(path), "--out", str(tmp_path / "v.html"), "--quiet"]) == 2
    assert nested in capsys.readouterr().err
    (tmp_path / "chair.pt").write_bytes(b"")
    (tmp_path / "chair.json").write_text(deep)  # the checkpoint's card
    with pytest.raises(ValueError, match=nested):
        read_card(tmp_path / "chair.pt")
    (tmp_path / MANIFEST).write_text(deep)  # a results folder's own files are then only those beside result JSONs
    assert read_manifest(tmp_path) is None and MANIFEST not in result_files_in(tmp_path)
    root = tmp_path / "shapenet"
    (root / "train_test_split").mkdir(parents=True)
    (root / "synsetoffset2category.txt").write_text("Chair\t03001627\n")
    (root / "train_test_split" / "shuffled_train_file_list.json").write_text(deep)
    with pytest.raises(ValueError, match=f"shuffled_train_file_list.json: the JSON is {nested}"):
        io.shapenet_part_files(root, "chair")
    assert main(["train", "--set", f"model.k={deep}", "--out", str(tmp_path / "run")]) == 2
    assert "--set model.k: the value is nested too deeply" in capsys.readouterr().err


@pytest.mark.parametrize("eol", ["\r", "\r\n"])
def test_a_byte_order_mark_and_cr_line_ends_are_read_in_every_text_format(tmp_path, chair, eol):
    from cuboidlib.config import read_config_file
    from cuboidlib.mesh_files import read_polygon_mesh

    bom = b"\xef\xbb\xbf"
    rows = [" ".join(repr(v) for v in p) for p in chair.points[:20].astype(np.float64).tolist()]
    files = {
        "c.xyz": rows,
        "c.pts": [str(len(rows))] + rows,
        "c.ply": ["ply", "format ascii 1.0", f"element vertex {len(rows)}", "property double x", "property double y",
                  "property double z", "end_header"] + rows,
    }
    for name, lines in files.items():
        (tmp_path / name).write_bytes(bom + (eol.join(lines) + eol).encode())
        np.testing.assert_array_equal(io.read_point_cloud(tmp_path / name).points, chair.points[:20])
    square = ["v 0 0 0", "v 1 0 0", "v 1 1 0", "v 0 1 0"]
    meshes = {"m.obj": ["# a square", *square, "f 1 2 3 4"], "m.off": ["OFF", "4 1 0", *(v[2:] for v in square),
                                                                       "4 0 1 2 3"]}
    for name, lines in meshes.items():
        (tmp_path / name).write_bytes(bom + (eol.join(lines) + eol).encode())
        mesh = read_polygon_mesh(tmp_path / name)
        assert mesh.vertices.shape == (4, 3) and mesh.indices.tolist() == [0, 1, 2, 3]
    (tmp_path / "c.seg").write_bytes(bom + eol.join(["3", "1", "2"]).encode())
    assert io.read_labels(tmp_path / "c.seg").tolist() == [3, 1, 2]
    (tmp_path / "c.json").write_bytes(bom + eol.join(["{", '"seed": 3', "}"]).encode())
    assert read_config_file(tmp_path / "c.json") == {"seed": 3}


@pytest.mark.parametrize("header, message", [
    ("element vertex 1\nproperty float x\nproperty float y\nproperty float x\n",
     "PLY element 'vertex' declares property 'x' twice"),
    ("element vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement face 0\n"
     "property list uchar int vertex_indices\nproperty list uchar int vertex_indices\n",
     "PLY element 'face' declares property 'vertex_indices' twice"),
    ("element vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement vertex 1\nproperty float x\n",
     "the PLY header declares element 'vertex' twice"),
    ("element vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement face 1\n"
     "property list float int vertex_indices\n", "PLY list 'vertex_indices' has count type 'float'"),
])
def test_a_duplicated_or_ill_typed_ply_property_is_refused_by_name(tmp_path, header, message):
    path = tmp_path / "dup.ply"
    path.write_text(f"ply\nformat ascii 1.0\n{header}end_header\n0 0 0\n")
    with pytest.raises(ValueError, match=f"dup.ply: {message}"):
        io.read_point_cloud(path)
