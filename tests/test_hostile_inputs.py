"""Unusual and hostile inputs: a correct answer or a clear ValueError/TypeError, never a silent wrong one.

The first part keeps one reproduction per reported case; the second runs property-based cases
(Hypothesis) over the public functions, each checked against a float64 reference where one exists.
"""

import json
import math
import os
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
                                    load_trained_model)
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
SAMPLE_MESH = Path(__file__).resolve().parents[1] / "data_samples" / "meshes" / "table_0.ply"
FAST_FIT = ["--steps", "2", "--cuboids", "3", "--points", "128", "--quiet"]


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
