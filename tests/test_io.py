import csv
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from cuboidlib import io
from cuboidlib.shapes import PART_NAMES, make_shape

DATA_SAMPLES = Path(__file__).resolve().parents[1] / "data_samples"


@pytest.fixture(scope="module")
def chair():
    return make_shape("chair", 1, n_points=600, seed=0)


def _assert_same_cloud(pc, points, normals=None, labels=None):
    np.testing.assert_allclose(pc.points, points, atol=1e-6)
    if normals is None:
        assert pc.normals is None
    else:
        np.testing.assert_allclose(pc.normals, normals, atol=1e-6)
    if labels is None:
        assert pc.labels is None
    else:
        np.testing.assert_array_equal(pc.labels, labels)


@pytest.mark.parametrize("suffix", [".ply", ".txt", ".npy"])
@pytest.mark.parametrize("content", ["points", "normals", "labels"])
def test_point_cloud_writers_and_readers_round_trip(tmp_path, chair, suffix, content):
    normals = chair.normals if content != "points" else None
    labels = chair.labels if content == "labels" else None
    path = io.write_point_cloud(tmp_path / f"c{suffix}", chair.points, normals, labels)
    _assert_same_cloud(io.read_point_cloud(path), chair.points, normals, labels)


def test_ascii_ply_round_trip(tmp_path, chair):
    path = io.write_point_cloud(tmp_path / "a.ply", chair.points, chair.normals, chair.labels, ascii=True)
    assert b"format ascii" in path.read_bytes()[:60]
    _assert_same_cloud(io.read_point_cloud(path), chair.points, chair.normals, chair.labels)


def test_reads_hand_written_ply_variants(tmp_path):
    ascii_ply = (
        "ply\nformat ascii 1.0\ncomment hand written\nelement vertex 3\nproperty double x\n"
        "property double y\nproperty double z\nproperty float normal_x\nproperty float normal_y\n"
        "property float normal_z\nproperty uchar label\nend_header\n"
        "0 0 0 0 0 2 1\n1 0 0 0 0 1 0\n0 1 0 0 0 1 3\n"
    )
    (tmp_path / "a.ply").write_text(ascii_ply)
    pc = io.read_point_cloud(tmp_path / "a.ply")
    np.testing.assert_allclose(pc.points, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_allclose(pc.normals, [[0, 0, 1]] * 3)  # renormalised
    np.testing.assert_array_equal(pc.labels, [1, 0, 3])
    # big-endian binary with an extra element before the vertices
    pts = np.array([[0, 0, 0], [2, 0, 0], [0, 0, 3]], dtype=">f4")
    header = (
        "ply\nformat binary_big_endian 1.0\nelement camera 1\nproperty float f\nelement vertex 3\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    (tmp_path / "b.ply").write_bytes(header.encode() + np.array([1.5], ">f4").tobytes() + pts.tobytes())
    pc = io.read_point_cloud(tmp_path / "b.ply")
    np.testing.assert_allclose(pc.points, pts.astype(float))
    assert pc.normals is None and pc.labels is None


def test_shapenet_part_text_rows_with_float_labels(tmp_path):
    rows = "0.1 0.2 0.3 0 1 0 12.000000\n0.4 0.5 0.6 0 -1 0 15.000000\n-0.1 0 0.2 1 0 0 14.000000\n"
    (tmp_path / "s.txt").write_text(rows)
    pc = io.read_point_cloud(tmp_path / "s.txt")
    np.testing.assert_array_equal(pc.labels, [12, 15, 14])
    np.testing.assert_array_equal(io.shapenet_part_labels(pc.labels, "chair"), [0, 3, 2])
    np.testing.assert_array_equal(io.shapenet_part_labels(np.array([47, 48, 49]), "table"), [0, 1, 1])
    np.testing.assert_array_equal(io.shapenet_part_labels(np.array([1, 3]), "table", "one-based"), [0, 1])
    with pytest.raises(ValueError, match=r"not global ShapeNet-part ids of 'chair'.*12, 13, 14, 15"):
        io.shapenet_part_labels(np.array([0, 1]), "chair")


def _write_shapenet_part(root: Path, chair) -> None:
    (root / "train_test_split").mkdir(parents=True)
    (root / "synsetoffset2category.txt").write_text("Airplane\t02691156\nChair\t03001627\n")
    for synset, names in (("03001627", ["c1", "c2", "c3"]), ("02691156", ["a1"])):
        (root / synset).mkdir()
        for k, name in enumerate(names):
            lab = chair.labels + 12 if synset == "03001627" else np.zeros(len(chair.labels), int)
            io.write_point_cloud(root / synset / f"{name}.txt", chair.points * (k + 1), chair.normals, lab)
    lists = {"train": ["shape_data/03001627/c1", "shape_data/02691156/a1", "shape_data/03001627/c2"],
             "val": [], "test": ["shape_data/03001627/c3"]}
    for split, entries in lists.items():
        (root / "train_test_split" / f"shuffled_{split}_file_list.json").write_text(json.dumps(entries))


def test_shapenet_part_folder_layout(tmp_path, chair):
    _write_shapenet_part(tmp_path, chair)
    train = io.shapenet_part_files(tmp_path, "chair", "train")
    assert [f.name for f in train] == ["c1.txt", "c2.txt"]
    assert [f.name for f in io.shapenet_part_files(tmp_path, "Chair", "test")] == ["c3.txt"]
    assert len(io.shapenet_part_files(tmp_path, "airplane", "trainval")) == 1
    with pytest.raises(ValueError, match="no category 'table'"):
        io.shapenet_part_files(tmp_path, "table")
    (tmp_path / "03001627" / "c2.txt").unlink()
    with pytest.raises(FileNotFoundError, match="c2.txt: listed in the train split but missing"):
        io.shapenet_part_files(tmp_path, "chair", "train")


def test_authors_layout(tmp_path, chair):
    (tmp_path / "chair").mkdir()
    for name in ("s0", "s1", "s2"):
        np.save(tmp_path / "chair" / f"{name}.npy", np.concatenate([chair.points, chair.normals], axis=1))
    np.save(tmp_path / "chair_train.npy", np.array(["s0.npy", "s1.npy"]))
    (tmp_path / "chair_test.txt").write_text("s2\n")
    train = io.authors_layout_files(tmp_path, "chair", "train")
    assert [f.name for f in train] == ["s0.npy", "s1.npy"]
    assert [f.name for f in io.authors_layout_files(tmp_path, "chair", "test")] == ["s2.npy"]
    pc = io.read_point_cloud(train[0])
    _assert_same_cloud(pc, chair.points, chair.normals)
    with pytest.raises(FileNotFoundError, match="table_train.npy: no such file list"):
        io.authors_layout_files(tmp_path, "table", "train")


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".off", ".stl", ".glb"])
def test_mesh_formats_are_sampled_on_the_surface_with_outward_normals(tmp_path, suffix):
    mesh = trimesh.creation.box(extents=[2.0, 1.0, 0.5])
    mesh.apply_translation([1.0, 2.0, 3.0])
    path = tmp_path / f"box{suffix}"
    mesh.export(path)
    pc = io.load_mesh_as_point_cloud(path, 500, seed=1)
    assert pc.points.shape == (500, 3) and pc.normals.shape == (500, 3)
    local = np.abs(pc.points - [1.0, 2.0, 3.0])
    # every point is on a face: one coordinate at its half extent, the others within
    on_face = np.isclose(local, [1.0, 0.5, 0.25], atol=1e-5)
    assert on_face.any(axis=1).all() and (local <= np.array([1.0, 0.5, 0.25]) + 1e-5).all()
    expected = np.where(on_face, np.sign(pc.points - [1.0, 2.0, 3.0]), 0.0)
    first = np.argmax(on_face, axis=1)
    rows = np.arange(500)
    np.testing.assert_allclose(pc.normals[rows, first], expected[rows, first], atol=1e-6)
    # faces receive points by area: the two z faces (2 x 1 each) hold 4 of the total area 7
    assert (np.abs(pc.normals[:, 2]) > 0.5).mean() == pytest.approx(4 / 7, abs=0.07)


def test_inside_out_and_open_meshes_get_outward_normals(tmp_path):
    inside_out = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    inside_out.invert()
    inside_out.export(tmp_path / "inv.obj")
    pc = io.load_mesh_as_point_cloud(tmp_path / "inv.obj", 400)
    assert ((pc.normals * pc.points).sum(axis=1) > 0).all()
    sphere = trimesh.creation.icosphere(subdivisions=3)
    keep = sphere.triangles_center[:, 2] < 0.9  # open at the top, random winding
    rng = np.random.default_rng(0)
    faces = sphere.faces[keep]
    flip = rng.random(len(faces)) < 0.5
    faces[flip] = faces[flip][:, ::-1]
    trimesh.Trimesh(sphere.vertices, faces, process=False).export(tmp_path / "open.obj")
    pc = io.load_mesh_as_point_cloud(tmp_path / "open.obj", 1000)
    assert ((pc.normals * pc.points).sum(axis=1) > 0).mean() > 0.95


def test_load_point_cloud_normalises_subsamples_and_estimates_missing_normals(tmp_path):
    rng = np.random.default_rng(3)
    u = rng.normal(size=(3000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    pts = u * 2.0 + [5.0, -1.0, 0.5]  # a sphere of radius 2
    io.write_point_cloud(tmp_path / "sphere.ply", pts)
    pc = io.load_point_cloud(tmp_path / "sphere.ply", n_points=1000, seed=4)
    assert pc.points.shape == (1000, 3)
    lo, hi = pc.points.min(0), pc.points.max(0)
    np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-6)
    assert np.linalg.norm(hi - lo) == pytest.approx(1.0, abs=1e-6)
    back = pc.points * pc.scale + pc.center
    nearest = np.linalg.norm(back[:, None, :] - pts[None, :, :], axis=2).min(axis=1)
    assert nearest.max() < 1e-5, "(center, scale) map the points back onto the original ones"
    radial = (back - [5.0, -1.0, 0.5]) / 2.0
    assert ((pc.normals * radial).sum(axis=1) > 0.95).mean() > 0.98, "estimated normals point outward"
    mesh_pc = io.load_point_cloud(DATA_SAMPLES / "meshes" / "chair_0.ply", n_points=300)
    assert mesh_pc.points.shape == (300, 3) and mesh_pc.normals.shape == (300, 3)
    assert set(np.unique(mesh_pc.labels)) == {0, 1, 2, 3}, "face labels of the sample mesh carried over"


def test_separate_label_files(tmp_path, chair):
    io.write_point_cloud(tmp_path / "c.txt", chair.points, chair.normals)
    (tmp_path / "c.seg").write_text("\n".join(str(v + 1) for v in chair.labels))
    pc = io.load_point_cloud(tmp_path / "c.txt", labels_path=tmp_path / "c.seg", normalize_shape=False)
    np.testing.assert_array_equal(pc.labels, chair.labels + 1)
    (tmp_path / "short.seg").write_text("1\n2\n3\n")
    with pytest.raises(ValueError, match=r"short.seg: 3 labels for 600 points"):
        io.load_point_cloud(tmp_path / "c.txt", labels_path=tmp_path / "short.seg")


def test_bad_inputs_name_the_file_and_the_problem(tmp_path, chair):
    with pytest.raises(FileNotFoundError, match="missing.ply: no such file"):
        io.read_point_cloud(tmp_path / "missing.ply")
    with pytest.raises(FileNotFoundError, match="missing.obj: no such file"):
        io.load_mesh_as_point_cloud(tmp_path / "missing.obj", 10)
    (tmp_path / "empty.obj").write_text("# nothing here\n")
    with pytest.raises(ValueError, match="empty.obj: .*(empty|no faces)"):
        io.load_mesh_as_point_cloud(tmp_path / "empty.obj", 10)
    (tmp_path / "garbage.glb").write_bytes(b"\x00\x01 definitely not a mesh")
    with pytest.raises(ValueError, match="garbage.glb: unreadable mesh"):
        io.load_mesh_as_point_cloud(tmp_path / "garbage.glb", 10)
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], process=False)
    flat.export(tmp_path / "flat.obj")
    with pytest.raises(ValueError, match="flat.obj: .*zero surface area"):
        io.load_mesh_as_point_cloud(tmp_path / "flat.obj", 10)
    nan = chair.points.copy()
    nan[7, 1] = np.nan
    np.savetxt(tmp_path / "nan.txt", nan)
    with pytest.raises(ValueError, match=r"nan.txt: 1 point\(s\) have NaN .*row 7"):
        io.read_point_cloud(tmp_path / "nan.txt")
    io.write_point_cloud(tmp_path / "few.npy", chair.points[:50], chair.normals[:50])
    with pytest.raises(ValueError, match="few.npy: has only 50 points, fewer than the 100 asked for"):
        io.load_point_cloud(tmp_path / "few.npy", n_points=100)
    np.save(tmp_path / "same.npy", np.ones((20, 3)))
    with pytest.raises(ValueError, match="same.npy: all 20 points are identical"):
        io.read_point_cloud(tmp_path / "same.npy")
    np.save(tmp_path / "cols.npy", np.zeros((20, 5)))
    with pytest.raises(ValueError, match="cols.npy: expected 3 .* columns, got 5"):
        io.read_point_cloud(tmp_path / "cols.npy")
    (tmp_path / "ragged.txt").write_text("0 0 0\n1 1\n")
    with pytest.raises(ValueError, match="ragged.txt: rows have different numbers of columns"):
        io.read_point_cloud(tmp_path / "ragged.txt")
    (tmp_path / "empty.txt").write_text("\n")
    with pytest.raises(ValueError, match="empty.txt: contains no points"):
        io.read_point_cloud(tmp_path / "empty.txt")
    (tmp_path / "x.las").write_text("0 0 0\n")
    with pytest.raises(ValueError, match="x.las: unknown point cloud format"):
        io.read_point_cloud(tmp_path / "x.las")
    with pytest.raises(ValueError, match="is a mesh"):
        io.read_point_cloud(DATA_SAMPLES / "meshes" / "table_0.ply")
    with pytest.raises(ValueError, match="give n_points"):
        io.load_point_cloud(DATA_SAMPLES / "meshes" / "table_0.ply")
    with pytest.raises(ValueError, match=r"labels for 600 points|labels must have"):
        io.write_point_cloud(tmp_path / "w.ply", chair.points, chair.normals, chair.labels[:10])
    zero = chair.normals.copy()
    zero[3] = 0
    with pytest.raises(ValueError, match="zero length"):
        io.write_point_cloud(tmp_path / "z.ply", chair.points, zero)


def test_write_data_samples(tmp_path):
    written = io.write_data_samples(tmp_path, n_per_category=1, n_points=128, figure=False)
    assert (tmp_path / "index.csv") in written
    with open(tmp_path / "index.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["category"] for r in rows] == ["chair", "table", "airplane", "animal"]
    for r in rows:
        pc = io.read_point_cloud(tmp_path / r["points"])
        assert pc.points.shape == (128, 3) and pc.labels.max() < len(PART_NAMES[r["category"]])
        assert io.is_mesh_file(tmp_path / r["mesh"])


def test_committed_data_samples_are_readable():
    with open(DATA_SAMPLES / "index.csv") as f:
        rows = list(csv.DictReader(f))
    assert {r["category"] for r in rows} == set(PART_NAMES)
    for r in rows:
        pc = io.read_point_cloud(DATA_SAMPLES / r["points"])
        assert pc.points.shape == (2048, 3) and pc.normals is not None and pc.labels is not None
        expected = make_shape(r["category"], int(r["collection_index"]), n_points=2048, seed=0)
        np.testing.assert_array_equal(pc.labels, expected.labels)
        np.testing.assert_allclose(pc.points, expected.points, atol=1e-6)
        from_mesh = io.load_mesh_as_point_cloud(DATA_SAMPLES / r["mesh"], 300)
        nearest = np.linalg.norm(from_mesh.points[:, None] - pc.points[None], axis=2).argmin(axis=1)
        # (the concatenated mesh also has faces buried inside other parts, so not 100 %)
        assert (from_mesh.labels == pc.labels[nearest]).mean() > 0.75, "mesh face labels match the points"
    assert (DATA_SAMPLES / "samples.png").is_file() and (DATA_SAMPLES / "README.md").is_file()


def test_samples_command(tmp_path, capsys):
    from cuboidlib.cli import main

    assert main(["samples", "--out", str(tmp_path), "--per-category", "1", "--points", "64", "--no-figure"]) == 0
    assert "wrote 9 files" in capsys.readouterr().out
    assert io.read_point_cloud(tmp_path / "points" / "animal_0.ply").points.shape == (64, 3)
    assert main(["samples", "--out", str(tmp_path), "--points", "0"]) == 2
    assert "--per-category and --points must be positive" in capsys.readouterr().err
