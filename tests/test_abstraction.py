import ast
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cuboidlib
from cuboidlib.abstraction import Abstraction, OrientationWarning
from cuboidlib.export import read_cuboids_json
from cuboidlib.fitting import FitConfig
from cuboidlib.io import read_point_cloud, write_point_cloud
from cuboidlib.shapes import PART_NAMES, make_shape

MESHES = Path(__file__).resolve().parents[1] / "data_samples" / "meshes"


@pytest.fixture(scope="module")
def table_cloud(tmp_path_factory):
    """A table as a point cloud file in millimetres, moved away from the origin, with part labels."""
    s = make_shape("table", 3, n_points=1024)
    path = tmp_path_factory.mktemp("in") / "table.ply"
    write_point_cloud(path, s.points * 1000.0 + np.array([500.0, 0.0, -200.0]), s.normals, s.labels)
    return path, s


def test_three_lines_abstract_a_file_and_write_it_in_its_own_units(tmp_path, table_cloud):
    path, shape = table_cloud
    result = cuboidlib.abstract(path, model="table")
    files = result.save(tmp_path)
    assert {k: p.name for k, p in files.items()} == {
        "points": "table_segmentation.ply", "json": "table.json", "glb": "table.glb"}
    cuboids, meta = read_cuboids_json(files["json"])
    assert meta["coordinates"] == "original" and meta["method"]["name"] == "network"
    assert meta["num_existing"] == result.num_existing >= 2
    # the cuboids are in millimetres around the input: their centres lie inside its bounding box
    lo, hi = shape.points.min(0) * 1000 + [500, 0, -200], shape.points.max(0) * 1000 + [500, 0, -200]
    centers = cuboids.centers[0][cuboids.exists[0]].numpy()
    assert ((centers > lo - 1) & (centers < hi + 1)).all()
    np.testing.assert_allclose(result.numpy()["centers"], centers, rtol=1e-5, atol=1e-3)
    cloud = read_point_cloud(files["points"])
    assert len(cloud) == 1024 and set(np.unique(cloud.labels)) <= set(result.numpy()["index"].tolist())


def test_units_and_position_do_not_change_the_abstraction(table_cloud):
    path, shape = table_cloud
    in_file = cuboidlib.abstract(path, model="table")
    as_array = cuboidlib.abstract(np.concatenate([shape.points, shape.normals], axis=1), model="table")
    torch.testing.assert_close(in_file.cuboids.centers, as_array.cuboids.centers, atol=1e-4, rtol=1e-4)
    assert np.array_equal(in_file.labels, as_array.labels)
    assert in_file.scale == pytest.approx(1000.0 * as_array.scale, rel=1e-6)


def test_part_labels_of_the_input_name_the_cuboids(table_cloud):
    path, _ = table_cloud
    result = cuboidlib.abstract(path, model="table", part_names=PART_NAMES["table"])
    doc = result.to_dict()
    named = {c["part_name"] for c in doc["cuboids"] if c["exists"]}
    assert named <= {"top", "leg", None} and "top" in named
    with pytest.raises(ValueError, match="part labels up to 1 but part_names gives only 1"):
        cuboidlib.abstract(path, model="table", part_names=("top",))


def test_without_a_model_the_shape_is_fitted_alone():
    s = make_shape("chair", 0, n_points=600)
    result = cuboidlib.abstract(s.points, model=None, fit_config=FitConfig(steps=40, seed=1))
    assert result.method["name"] == "fit" and result.method["steps"] == 40
    assert 2 <= result.num_existing <= 16 and result.chamfer < 0.02
    assert result.normals is not None  # estimated, since the array had none
    tighten = result.method["tighten"]
    assert tighten["steps"] > 0 and result.chamfer == pytest.approx(min(tighten["chamfer"].values()), abs=1e-6)


def test_dict_round_trip_and_arrays(table_cloud):
    path, _ = table_cloud
    result = cuboidlib.abstract(path, model="table", part_names=PART_NAMES["table"])
    doc = json.loads(json.dumps(result.to_dict()))
    back = Abstraction.from_dict(doc)
    torch.testing.assert_close(back.cuboids.centers, result.cuboids.centers.double(), atol=1e-6, rtol=1e-6)
    assert back.part_names == PART_NAMES["table"] and back.chamfer == pytest.approx(result.chamfer)
    arrays = result.numpy("normalized")
    k = result.num_existing
    assert arrays["centers"].shape == (k, 3) and arrays["rotations"].shape == (k, 3, 3)
    np.testing.assert_allclose(arrays["rotations"] @ arrays["rotations"].transpose(0, 2, 1), np.eye(3)[None].repeat(k, 0),
                               atol=1e-5)
    fig = result.plot()
    assert len(fig.data) >= k


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match=r"\(N, 3\) / \(N, 6\) array"):
        cuboidlib.abstract(np.zeros((10, 4)), model="table")
    with pytest.raises(ValueError, match="centers must be"):
        cuboidlib.abstract(np.random.default_rng(0).random((100, 3)), model="table", centers="middle")
    with pytest.raises(FileNotFoundError):
        cuboidlib.abstract("no_such_file.ply", model="table")


def test_python_dash_m_runs_the_command_line_tool():
    done = subprocess.run([sys.executable, "-m", "cuboidlib", "--version"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.strip().endswith(cuboidlib.__version__)


def test_importing_cuboidlib_is_light_and_offers_the_public_names():
    code = ("import sys, cuboidlib; assert 'torch' not in sys.modules; "
            "print(sorted(n for n in cuboidlib.__all__ if n != '__version__'))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    for name in ast.literal_eval(done.stdout):
        assert getattr(cuboidlib, name) is not None


def test_the_readme_example_runs_as_written(tmp_path, monkeypatch):
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    section = readme[readme.index("## Your own shapes, in three lines"):]
    code = section[section.index("```python\n") + 10: section.index("```\n", section.index("```python"))]
    (tmp_path / "data_samples").symlink_to(MESHES.parent)
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(compile(code, "README.md", "exec"), namespace)
    assert namespace["result"].num_existing >= 2
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "chair_0.glb", "chair_0.json", "chair_0_segmentation.ply"]


def test_the_built_wheel_ships_the_committed_networks_and_loads_them(tmp_path):
    import zipfile

    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", str(root), "--no-deps", "--no-build-isolation",
                           "-w", str(tmp_path / "wheel"), "-q"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    (wheel,) = (tmp_path / "wheel").glob("cuboidlib-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for category in ("chair", "table", "airplane", "animal"):
        assert {f"cuboidlib/networks/{category}.pt", f"cuboidlib/networks/{category}.json",
                f"cuboidlib/networks/configs/{category}.json"} <= names
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    # import the unpacked wheel, not this checkout (whose editable install hooks into sys.meta_path)
    code = (f"import sys; sys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in repr(f)]; "
            f"sys.path.insert(0, {str(site)!r}); "
            "from cuboidlib.applications import checkpoint_dir, load_trained_model; "
            "model, state, path = load_trained_model('chair'); print(path)")
    env = {k: v for k, v in os.environ.items() if k != "CUBOIDLIB_CHECKPOINTS"}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                         env=env)
    assert run.returncode == 0, run.stderr
    assert Path(run.stdout.strip()) == site / "cuboidlib" / "networks" / "chair.pt"


@pytest.mark.parametrize("up, front", [("z", None), ("x", "-z"), ("-y", "z")])
def test_another_up_axis_gives_the_upright_result_written_back_in_the_input_axes(tmp_path, up, front):
    from cuboidlib.abstraction import frame_rotation

    s = make_shape("chair", 4, n_points=1024)
    R = frame_rotation(up, front)
    turned = np.concatenate([s.points @ R, s.normals @ R], axis=1)  # the chair with `up` as its up axis
    upright = cuboidlib.abstract(np.concatenate([s.points, s.normals], axis=1), model="chair")
    told = cuboidlib.abstract(turned, model="chair", up=up, front=front)
    assert np.array_equal(told.labels, upright.labels) and told.chamfer == pytest.approx(upright.chamfer, rel=1e-5)
    torch.testing.assert_close(told.cuboids.half_sizes, upright.cuboids.half_sizes, atol=1e-5, rtol=1e-4)
    mine = told.numpy("normalized")
    ref = upright.numpy("normalized")
    np.testing.assert_allclose(mine["centers"], ref["centers"] @ R, atol=1e-4)  # rows: R^T c
    np.testing.assert_allclose(mine["rotations"], R.T[None] @ ref["rotations"], atol=1e-4)
    assert told.method["up"] == up
    files = told.save(tmp_path)
    cloud = read_point_cloud(files["points"])
    np.testing.assert_allclose(cloud.points, turned[:, :3], atol=1e-5)  # the input's own points, frame and units
    np.testing.assert_allclose(cloud.normals, turned[:, 3:], atol=1e-5)


def test_up_and_front_must_be_axes_at_right_angles():
    from cuboidlib.abstraction import frame_rotation

    with pytest.raises(ValueError, match="up must be one of"):
        frame_rotation("w")
    with pytest.raises(ValueError, match="must be perpendicular"):
        frame_rotation("z", "-z")


def test_merging_a_network_result_records_the_cuboids_before_and_after(table_cloud):
    path, _ = table_cloud
    network = cuboidlib.abstract(path, model="table", up="y")
    merged = cuboidlib.abstract(path, model="table", up="y", merge=math.inf)  # every cuboid into one
    assert merged.method["merge"]["max_growth"] == math.inf and "merge" not in network.method
    assert merged.method["merge"]["cuboids"] == {"before": int(network.cuboids.exists.sum()), "after": 1}
    assert int(merged.cuboids.exists.sum()) == 1 and len(np.unique(merged.labels)) == 1
    with pytest.raises(ValueError, match="merge acts on a network's cuboids"):
        cuboidlib.abstract(path, model=None, merge=0.25)
    with pytest.raises(ValueError, match="merge must be None or a growth >= 0"):
        cuboidlib.abstract(path, model="table", merge=-0.5)


def test_refining_a_network_result_keeps_its_cuboid_slots_and_records_the_steps(table_cloud):
    path, _ = table_cloud
    network = cuboidlib.abstract(path, model="table")
    refined = cuboidlib.abstract(path, model="table", refine=60)
    assert refined.method["refine"]["steps"] == 60 and "refine" not in network.method
    assert set(np.nonzero(refined.cuboids.exists[0].numpy())[0]) <= set(np.nonzero(network.cuboids.exists[0].numpy())[0])
    assert np.mean(refined.labels == network.labels) > 0.8, "the segmentation stays the network's, mostly"
    assert refined.chamfer < network.chamfer
    with pytest.raises(ValueError, match="refine starts the fit from a network"):
        cuboidlib.abstract(path, model=None, refine=10)
    with pytest.raises(ValueError, match="refine must be a non-negative number of steps"):
        cuboidlib.abstract(path, model="table", refine=-1)


def test_up_auto_finds_the_frame_of_a_turned_shape_by_the_networks_reconstruction():
    s = make_shape("chair", 3, n_points=1024)
    turn = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # +y up, facing +z  ->  +z up, facing -y (Blender's)
    cloud = np.concatenate([s.points @ turn.T, s.normals @ turn.T], axis=1)
    auto = cuboidlib.abstract(cloud, model="chair", up="auto")
    assert auto.method["up_auto"]["chosen"] == {"up": "z", "front": "-y"}, "the axis frame itself, not one near it"
    assert auto.method["up_auto"]["by"] == "axis" and np.array_equal(auto.frame, turn.T)  # p_course = R p_input
    assert 0 < auto.method["up_auto"]["frames"] <= 30
    with pytest.warns(OrientationWarning, match=r"with up z the network's cuboids reconstruct it") as caught:
        default = cuboidlib.abstract(cloud, model="chair")
    assert caught[0].filename == __file__, "the warning points at the caller's line"
    assert auto.chamfer < 0.5 * default.chamfer, "the default +y up fits far worse"
    assert default.method["up_check"]["suggested"] == "z" and default.frame is None, "a warning, not a turn"
    with pytest.raises(ValueError, match="up='auto' chooses the frame by the network"):
        cuboidlib.abstract(cloud, model=None, up="auto")


def test_an_upright_shape_gets_no_orientation_warning_and_up_y_skips_the_check():
    import warnings

    s = make_shape("chair", 3, n_points=1024)
    cloud = np.concatenate([s.points, s.normals], axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", OrientationWarning)
        checked = cuboidlib.abstract(cloud, model="chair")
    scores = checked.method["up_check"]["chamfer"]
    assert sorted(scores) == sorted(["x", "y", "z", "-x", "-y", "-z"]) and checked.method["up_check"]["suggested"] is None
    assert min(scores, key=scores.get) == "y"
    told = cuboidlib.abstract(cloud, model="chair", up="y")
    assert "up_check" not in told.method, "an explicit up is trusted"
    assert abs(checked.chamfer - told.chamfer) < 1e-6, "the check's own +y result is the answer"
    assert told.chamfer < scores["y"] < 4 * told.chamfer, "the frame score is the Chamfer distance on fewer samples"
    assert "up_check" not in cuboidlib.abstract(cloud[:300], model=None, fit_config=FitConfig(steps=5)).method


def test_abstract_reads_the_input_and_loads_the_network_once_whatever_up(monkeypatch):
    import cuboidlib.abstraction as pipeline

    calls = {"read": 0, "load": 0}
    read, load = pipeline.load_point_cloud, pipeline.load_trained_model

    def counted_read(*args, **kwargs):
        calls["read"] += 1
        return read(*args, **kwargs)

    def counted_load(*args, **kwargs):
        calls["load"] += 1
        return load(*args, **kwargs)

    monkeypatch.setattr(pipeline, "load_point_cloud", counted_read)
    monkeypatch.setattr(pipeline, "load_trained_model", counted_load)
    path = MESHES / "chair_0.ply"
    for up in ("y", None, "auto"):
        calls.update(read=0, load=0)
        cuboidlib.abstract(path, model="chair", up=up)
        assert calls == {"read": 1, "load": 1}, f"up={up!r}: {calls}"


def test_abstract_and_the_fit_of_one_shape_run_on_one_thread_and_restore_the_callers_count(monkeypatch):
    import cuboidlib.fitting as fitting

    seen = []
    optimise = fitting._optimise
    monkeypatch.setattr(fitting, "_optimise", lambda *a, **k: (seen.append(torch.get_num_threads()), optimise(*a, **k))[1])
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        s = make_shape("chair", 3, n_points=512)
        cuboidlib.abstract(np.concatenate([s.points, s.normals], 1), model=None, fit_config=FitConfig(steps=2))
        assert seen == [1] and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_a_refinement_never_returns_a_higher_chamfer_distance_than_the_networks(table_cloud, monkeypatch):
    import cuboidlib.abstraction as pipeline
    from cuboidlib.geometry import Cuboids

    path, _ = table_cloud
    network = cuboidlib.abstract(path, model="table", up="y")
    refined = cuboidlib.abstract(path, model="table", up="y", refine=60)
    record = refined.method["refine"]
    assert record["kept"] == "refined" and record["chamfer"]["network"] == pytest.approx(network.chamfer, abs=1e-6)
    assert refined.chamfer == pytest.approx(record["chamfer"]["refined"], abs=1e-6) and refined.chamfer < network.chamfer

    def looser(points, cuboids, *args, **kwargs):  # a refinement that makes every cuboid three times larger
        return Cuboids(cuboids.centers, cuboids.quaternions, 3 * cuboids.half_sizes, cuboids.exists)

    monkeypatch.setattr(pipeline, "tighten_cuboids", looser)
    kept = cuboidlib.abstract(path, model="table", up="y", refine=60)
    assert kept.method["refine"]["kept"] == "network" and kept.chamfer == pytest.approx(network.chamfer, abs=1e-9)
    assert np.array_equal(kept.labels, network.labels), "the start is returned whole, segmentation included"


def test_a_shape_of_another_category_warns_naming_that_network_and_fallback_takes_it():
    import warnings

    from cuboidlib.abstraction import NetworkFitWarning

    s = make_shape("table", 0, n_points=1024)
    cloud = np.concatenate([s.points, s.normals], axis=1)
    with pytest.warns(NetworkFitWarning, match=r"nearer the table network's .* pass model='table'") as caught:
        off = cuboidlib.abstract(cloud, model="chair", up="y", check=True)
    assert caught[0].filename == __file__, "the warning points at the caller's line"
    check = off.method["network_check"]
    assert check["speaks"] and check["warned"] and check["route"] == "table" and check["given"] == "chair"
    assert check["latent_distance"]["chair"] == off.method["latent_distance"] > check["threshold"]["chair"]
    assert check["latent_distance"]["table"] < check["threshold"]["table"]
    with pytest.warns(NetworkFitWarning, match="used the table network instead"):
        taken = cuboidlib.abstract(cloud, model="chair", up="y", fallback=True)
    assert taken.method["name"] == "network" and Path(taken.method["checkpoint"]).stem == "table"
    assert taken.method["fallback"]["network_check"]["route"] == "table"
    assert taken.method["fallback"]["network"]["latent_distance"] == off.method["latent_distance"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", NetworkFitWarning)
        own = cuboidlib.abstract(cloud, model="table", up="y", check=True)
        unchecked = cuboidlib.abstract(cloud, model="chair", up="y")
    assert taken.chamfer == pytest.approx(own.chamfer, abs=1e-9), "the route is the table network's own result"
    assert taken.chamfer < off.chamfer
    assert not own.method["network_check"]["speaks"] and "network_check" not in unchecked.method
    with pytest.raises(ValueError, match="check and fallback must be True or False"):
        cuboidlib.abstract(cloud, model="chair", check="yes")


def test_a_shape_no_network_knows_warns_naming_the_fit_and_fallback_fits_it():
    from cuboidlib.abstraction import NetworkFitWarning
    from cuboidlib.thin_shapes import thin_shape

    insect = np.concatenate(thin_shape("insect", 0, 1024), axis=1)
    with pytest.warns(NetworkFitWarning, match=r"unlike the training shapes of every network .*model=None"):
        result = cuboidlib.abstract(insect, model="animal", up="y", check=True)
    check = result.method["network_check"]
    assert check["route"] == "fit" and all(check["latent_distance"][n] > check["threshold"][n] for n in check["threshold"])
    with pytest.warns(NetworkFitWarning, match="fell back to the per-shape fit"):
        fitted = cuboidlib.abstract(insect, model="animal", up="y", fallback=True)
    assert fitted.method["name"] == "fit" and fitted.method["fallback"]["network_check"]["route"] == "fit"
    assert fitted.chamfer < result.chamfer


def test_a_checkpoint_outside_the_committed_ones_is_checked_with_the_default_threshold(tmp_path):
    import shutil

    from cuboidlib.applications import committed_checkpoints
    from cuboidlib.network_check import DEFAULT_THRESHOLD, LATENT_THRESHOLDS

    mine = shutil.copy(committed_checkpoints()["chair"], tmp_path / "mine.pt")  # the chair network, by another name
    s = make_shape("chair", 2, n_points=1024)
    result = cuboidlib.abstract(np.concatenate([s.points, s.normals], axis=1), model=mine, up="y", check=True)
    check = result.method["network_check"]
    assert check["given"] == "mine.pt" and check["threshold"]["mine.pt"] == DEFAULT_THRESHOLD
    assert set(check["latent_distance"]) == {"mine.pt", *committed_checkpoints()}
    assert check["latent_distance"]["mine.pt"] == pytest.approx(check["latent_distance"]["chair"], abs=0.01)
    assert (DEFAULT_THRESHOLD == LATENT_THRESHOLDS["chair"]) == (not check["speaks"]), \
        "the same network: silent unless its own threshold is below the committed one's"


def test_a_loaded_network_without_its_checkpoint_is_recorded_as_unchecked():
    import warnings

    from cuboidlib.abstraction import NetworkFitWarning
    from cuboidlib.thin_shapes import thin_shape

    net = cuboidlib.load_trained_model("animal")[0]
    insect = np.concatenate(thin_shape("insect", 0, 1024), axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", NetworkFitWarning)
        result = cuboidlib.abstract(insect, model=net, up="y", check=True)
    assert not result.method["network_check"]["speaks"] and "latent statistics" in result.method["network_check"]["unchecked"]


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(log_scale=st.floats(-3, 6), offset=st.tuples(*[st.floats(-1e4, 1e4)] * 3), model=st.sampled_from([None, "chair"]),
       subsample=st.booleans())
def test_a_point_cloud_object_gives_the_cuboids_in_its_files_coordinates_property(tmp_path, log_scale, offset, model,
                                                                                  subsample):
    """abstract(load_point_cloud(f)) and abstract(f) give the same cuboids, in f's own coordinates; so does a
    PointCloud holding f's raw points."""
    from cuboidlib.io import PointCloud, load_point_cloud

    s = make_shape("chair", 1, n_points=300)
    points = s.points.astype(np.float64) * 10.0**log_scale + np.array(offset)
    path = write_point_cloud(tmp_path / "moved.ply", points, s.normals, s.labels)
    n = 200 if subsample else None
    fit = FitConfig(steps=2, num_cuboids=3)
    options = dict(n_points=n, up="y", fit_config=fit if model is None else None)
    from_file = cuboidlib.abstract(path, model, **options)
    loaded = load_point_cloud(path, n, fewer_ok=True)  # normalised, with the file's centre and scale
    raw = read_point_cloud(path)  # the file's own coordinates
    for shape in (loaded, PointCloud(raw.points, raw.normals, raw.labels, source="moved.ply")):
        result = cuboidlib.abstract(shape, model, **{**options, "n_points": None} if shape is loaded else options)
        size = float(np.linalg.norm(np.ptp(points, axis=0)))
        np.testing.assert_allclose(result.scale, from_file.scale, rtol=1e-5)
        np.testing.assert_allclose(result.center, from_file.center, atol=1e-5 * size)
        np.testing.assert_allclose(result.numpy()["centers"], from_file.numpy()["centers"], atol=1e-3 * size)
        np.testing.assert_allclose(result.numpy()["sizes"], from_file.numpy()["sizes"], atol=1e-3 * size)
        doc = result.to_dict()  # the JSON claims the input's coordinates, and they are
        assert doc["coordinates"] == "original"
        lo, hi = points.min(axis=0), points.max(axis=0)
        centres = result.numpy()["centers"]
        assert ((centres > lo - 0.5 * size) & (centres < hi + 0.5 * size)).all()
