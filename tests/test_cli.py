"""Tests of the command-line tool's fit, abstract, generate, interpolate and view subcommands.

Each subcommand runs once through a real subprocess (``python -m cuboidlib.cli``) on the files of
data_samples/, as a user would; the many small variations (flags, bad arguments) run in-process
through ``main(argv)``, which is the same code without the cost of starting Python and torch again.
The network is a tiny randomly initialised one: these tests check the plumbing, not the quality.
"""

from __future__ import annotations

import csv
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cuboidlib
from cuboidlib.applications import CHECKPOINT_DIR_ENV
from cuboidlib.checkpoint import save_checkpoint
from cuboidlib.cli import build_parser, main
from cuboidlib.export import MESH_FORMATS, read_cuboids_json
from cuboidlib.fitting import FitConfig
from cuboidlib.io import read_point_cloud, write_point_cloud
from cuboidlib.model import CuboidAbstractionNet, ModelConfig
from cuboidlib.shapes import make_shape
from cuboidlib.train_config import TrainConfig

SAMPLES = Path(cuboidlib.__file__).resolve().parent.parent / "data_samples"
TINY = ModelConfig.small(num_cuboids=6, k=8, edge_dims=(8,), global_dim=16, latent_dim=8, cuboid_code_dim=8,
                         cuboid_feature_dims=(16,), exist_hidden_dim=8, seg_dim=8)
SUMMARY = re.compile(
    r"^(\d+) cuboids? used of (\d+) \| Chamfer distance ([0-9.e+-]+) \(squared L2, mean over points per direction, "
    r"sum of the two directions, 4096 points sampled on the cuboids; on the normalised shape\) \| [0-9.]+ s$"
)


def run(*args, env: dict | None = None) -> subprocess.CompletedProcess:
    environment = {**os.environ, "OMP_NUM_THREADS": "1", **(env or {})}
    return subprocess.run([sys.executable, "-m", "cuboidlib.cli", *map(str, args)], capture_output=True,
                          text=True, env=environment, timeout=300)


def assert_one_line_error(stderr: str, *fragments: str) -> None:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1, stderr
    assert "Traceback" not in stderr and "error:" in lines[0]
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """A tiny network saved like a training run (TrainConfig with n_points = 256)."""
    torch.manual_seed(0)
    net = CuboidAbstractionNet(TINY)
    path = tmp_path_factory.mktemp("run") / "best.pt"
    return save_checkpoint(path, TrainConfig(model=TINY, n_points=256).to_dict(), net.state_dict(), step=3)


@pytest.fixture(scope="module")
def moved_cloud(tmp_path_factory) -> tuple[Path, np.ndarray]:
    """data_samples' chair_0 points, scaled by 10 and shifted: a shape in its own coordinates."""
    cloud = read_point_cloud(SAMPLES / "points" / "chair_0.ply")
    points = cloud.points.astype(np.float64) * 10 + np.array([5.0, 2.0, -3.0])
    path = write_point_cloud(tmp_path_factory.mktemp("input") / "big_chair.ply", points, cloud.normals, cloud.labels)
    return path, read_point_cloud(path).points


# ----------------------------------------------------------------------------------------------
# Every subcommand through a subprocess
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fitted(tmp_path_factory, moved_cloud) -> tuple[Path, subprocess.CompletedProcess]:
    out = tmp_path_factory.mktemp("fit")
    proc = run("fit", moved_cloud[0], "--out", out, "--cuboids", 6, "--steps", 15, "--points", 4096,
               "--mesh-format", "glb,obj,ply", "--part-names", "back,seat,leg,arm")
    return out, proc


def test_fit_writes_json_meshes_and_segmentation_in_the_input_coordinates(fitted, moved_cloud):
    out, proc = fitted
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    match = SUMMARY.match(lines[0])
    assert match, lines[0]
    used, total = int(match[1]), int(match[2])
    assert total == 6 and 1 <= used <= 6 and float(match[3]) > 0
    assert lines[1].startswith("wrote ")
    names = {"big_chair.json", "big_chair.glb", "big_chair.obj", "big_chair.mtl", "big_chair.ply",
             "big_chair_segmentation.ply"}
    assert names <= {p.name for p in out.iterdir()}
    cuboids, meta = read_cuboids_json(out / "big_chair.json")
    assert meta["coordinates"] == "original" and meta["num_existing"] == used and meta["source"] == "big_chair.ply"
    assert meta["method"]["name"] == "fit" and meta["method"]["steps"] == 15
    assert meta["normalization"]["scale"] == pytest.approx(10.0, rel=1e-3)  # the sample has diagonal ~1
    assert meta["chamfer"]["value"] == pytest.approx(float(match[3]), rel=1e-3)
    assert meta["part_names"] == ["back", "seat", "leg", "arm"]
    exists = cuboids.exists[0]
    assert all(label is not None and label >= 0 for label, e in zip(meta["part_labels"], exists) if e)
    segmented = read_point_cloud(out / "big_chair_segmentation.ply")
    np.testing.assert_allclose(segmented.points, moved_cloud[1], atol=1e-5)  # all points, original frame
    assert set(segmented.labels.tolist()) <= set(torch.nonzero(exists)[:, 0].tolist())
    # the existing cuboids sit where the (moved) points are
    lo, hi = moved_cloud[1].min(axis=0), moved_cloud[1].max(axis=0)
    centers = cuboids.centers[0][exists].numpy()
    assert ((centers > lo - 1) & (centers < hi + 1)).all()
    glb = trimesh.load(out / "big_chair.glb", process=False)
    assert len(glb.graph.nodes_geometry) == used


def test_view_writes_a_self_contained_page(fitted):
    out, _ = fitted
    proc = run("view", out)
    assert proc.returncode == 0, proc.stderr
    page = out / "view.html"
    assert proc.stdout.strip().startswith(f"wrote {page}")
    html = page.read_text()
    assert "plotly.js v" in html and "<script src=" not in html.replace(" ", "")
    assert "big_chair.ply" in html


def test_abstract_runs_the_network_on_a_mesh(tmp_path, checkpoint):
    proc = run("abstract", SAMPLES / "meshes" / "table_0.ply", "--model", checkpoint, "--out", tmp_path)
    assert proc.returncode == 0, proc.stderr
    match = SUMMARY.match(proc.stdout.splitlines()[0])
    assert match and int(match[2]) == TINY.num_cuboids
    cuboids, meta = read_cuboids_json(tmp_path / "table_0.json")
    assert meta["method"]["name"] == "network" and meta["method"]["points"] == 256  # as in training
    assert meta["method"]["checkpoint"] == str(checkpoint) and meta["method"]["step"] == 3
    assert cuboids.num_cuboids == TINY.num_cuboids and int(cuboids.exists.sum()) == int(match[1])
    assert len(read_point_cloud(tmp_path / "table_0_segmentation.ply")) == 256
    assert (tmp_path / "table_0.glb").is_file()


def test_generate_writes_one_shape_per_sample(tmp_path, checkpoint):
    proc = run("generate", "--model", checkpoint, "--out", tmp_path, "--count", 3, "--seed", 4,
               "--mesh-format", "ply")
    assert proc.returncode == 0, proc.stderr
    first = proc.stdout.splitlines()[0]
    assert re.match(r"^3 shapes generated \| cuboids used: \d \d \d of 6 \| [0-9.]+ s$", first), first
    for k in range(3):
        cuboids, meta = read_cuboids_json(tmp_path / f"generated_{k:02d}.json")
        assert meta["coordinates"] == "normalized" and meta["method"]["sample"] == k
        assert (tmp_path / f"generated_{k:02d}.ply").is_file()
    used = [int(read_cuboids_json(tmp_path / f"generated_{k:02d}.json")[1]["num_existing"]) for k in range(3)]
    assert first.split(": ")[1].split(" of")[0] == " ".join(map(str, used))


def test_interpolate_writes_the_path_and_reports_its_smoothness(tmp_path, checkpoint):
    a, b = SAMPLES / "points" / "chair_0.ply", SAMPLES / "meshes" / "chair_2.ply"
    proc = run("interpolate", a, b, "--model", checkpoint, "--out", tmp_path, "--steps", 4)
    assert proc.returncode == 0, proc.stderr
    first = proc.stdout.splitlines()[0]
    assert first.startswith("4 steps from chair_0.ply to chair_2.ply | largest move of an existing cuboid")
    ts = [read_cuboids_json(tmp_path / f"step_{k:02d}.json")[1]["method"]["t"] for k in range(4)]
    assert ts == pytest.approx([0, 1 / 3, 2 / 3, 1]) and ts[0] == 0 and ts[-1] == 1


def test_bad_path_is_one_readable_line(tmp_path):
    proc = run("fit", tmp_path / "missing.ply", "--out", tmp_path)
    assert proc.returncode == 2 and proc.stdout == ""
    assert_one_line_error(proc.stderr, "cuboidlib fit: error:", "missing.ply: no such file")


def test_bad_format_is_one_readable_line(tmp_path):
    (tmp_path / "shape.abc").write_text("1 2 3\n")
    proc = run("fit", tmp_path / "shape.abc", "--out", tmp_path / "out")
    assert proc.returncode == 2
    assert_one_line_error(proc.stderr, "unsupported file type '.abc'")


def test_bad_number_is_one_readable_line(tmp_path):
    proc = run("fit", SAMPLES / "points" / "chair_0.ply", "--out", tmp_path, "--steps", "many")
    assert proc.returncode == 2
    assert_one_line_error(proc.stderr, "argument --steps: expected a non-negative integer, got 'many'",
                          "cuboidlib fit --help")


def test_traceback_is_shown_only_when_asked_for(tmp_path):
    proc = run("fit", tmp_path / "missing.ply", "--out", tmp_path, "--traceback")
    assert proc.returncode != 0 and "Traceback" in proc.stderr
    assert "FileNotFoundError: " in proc.stderr and "missing.ply: no such file" in proc.stderr


# ----------------------------------------------------------------------------------------------
# Variations in-process
# ----------------------------------------------------------------------------------------------


def test_help_of_every_subcommand_and_the_defaults_it_shows(capsys):
    commands = ("fit", "abstract", "generate", "interpolate", "view")
    texts = {}
    for command in commands:
        with pytest.raises(SystemExit) as info:
            main([command, "--help"])
        assert info.value.code == 0
        texts[command] = " ".join(capsys.readouterr().out.split())
        assert texts[command].startswith(f"usage: cuboidlib {command}") and "--traceback" in texts[command]
    assert set(commands) <= set(build_parser()._subparsers._group_actions[0].choices)
    defaults = FitConfig()  # the defaults shown are the fitting module's
    assert f"are used (default: {defaults.num_cuboids})" in texts["fit"]
    assert f"Adam steps (default: {defaults.steps})" in texts["fit"]
    assert f"keep the lowest loss (default: {defaults.restarts})" in texts["fit"]
    assert f"any of {','.join(MESH_FORMATS)} (default: glb)" in texts["fit"]  # the one list, export's


def test_fit_a_mesh_quietly_in_the_normalised_frame(tmp_path, capsys):
    code = main(["fit", str(SAMPLES / "meshes" / "table_0.ply"), "--out", str(tmp_path), "--steps", "5",
                 "--cuboids", "4", "--points", "512", "--normalized", "--quiet"])
    assert code == 0
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""
    cuboids, meta = read_cuboids_json(tmp_path / "table_0.json")
    assert meta["coordinates"] == "normalized" and cuboids.num_cuboids == 4 and meta["method"]["points"] == 512
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "cuboidlib-manifest.json", "table_0.glb", "table_0.json", "table_0_segmentation.ply"]


def test_many_shapes_in_one_run_with_a_summary_and_failures_skipped(tmp_path, checkpoint, capsys):
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    for name in ("chair_0.ply", "chair_1.ply"):
        (inputs / name).write_bytes((SAMPLES / "points" / name).read_bytes())
    (inputs / "broken.ply").write_text("not a ply file")
    (inputs / "notes.txt.bak").write_text("ignored: not a shape file")
    other = tmp_path / "other"
    other.mkdir()
    (other / "chair_0.ply").write_bytes((SAMPLES / "points" / "chair_0.ply").read_bytes())  # same name, other folder
    code = main(["abstract", str(inputs), str(other / "*.ply"), "--model", str(checkpoint), "--out",
                 str(tmp_path / "out"), "--points", "128"])
    err = capsys.readouterr().err
    assert code == 1, "some shape failed"
    assert "skipped" in err and "broken.ply" in err and "Traceback" not in err
    with open(tmp_path / "out" / "summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(Path(r["shape"]).name, r["status"]) for r in rows] == [
        ("broken.ply", "failed"), ("chair_0.ply", "ok"), ("chair_1.ply", "ok"), ("chair_0.ply", "ok")]
    assert [r["result"] for r in rows[1:]] == ["chair_0.json", "chair_1.json", "chair_0_2.json"]
    assert "not a PLY file" in rows[0]["error"] and all(0 <= int(r["cuboids_used"]) <= 6 for r in rows[1:])
    manifest = json.loads((tmp_path / "out" / "cuboidlib-manifest.json").read_text())
    assert manifest["complete"] and "summary.csv" in manifest["files"] and "chair_0_2.json" in manifest["files"]
    assert main(["fit", str(inputs / "chair_*.ply"), "--out", str(tmp_path / "fits"), "--steps", "3", "--quiet"]) == 0
    assert sorted(p.name for p in (tmp_path / "fits").glob("*.json") if p.name != "cuboidlib-manifest.json") == [
        "chair_0.json", "chair_1.json"]
    assert main(["fit", str(tmp_path / "nothing_*.ply"), "--out", str(tmp_path / "none")]) == 2
    assert_one_line_error(capsys.readouterr().err, "no mesh or point cloud file matches this pattern")


def test_abstract_warns_on_stderr_when_the_input_looks_z_up(tmp_path, capsys):
    from cuboidlib.abstraction import frame_rotation

    s = make_shape("chair", 3, n_points=1024)
    path = tmp_path / "chair_zup.xyz"
    np.savetxt(path, np.concatenate([s.points @ frame_rotation("z"), s.normals @ frame_rotation("z")], axis=1))
    assert main(["abstract", str(path), "--model", "chair", "--out", str(tmp_path / "out"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "warning: chair_zup.xyz looks like it is not +y up: with --up z the network reconstructs it" in err
    assert err.count("\n") == 1, err
    assert main(["abstract", str(path), "--model", "chair", "--up", "z", "--out", str(tmp_path / "z"), "--quiet"]) == 0
    assert capsys.readouterr().err == ""


def test_abstract_warns_on_stderr_when_the_network_does_not_fit_the_shape(tmp_path, capsys):
    s = make_shape("table", 0, n_points=1024)
    path = tmp_path / "table.xyz"
    np.savetxt(path, np.concatenate([s.points, s.normals], axis=1))
    assert main(["abstract", str(path), "--model", "chair", "--up", "y", "--out", str(tmp_path / "out"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("warning: table.xyz: it lies nearer the table network's training shapes than the chair "
                          "network's (latent distance ") and err.rstrip().endswith("pass --model table"), err
    assert err.count("\n") == 1, err
    assert main(["abstract", str(path), "--model", "table", "--up", "y", "--out", str(tmp_path / "own"), "--quiet"]) == 0
    assert capsys.readouterr().err == ""


def test_up_auto_says_which_frame_it_chose(tmp_path, capsys):
    # at the network's own density (its 1024 training points, the default): with 256 points the upright chair
    # was reconstructed better upside down, so the choice is only as good as the network on that input
    code = main(["abstract", str(SAMPLES / "points" / "chair_1.ply"), "--model", "chair", "--up", "auto", "--out",
                 str(tmp_path / "out")])
    assert code == 0, capsys.readouterr().err
    assert "--up auto chose up y, front z (the input's own axes; " in capsys.readouterr().out
    _, meta = read_cuboids_json(tmp_path / "out" / "chair_1.json")
    assert meta["method"]["up_auto"]["chosen"] == {"up": "y", "front": "z"}
    assert main(["fit", str(SAMPLES / "points" / "chair_1.ply"), "--up", "auto", "--out", str(tmp_path / "f")]) == 2
    assert_one_line_error(capsys.readouterr().err, "give a model")


def test_abstract_accepts_a_committed_checkpoint_name(tmp_path, checkpoint, monkeypatch, capsys):
    committed = tmp_path / "committed"
    committed.mkdir()
    (committed / "chair.pt").write_bytes(checkpoint.read_bytes())
    monkeypatch.setenv(CHECKPOINT_DIR_ENV, str(committed))
    code = main(["abstract", str(SAMPLES / "points" / "chair_1.ply"), "--model", "chair", "--out",
                 str(tmp_path / "out"), "--points", "128", "--centers", "allocation"])
    assert code == 0, capsys.readouterr().err
    _, meta = read_cuboids_json(tmp_path / "out" / "chair_1.json")
    assert meta["method"]["checkpoint"] == str(committed / "chair.pt") and meta["method"]["centers"] == "allocation"
    assert meta["method"]["points"] == 128
    code = main(["abstract", str(SAMPLES / "points" / "chair_1.ply"), "--model", "chair", "--out",
                 str(tmp_path / "refined"), "--points", "128", "--refine", "20"])
    assert code == 0, capsys.readouterr().err
    _, meta = read_cuboids_json(tmp_path / "refined" / "chair_1.json")
    assert meta["method"]["refine"]["steps"] == 20
    assert ("warning: chair_1.ply: the network check could not run: the network carries no latent statistics"
            in capsys.readouterr().err), "the test network was saved without them, and the command says so"
    code = main(["abstract", str(SAMPLES / "points" / "chair_1.ply"), "--model", "table", "--out",
                 str(tmp_path / "out2")])
    assert code == 2
    assert_one_line_error(capsys.readouterr().err, "table: no such checkpoint", "committed: chair")


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["fit", "SHAPE", "--out", "OUT", "--cuboids", "0"], "argument --cuboids: expected a positive integer"),
        (["fit", "SHAPE", "--out", "OUT", "--mesh-format", "glb,stl"], "unknown mesh format 'stl'"),
        (["fit", "SHAPE"], "the following arguments are required: --out"),
        (["abstract", "SHAPE", "--model", "CKPT", "--out", "OUT", "--threshold", "1.5"],
         "argument --threshold: expected a number in [0, 1)"),
        (["abstract", "SHAPE", "--model", "CKPT", "--out", "OUT", "--refine", "-3"],
         "argument --refine: expected a non-negative integer"),
        (["generate", "--model", "CKPT", "--out", "OUT", "--count", "-1"], "argument --count"),
        (["interpolate", "SHAPE", "--model", "CKPT", "--out", "OUT"], "required: SHAPE_B"),
        (["view"], "required: RESULT"),
        (["fit", "SHAPE", "--out", "OUT", "--part-names", "a,,b"], "argument --part-names: expected comma-separated"),
        (["frobnicate"], "invalid choice: 'frobnicate'"),
    ],
)
def test_bad_arguments_are_one_line_usage_errors(argv, fragment, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert_one_line_error(capsys.readouterr().err, fragment, "--help")


def test_bad_inputs_are_one_line_errors(tmp_path, checkpoint, capsys):
    sample = str(SAMPLES / "points" / "chair_0.ply")
    (tmp_path / "file").write_text("")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"\x00" * 100)
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "cuboids.json").write_text('{"format": "cuboidlib-cuboids", "version": 1}')
    not_ply = tmp_path / "not_a.ply"
    not_ply.write_text("hello")
    empty = tmp_path / "empty"
    (empty / "sub").mkdir(parents=True)  # folders are read one level deep: no shape file here
    cases = [
        (["fit", sample, "--out", str(tmp_path / "file")], "exists and is not a folder"),
        (["fit", str(not_ply), "--out", str(tmp_path / "o")], "not_a.ply: not a PLY file"),
        (["fit", sample, "--out", str(tmp_path / "o"), "--part-names", "back,seat"], "only 2 names"),
        (["fit", str(empty), "--out", str(tmp_path / "o")], "a folder without mesh or point cloud files"),
        (["abstract", sample, "--model", str(junk), "--out", str(tmp_path / "o")], "not a readable cuboidlib checkpoint"),
        (["interpolate", sample, sample, "--model", str(checkpoint), "--out", str(tmp_path / "o"),
          "--steps", "1"], "--steps must be at least 2"),
        (["view", str(tmp_path / "nothing")], "no such result folder"),
        (["view", str(broken)], "\"coordinates\" must be one of"),
    ]
    for argv, fragment in cases:
        assert main(argv) == 2, argv
        assert_one_line_error(capsys.readouterr().err, f"cuboidlib {argv[0]}: error:", fragment)


def test_unexpected_errors_are_one_line_with_a_hint(tmp_path, monkeypatch, capsys):
    import cuboidlib.export_view

    def broken(*args, **kwargs):
        raise RuntimeError("something deep\ninside failed")

    monkeypatch.setattr(cuboidlib.export_view, "write_view_html", broken)
    assert main(["view", str(tmp_path)]) == 1
    assert_one_line_error(capsys.readouterr().err, "RuntimeError: something deep inside failed",
                          "rerun with --traceback")
    with pytest.raises(RuntimeError, match="something deep"):
        main(["view", str(tmp_path), "--traceback"])


def test_an_output_folder_is_never_mixed_or_overwritten_without_asking(tmp_path, capsys):
    out = tmp_path / "out"
    fit = ["fit", str(SAMPLES / "meshes" / "table_0.ply"), "--out", str(out), "--steps", "3", "--cuboids", "4",
           "--points", "256", "--quiet"]
    assert main(fit) == 0
    manifest = json.loads((out / "cuboidlib-manifest.json").read_text())
    assert manifest["complete"] and manifest["files"] == ["table_0.glb", "table_0.json", "table_0_segmentation.ply"]
    assert main(fit) == 2
    assert_one_line_error(capsys.readouterr().err, "already holds 4 file(s)", "--overwrite")
    (out / "notes.txt").write_text("mine")
    other = ["fit", str(SAMPLES / "meshes" / "chair_0.ply"), *fit[2:], "--overwrite"]
    assert main(other) == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "chair_0.glb", "chair_0.json", "chair_0_segmentation.ply", "cuboidlib-manifest.json", "notes.txt"]
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "a.txt").write_text("x")
    assert main([*fit[:3], str(foreign), *fit[4:], "--overwrite"]) == 2
    assert_one_line_error(capsys.readouterr().err, "no cuboidlib run recorded")
    assert (foreign / "a.txt").read_text() == "x"


def test_abstract_says_when_the_shape_is_unlike_the_networks_training_shapes(tmp_path, capsys):
    from cuboidlib.thin_shapes import thin_shape

    points, normals = thin_shape("insect", 1, 1024)
    path = write_point_cloud(tmp_path / "insect.ply", points, normals)
    assert main(["abstract", str(path), "--model", "animal", "--up", "y", "--out", str(tmp_path / "out"),
                 "--quiet"]) == 0
    err = capsys.readouterr().err
    assert re.search(r"^warning: insect.ply: it is unlike the training shapes of every network \(latent distance "
                     r"[\d.]+ under the animal network, threshold [\d.]+; .*`cuboidlib fit`", err, re.M), err


# ----------------------------------------------------------------------------------------------
# Runs over many shapes: every shape reported, whatever fails
# ----------------------------------------------------------------------------------------------

BAD_FILES = {
    "npz.npy": lambda path: (np.savez(path.with_suffix(".npz"), a=np.zeros((5, 3))), path.with_suffix(".npz").rename(path)),
    "garbage.ply": lambda path: path.write_bytes(b"\x00\xffnot a shape"),
    "empty.xyz": lambda path: path.write_text(""),
    "boom.ply": lambda path: path.write_bytes((SAMPLES / "points" / "chair_1.ply").read_bytes()),  # fails inside
}


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kinds=st.lists(st.sampled_from(["good", "zup", *BAD_FILES]), min_size=2, max_size=5),
       names=st.sampled_from(["plain", "formula"]))
def test_a_folder_run_reports_every_shape_and_skips_any_that_fails_property(tmp_path_factory, capsys, kinds, names):
    from unittest import mock

    import cuboidlib.abstraction
    from cuboidlib.abstraction import frame_rotation

    work = tmp_path_factory.mktemp("folder")
    inputs = work / "in"
    inputs.mkdir()
    prefix = {"plain": "", "formula": "=1+"}[names]
    expected = {}
    for k, kind in enumerate(kinds):
        if kind in ("good", "zup"):
            s = make_shape("chair", 3 if kind == "zup" else k, n_points=1024)  # chair 3 on its back: warned
            turn = frame_rotation("z") if kind == "zup" else np.eye(3)
            path = inputs / f"{prefix}{kind}{k}.xyz"
            np.savetxt(path, np.concatenate([s.points @ turn, s.normals @ turn], axis=1))
        else:
            path = inputs / f"{prefix}{k}{kind}"
            BAD_FILES[kind](path)
        expected[path.name] = kind
    real = cuboidlib.abstraction.abstract

    def abstract(path, *args, **kwargs):
        if "boom" in str(path):
            raise RuntimeError("something unforeseen")
        return real(path, *args, **kwargs)

    out = work / "out"
    with mock.patch.object(cuboidlib.abstraction, "abstract", abstract):
        code = main(["abstract", str(inputs), "--model", "chair", "--out", str(out)])
    captured = capsys.readouterr()
    failed = [name for name, kind in expected.items() if kind not in ("good", "zup")]
    assert code == (1 if failed else 0), captured.err
    assert "Traceback" not in captured.err
    with open(out / "summary.csv", newline="") as f:
        rows = {Path(r["shape"].lstrip("'")).name: r for r in csv.DictReader(f)}
    assert set(rows) == set(expected), "every shape has a row"
    for name, kind in expected.items():
        row = rows[name]
        assert row["status"] == ("ok" if kind in ("good", "zup") else "failed"), row
        for cell in row.values():  # no cell is a live formula
            assert cell[:1] not in ("=", "+", "-", "@")
        if kind in ("good", "zup"):
            result = out / row["result"].lstrip("'")
            assert result.is_file() and read_cuboids_json(result)[1]["source"] == name
            assert row["frame"] == "up y, front z"
            if row["warning"]:  # each warning is printed with the shape's name, and kept in its row
                assert f"warning: {name}" in captured.err and row["warning"].lstrip("'").startswith(name)
            if kind == "zup":
                assert "looks like it is not +y up" in row["warning"]
        else:
            assert f"skipped {inputs / name}" in captured.err and name in row["error"]
            assert "(unexpected)" in row["error"] if kind == "boom" else True
    last = captured.out.strip().splitlines()[-1]
    assert last.startswith(f"{len(expected) - len(failed)} of {len(expected)} shapes written to {out}")
    assert (f"; {len(failed)} failed" in last) == bool(failed)
    manifest = json.loads((out / "cuboidlib-manifest.json").read_text())
    assert manifest["complete"] and "summary.csv" in manifest["files"]


def test_a_folder_run_says_which_frame_up_auto_chose_for_each_shape(tmp_path, capsys):
    from cuboidlib.abstraction import frame_rotation

    inputs = tmp_path / "in"
    inputs.mkdir()
    for k, up in enumerate(("y", "z")):
        s = make_shape("chair", k, n_points=1024)
        turn = frame_rotation(up)
        np.savetxt(inputs / f"chair_{up}.xyz", np.concatenate([s.points @ turn, s.normals @ turn], axis=1))
    assert main(["abstract", str(inputs), "--model", "chair", "--up", "auto", "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    with open(tmp_path / "out" / "summary.csv", newline="") as f:
        rows = {Path(r["shape"]).name: r for r in csv.DictReader(f)}
    for name, row in rows.items():
        chosen = read_cuboids_json(tmp_path / "out" / row["result"])[1]["method"]["up_auto"]["chosen"]
        frame = f"up {chosen['up']}, front {chosen['front']}"
        assert row["frame"] == frame and f"{inputs / name}: --up auto chose {frame}" in out
    assert rows["chair_z.xyz"]["frame"].startswith("up z")


@pytest.mark.parametrize("names", [["cuboidlib-manifest.ply"], ["cuboidlib-manifest.ply", "summary.ply", "a.ply"]])
def test_an_input_named_like_a_reserved_file_gets_a_result_of_its_own(tmp_path, capsys, names):
    inputs = tmp_path / "in"
    inputs.mkdir()
    for name in names:
        (inputs / name).write_bytes((SAMPLES / "points" / "chair_0.ply").read_bytes())
    out = tmp_path / "out"
    assert main(["fit", *(str(inputs / n) for n in names), "--out", str(out), "--steps", "2", "--cuboids", "3",
                 "--points", "128", "--quiet"]) == 0
    manifest = json.loads((out / "cuboidlib-manifest.json").read_text())
    assert manifest["format"] == "cuboidlib-manifest" and manifest["complete"]
    results = [p for p in out.glob("*.json") if p.name != "cuboidlib-manifest.json"]
    assert sorted(read_cuboids_json(p)[1]["source"] for p in results) == sorted(names)
    assert "cuboidlib-manifest_2.json" in manifest["files"]
