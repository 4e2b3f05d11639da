"""The real-mesh loader (benchmarks/real_meshes/load.py) on tiny meshes written here, and the manifest's form."""

from __future__ import annotations

import base64
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import trimesh

from cuboidlib.shapes import PART_NAMES

ROOT = Path(__file__).resolve().parents[1]
FOLDER = ROOT / "benchmarks" / "real_meshes"


def _module():
    spec = importlib.util.spec_from_file_location("real_meshes_load", FOLDER / "load.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


load = _module()

# A rotation that is not the identity: file +z up, file -x front.
ROT = [[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]]


def _entry(path, category, labels, rot=None, root="r"):
    entry = {"id": Path(path).stem, "category": category, "root": root,
             "source": {"repo": "x/y", "commit": "0" * 40, "path": path}, "licence": "CC0-1.0",
             "attribution": "test", "to_network": rot or np.eye(3).tolist()}
    if labels is not None:
        entry["labels"] = labels
    return entry


def _two_box_obj(path: Path, names=("seat", "leg")) -> None:
    """Two unit boxes as OBJ groups: the first at z in [0, 1], the second at z in [-3, -2]."""
    lines, offset = [], 0
    for name, z in zip(names, (0.0, -3.0)):
        box = trimesh.creation.box(bounds=[[0, 0, z], [1, 1, z + 1]])
        lines += [f"v {x} {y} {w}" for x, y, w in box.vertices]
        lines.append(f"g {name}")
        lines += [f"f {a + 1 + offset} {b + 1 + offset} {c + 1 + offset}" for a, b, c in box.faces]
        offset += len(box.vertices)
    path.write_text("\n".join(lines) + "\n")


def test_obj_groups_give_the_labels_and_the_points_stay_in_the_file_frame(tmp_path):
    _two_box_obj(tmp_path / "c.obj")
    entry = _entry("c.obj", "chair", {"by": "group", "map": {"seat": "seat", "leg": "leg"}}, ROT)
    shapes, skipped = load.load_real_shapes({"r": tmp_path}, n_points=512, seed=1, manifest={"shapes": [entry]})
    assert skipped == []
    (shape,) = shapes
    assert shape.points.shape == (512, 3) and shape.points.dtype == np.float32 and shape.labels.dtype == np.int64
    upper = shape.points[:, 2] > -0.5
    assert np.all(shape.labels[upper] == PART_NAMES["chair"].index("seat"))
    assert np.all(shape.labels[~upper] == PART_NAMES["chair"].index("leg"))
    assert 0.4 < upper.mean() < 0.6  # equal areas, equal shares
    np.testing.assert_allclose(np.linalg.norm(shape.normals, axis=1), 1, atol=1e-5)
    # the rotation: file z becomes network y, file -x network z
    net = shape.network_points()
    np.testing.assert_allclose(net[:, 1], shape.points[:, 2], atol=1e-5)
    np.testing.assert_allclose(net[:, 2], -shape.points[:, 0], atol=1e-5)
    again, _ = load.load_real_shapes({"r": tmp_path}, n_points=512, seed=1, manifest={"shapes": [entry]})
    np.testing.assert_array_equal(again[0].points, shape.points)


def test_an_unmapped_group_is_refused_and_a_stale_name_too(tmp_path):
    _two_box_obj(tmp_path / "c.obj", names=("seat", "stretcher"))
    unmapped = _entry("c.obj", "chair", {"by": "group", "map": {"seat": "seat"}})
    stale = dict(_entry("c.obj", "chair", {"by": "group", "map": {"seat": "seat", "stretcher": "leg",
                                                                  "arm_l": "arm"}}), id="stale")
    shapes, skipped = load.load_real_shapes({"r": tmp_path}, manifest={"shapes": [unmapped, stale]})
    assert shapes == []
    assert "not in the label map" in skipped[0] and "stretcher" in skipped[0]
    assert "not in the file" in skipped[1] and "arm_l" in skipped[1]


def test_an_ignored_group_is_dropped_and_a_wrong_part_refused(tmp_path):
    _two_box_obj(tmp_path / "c.obj", names=("top", "shadow"))
    ok = _entry("c.obj", "table", {"by": "group", "map": {"top": "top", "shadow": "ignore"}})
    bad = dict(_entry("c.obj", "table", {"by": "group", "map": {"top": "top", "shadow": "wing"}}), id="bad")
    shapes, skipped = load.load_real_shapes({"r": tmp_path}, n_points=256, manifest={"shapes": [ok, bad]})
    assert len(shapes) == 1 and shapes[0].points[:, 2].min() > -0.01  # nothing sampled on the ignored box
    assert np.all(shapes[0].labels == 0)
    assert len(skipped) == 1 and "wing" in skipped[0]


def test_missing_root_and_missing_file_are_skipped_with_a_line(tmp_path):
    entries = [_entry("c.obj", "chair", None, root="absent"), dict(_entry("nowhere.obj", "chair", None), id="gone")]
    shapes, skipped = load.load_real_shapes({"r": tmp_path}, manifest={"shapes": entries})
    assert shapes == []
    assert skipped[0].startswith("c: no root 'absent'")
    assert skipped[1].startswith("gone:") and "missing" in skipped[1]


def test_glb_nodes_give_the_labels_with_their_transforms(tmp_path):
    scene = trimesh.Scene()
    body = trimesh.creation.box(extents=[1, 1, 4])
    wing = trimesh.creation.box(extents=[6, 0.1, 1])
    scene.add_geometry(body, node_name="Fuselage", geom_name="g_body")
    scene.add_geometry(wing, node_name="Wing.L", geom_name="g_wing",
                       transform=trimesh.transformations.translation_matrix([0, 2, 0]))
    scene.export(str(tmp_path / "p.glb"))
    pieces = load.read_pieces(tmp_path / "p.glb")
    assert sorted(p.name for p in pieces) == ["Fuselage", "Wing.L"]
    wing_piece = next(p for p in pieces if p.name == "Wing.L")
    assert abs(wing_piece.vertices[:, 1].mean() - 2) < 1e-6  # the node's translation applied
    entry = _entry("p.glb", "airplane", {"by": "node", "map": {"Fuselage": "body", "Wing.L": "wing"}})
    (shape,), skipped = load.load_real_shapes({"r": tmp_path}, n_points=400, manifest={"shapes": [entry]})
    assert skipped == []
    high = shape.points[:, 1] > 1.5
    assert np.all(shape.labels[high] == 1) and np.all(shape.labels[~high] == 0)


def _skinned_gltf(path: Path) -> None:
    """Two triangles, one weighted to joint 'Head', one mostly to 'Tail1' (a hand-written glTF)."""
    pos = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1], [0, 0, -1], [1, 0, -1], [0, 1, -1]], np.float32)
    idx = np.arange(6, dtype=np.uint16)
    joints = np.array([[0, 1, 0, 0]] * 3 + [[1, 0, 0, 0]] * 3, np.uint8)
    weights = np.array([[1, 0, 0, 0]] * 3 + [[0.8, 0.2, 0, 0]] * 3, np.float32)
    blobs = [pos.tobytes(), idx.tobytes() + b"\0\0", joints.tobytes(), weights.tobytes()]
    views, offset = [], 0
    for blob in blobs:
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(blob)})
        offset += len(blob)
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0, 1, 2]}],
        "nodes": [{"name": "Head"}, {"name": "Tail1"}, {"name": "Animal", "mesh": 0, "skin": 0}],
        "skins": [{"joints": [0, 1]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "JOINTS_0": 2, "WEIGHTS_0": 3}, "indices": 1}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 6, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5121, "count": 6, "type": "VEC4"},
            {"bufferView": 3, "componentType": 5126, "count": 6, "type": "VEC4"}],
        "bufferViews": views,
        "buffers": [{"byteLength": offset,
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(b"".join(blobs)).decode()}],
    }
    path.write_text(json.dumps(doc))


def test_skin_weights_give_each_triangle_its_part(tmp_path):
    _skinned_gltf(tmp_path / "a.gltf")
    entry = _entry("a.gltf", "animal", {"by": "skin_joint", "map": {"Head": "head", "Tail1": "tail"}})
    (shape,), skipped = load.load_real_shapes({"r": tmp_path}, n_points=300, manifest={"shapes": [entry]})
    assert skipped == []
    front = shape.points[:, 2] > 0
    assert np.all(shape.labels[front] == PART_NAMES["animal"].index("head"))  # joint 0 of [0, 1] is Head
    assert np.all(shape.labels[~front] == PART_NAMES["animal"].index("tail"))  # 0.8 on Tail1
    wrong = dict(entry, labels={"by": "skin_joint", "map": {"Head": "head"}})
    _, skipped = load.load_real_shapes({"r": tmp_path}, manifest={"shapes": [wrong]})
    assert "Tail1" in skipped[0]


def test_segment_colours_label_each_point_by_the_nearest_segment_point(tmp_path):
    _two_box_obj(tmp_path / "t.obj", names=("a", "b"))
    rng = np.random.default_rng(0)
    upper = rng.random((200, 3)) + [0, 0, 0]
    lower = rng.random((200, 3)) + [0, 0, -3]
    cols = np.array([[10, 20, 30]] * 200 + [[200, 0, 5]] * 200)
    rows = [f"{x} {y} {z} {r} {g} {b}" for (x, y, z), (r, g, b) in zip(np.vstack([upper, lower]), cols)]
    header = ["ply", "format ascii 1.0", "element vertex 400", "property float x", "property float y",
              "property float z", "property uchar red", "property uchar green", "property uchar blue", "end_header"]
    (tmp_path / "seg.ply").write_text("\n".join(header + rows) + "\n")
    labels = {"by": "segment_colour", "segments": "seg.ply", "map": {"#0a141e": "top", "#c80005": "leg"}}
    (shape,), skipped = load.load_real_shapes({"r": tmp_path}, n_points=300, manifest={"shapes": [_entry(
        "t.obj", "table", labels)]})
    assert skipped == []
    assert np.all(shape.labels[shape.points[:, 2] > -0.5] == 0) and np.all(shape.labels[shape.points[:, 2] < -1] == 1)


def test_the_manifest_lists_every_shape_fully_and_the_committed_meshes_load():
    data = load.read_manifest()
    ids = [e["id"] for e in data["shapes"]]
    assert len(ids) == len(set(ids))
    for e in data["shapes"]:
        assert e["root"] in data["roots"] and e["category"] in PART_NAMES and e["licence"] and e["attribution"]
        rot = np.asarray(e["to_network"])
        np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-5)
        assert np.linalg.det(rot) > 0
        if "labels" in e:
            assert set(e["labels"]["map"].values()) <= set(PART_NAMES[e["category"]]) | {"ignore"}
    counts = {c: sum(e["category"] == c and "labels" in e for e in data["shapes"]) for c in PART_NAMES}
    assert min(counts.values()) >= 8
    shapes, skipped = load.load_real_shapes({"pyvista": ROOT / "data_samples" / "real" / "pyvista"}, n_points=256,
                                            categories=("airplane", "animal"))
    names = sorted(s.name for s in shapes)
    assert names == ["airplane_pyvista", "animal_pyvista_ant"]
    assert all(s.labels is None for s in shapes)
    assert any("no root 'quaternius'" in line for line in skipped)


def test_command_line_summary(tmp_path, capsys):
    _two_box_obj(tmp_path / "c.obj")
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps({"shapes": [_entry("c.obj", "chair", {"by": "group",
                                                                          "map": {"seat": "seat", "leg": "leg"}})]}))
    assert load.main(["--root", f"r={tmp_path}", "--manifest", str(manifest), "--summary", "--points", "200",
                      "--png", str(tmp_path / "png")]) == 0
    out = capsys.readouterr().out
    assert "chair       1 shapes (1 labelled)" in out and "seat" in out and (tmp_path / "png" / "c.png").is_file()


def test_the_benchmark_refuses_a_model_without_a_known_category(capsys):
    spec = importlib.util.spec_from_file_location("bench_real_meshes", ROOT / "benchmarks" / "bench_real_meshes.py")
    bench = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        spec.loader.exec_module(bench)
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    for bad in ("runs/airplane_v2", "boat=runs/boat"):
        try:
            bench.main(["--model", bad])
        except SystemExit as stop:
            assert stop.code == 2
        else:
            raise AssertionError(f"--model {bad} was accepted")
        assert "--model takes CATEGORY=CHECKPOINT" in capsys.readouterr().err
