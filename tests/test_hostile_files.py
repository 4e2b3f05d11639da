"""Unusual and hostile files and commands: a correct answer or a clear error, never a silent wrong one, and
nothing of the user's overwritten.

The file-side half of tests/test_hostile_inputs.py: meshes, point clouds and result files that are odd, huge,
hostile or mislabelled, outputs that would overwrite inputs, and names that carry markup.
"""

import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cuboidlib import io
from cuboidlib.applications import resolve_checkpoint
from cuboidlib.cli import main
from cuboidlib.normalization import normalize
from cuboidlib.shapes import make_shape
from test_hostile_inputs import FAST_FIT, SAMPLE_MESH

CHECKPOINTS = Path(__file__).resolve().parents[1] / "data_samples" / "checkpoints"


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
