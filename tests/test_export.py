"""Tests of cuboidlib.export: JSON, GLB / OBJ / PLY meshes, segmented point clouds, results and HTML.

Every format is written and read back (with trimesh or cuboidlib.io) and compared with what went
in: cuboid parameters, corner positions, palette colours and the cuboid index of every face/point.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
import trimesh

from cuboidlib.abstraction import Abstraction
from cuboidlib.export import (
    JSON_FORMAT,
    cuboid_node_name,
    denormalize_cuboids,
    normalize_cuboids,
    palette_rgba,
    read_cuboids_json,
    write_cuboid_mesh,
    write_cuboids_json,
    write_segmented_point_cloud,
)
from cuboidlib.export_view import write_view_html
from cuboidlib.geometry import Cuboids
from cuboidlib.io import read_point_cloud
from cuboidlib.metrics import ChamferConvention
from cuboidlib.rotations import quaternion_to_rotation_matrix, random_quaternions
from cuboidlib.viz import PALETTE, UNLABELLED


def _hex(rgb) -> str:
    return "#" + "".join(f"{int(v):02x}" for v in rgb[:3])


@pytest.fixture()
def cuboids() -> Cuboids:
    """Four rotated cuboids of one shape (float32), cuboid 2 not existing."""
    g = torch.Generator().manual_seed(0)
    centers = torch.rand(1, 4, 3, generator=g) - 0.5
    quaternions = random_quaternions(1, 4, generator=g)
    half_sizes = 0.05 + 0.2 * torch.rand(1, 4, 3, generator=g)
    return Cuboids(centers, quaternions, half_sizes, torch.tensor([[True, True, False, True]]))


def _assert_same(a: Cuboids, b: Cuboids) -> None:
    for name in ("centers", "quaternions", "half_sizes"):
        assert torch.equal(getattr(a, name).to(getattr(b, name).dtype), getattr(b, name)), name
    assert torch.equal(a.existing(), b.existing())


# ----------------------------------------------------------------------------------------------
# Colours and coordinates
# ----------------------------------------------------------------------------------------------


def test_palette_rgba_is_the_course_palette():
    rgba = palette_rgba(len(PALETTE) + 2)
    assert rgba.dtype == np.uint8 and rgba.shape == (len(PALETTE) + 2, 4)
    assert [_hex(c) for c in rgba] == list(PALETTE) + list(PALETTE[:2])
    assert (rgba[:, 3] == 255).all()
    assert cuboid_node_name(7, 16) == "cuboid_07" and cuboid_node_name(7, 101) == "cuboid_007"


def test_denormalize_moves_every_corner_like_the_points(cuboids):
    center, scale = np.array([1.0, -2.0, 0.5]), 3.0
    moved = denormalize_cuboids(cuboids, center, scale)
    expected = cuboids.corners() * scale + torch.tensor(center, dtype=torch.float32)
    torch.testing.assert_close(moved.corners(), expected)
    assert torch.equal(moved.quaternions, cuboids.quaternions) and torch.equal(moved.exists, cuboids.exists)
    back = normalize_cuboids(moved, center, scale)
    torch.testing.assert_close(back.centers, cuboids.centers)
    torch.testing.assert_close(back.half_sizes, cuboids.half_sizes)
    with pytest.raises(ValueError, match="finite positive scale"):
        denormalize_cuboids(cuboids, center, 0.0)
    with pytest.raises(ValueError, match="center must have shape"):
        denormalize_cuboids(cuboids, [1.0, 2.0], 1.0)


# ----------------------------------------------------------------------------------------------
# JSON
# ----------------------------------------------------------------------------------------------


def test_json_round_trip_is_exact_and_documents_every_field(tmp_path, cuboids):
    convention = ChamferConvention()
    path = write_cuboids_json(
        tmp_path / "shape.json", cuboids, coordinates="normalized", center=[1.0, 2.0, 3.0], scale=2.5,
        source="chair [ 1, 2 ].ply", method={"name": "fit", "steps": 10}, part_labels=[1, 0, -1, 2],
        part_names=["back", "seat", "leg"], chamfer=0.0123, chamfer_convention=convention,
    )
    read, meta = read_cuboids_json(path)
    _assert_same(read, cuboids)  # float32 values come back bit for bit
    assert read.centers.dtype == torch.float64
    assert meta["format"] == JSON_FORMAT and meta["version"] == 1 and meta["source"] == "chair [ 1, 2 ].ply"
    assert meta["coordinates"] == "normalized" and meta["num_cuboids"] == 4 and meta["num_existing"] == 3
    assert meta["normalization"]["center"] == [1.0, 2.0, 3.0] and meta["normalization"]["scale"] == 2.5
    assert meta["normalization"]["rule"] == "original = normalized * scale + center"
    assert meta["chamfer"] == {"value": 0.0123, "convention": convention.describe(), "coordinates": "normalized"}
    assert meta["part_labels"] == [1, 0, -1, 2] and meta["method"] == {"name": "fit", "steps": 10}
    assert set(meta["convention"]) == {"center", "quaternion", "rotation_matrix", "size", "units"}
    text = path.read_text()
    doc = json.loads(text)
    assert f'"quaternion": {json.dumps(doc["cuboids"][0]["quaternion"])}' in text  # one line per list of numbers
    first = doc["cuboids"][0]
    assert first["index"] == 0 and first["part_name"] == "seat" and doc["cuboids"][2]["part_name"] is None
    assert first["size"] == (2 * cuboids.half_sizes[0, 0].double()).tolist()
    R = quaternion_to_rotation_matrix(cuboids.quaternions[0, 0])
    torch.testing.assert_close(torch.tensor(first["rotation_matrix"], dtype=torch.float32), R)  # row-major


def test_json_can_be_read_in_either_frame(tmp_path, cuboids):
    path = write_cuboids_json(tmp_path / "n.json", cuboids, coordinates="normalized", center=[0.5, 0, -1], scale=4.0)
    original, meta = read_cuboids_json(path, coordinates="original")
    assert meta["coordinates"] == "original"
    expected = denormalize_cuboids(cuboids.to(dtype=torch.float64), [0.5, 0, -1], 4.0)
    torch.testing.assert_close(original.centers, expected.centers)
    torch.testing.assert_close(original.half_sizes, expected.half_sizes)
    again = write_cuboids_json(tmp_path / "o.json", original, center=[0.5, 0, -1], scale=4.0)
    normalized, _ = read_cuboids_json(again, coordinates="normalized")
    torch.testing.assert_close(normalized.centers, cuboids.centers.double())


def _edited(tmp_path, cuboids, edit) -> str:
    path = write_cuboids_json(tmp_path / "c.json", cuboids)
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda d: d.update(format="something else"), "not a cuboidlib cuboid file"),
        (lambda d: d.update(version=99), "version 99 is not supported"),
        (lambda d: d.update(coordinates="world"), "coordinates"),
        (lambda d: d["normalization"].update(scale=-1), "normalization.scale must be a positive"),
        (lambda d: d.update(cuboids=[]), "non-empty list"),
        (lambda d: d["cuboids"][1].update(index=0), "index"),
        (lambda d: d["cuboids"][0].update(center=[0, 1]), "cuboid 0: center must be a list of 3"),
        (lambda d: d["cuboids"][0].update(size=[0.1, -0.2, 0.3]), "cuboid 0: every size must be positive"),
        (lambda d: d["cuboids"][3].update(exists="yes"), "cuboid 3: \"exists\" must be true or false"),
        (lambda d: d["cuboids"][1].update(quaternion=[2.0, 0, 0, 0]), "quaternions must hold unit vectors"),
        (lambda d: d["cuboids"][1].update(quaternion=[1.0, 0, 0, 0]),
         "cuboid 1: rotation_matrix and quaternion disagree"),
        (lambda d: d["cuboids"][0].update(part_label=-3), "part_label must be a non-negative integer"),
    ],
)
def test_malformed_json_is_rejected_with_the_file_and_entry_named(tmp_path, cuboids, edit, message):
    path = _edited(tmp_path, cuboids, edit)
    with pytest.raises(ValueError, match=message) as info:
        read_cuboids_json(path)
    assert "c.json" in str(info.value)


def test_json_read_errors_for_missing_and_non_json_files(tmp_path, cuboids):
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_cuboids_json(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="bad.json: not valid JSON"):
        read_cuboids_json(bad)
    with pytest.raises(ValueError, match="coordinates must be one of"):
        write_cuboids_json(tmp_path / "x.json", cuboids, coordinates="world")
    with pytest.raises(ValueError, match="needs its chamfer_convention"):
        write_cuboids_json(tmp_path / "x.json", cuboids, chamfer=0.1)
    with pytest.raises(ValueError, match=r"part_labels must be \(4,\) integers"):
        write_cuboids_json(tmp_path / "x.json", cuboids, part_labels=[0, 1])


# ----------------------------------------------------------------------------------------------
# Meshes
# ----------------------------------------------------------------------------------------------


def _corner_set_equal(vertices: np.ndarray, corners: torch.Tensor) -> None:
    """The vertex positions are the 8 corners (any order), within float32 precision."""
    v = np.asarray(vertices, dtype=np.float64)
    c = corners.double().numpy()
    assert len(v) == 8
    distance = np.linalg.norm(v[:, None] - c[None], axis=-1)
    assert distance.min(axis=1).max() < 1e-6 and distance.min(axis=0).max() < 1e-6


def test_glb_has_one_named_node_per_existing_cuboid_with_its_corners_and_colour(tmp_path, cuboids):
    path = write_cuboid_mesh(tmp_path / "c.glb", cuboids)
    scene = trimesh.load(path, process=False)
    assert sorted(scene.graph.nodes_geometry) == ["cuboid_00", "cuboid_01", "cuboid_03"]
    corners = cuboids.corners()[0]
    for node in scene.graph.nodes_geometry:
        transform, geometry = scene.graph[node]
        m = int(node.split("_")[1])
        mesh = scene.geometry[geometry]
        _corner_set_equal(trimesh.transform_points(mesh.vertices, transform), corners[m])
        assert len(mesh.faces) == 12
        assert _hex(mesh.visual.material.baseColorFactor) == PALETTE[m]


def test_obj_has_one_object_and_material_per_existing_cuboid(tmp_path, cuboids):
    path = write_cuboid_mesh(tmp_path / "c.obj", cuboids)
    assert (tmp_path / "c.mtl").is_file()
    scene = trimesh.load(path, process=False)
    assert sorted(scene.geometry) == ["cuboid_00", "cuboid_01", "cuboid_03"]
    corners = cuboids.corners()[0]
    for name, mesh in scene.geometry.items():
        m = int(name.split("_")[1])
        _corner_set_equal(mesh.vertices, corners[m])
        assert len(mesh.faces) == 12
        assert _hex(mesh.visual.material.main_color) == PALETTE[m]


def test_ply_mesh_stores_palette_colours_and_the_cuboid_of_every_face(tmp_path, cuboids):
    path = write_cuboid_mesh(tmp_path / "c.ply", cuboids)
    mesh = trimesh.load(path, process=False)
    face_cuboid = np.asarray(mesh.metadata["_ply_raw"]["face"]["data"]["cuboid"]).reshape(-1)
    assert sorted(set(face_cuboid.tolist())) == [0, 1, 3] and len(face_cuboid) == 36
    corners = cuboids.corners()[0]
    colors = np.asarray(mesh.visual.vertex_colors)
    for m in (0, 1, 3):
        used = np.unique(mesh.faces[face_cuboid == m])
        _corner_set_equal(mesh.vertices[used], corners[m])
        assert all(_hex(c) == PALETTE[m] for c in colors[used])
    # the faces are the cuboids' outward triangles: the mesh encloses the sum of the cuboids' volumes
    volume = sum(8 * float(cuboids.half_sizes[0, m].prod()) for m in (0, 1, 3))
    assert mesh.volume == pytest.approx(volume, rel=1e-5)


def test_mesh_writer_rejects_unknown_formats_and_empty_shapes(tmp_path, cuboids):
    with pytest.raises(ValueError, match="unknown mesh format '.stl'"):
        write_cuboid_mesh(tmp_path / "c.stl", cuboids)
    none = Cuboids(cuboids.centers, cuboids.quaternions, cuboids.half_sizes, torch.zeros(1, 4, dtype=torch.bool))
    with pytest.raises(ValueError, match="no existing cuboid"):
        write_cuboid_mesh(tmp_path / "c.glb", none)


# ----------------------------------------------------------------------------------------------
# Segmented point clouds
# ----------------------------------------------------------------------------------------------


def test_segmented_point_cloud_reads_back_with_labels_normals_and_palette_colours(tmp_path):
    g = torch.Generator().manual_seed(2)
    points = torch.rand(50, 3, generator=g)
    normals = torch.nn.functional.normalize(torch.randn(50, 3, generator=g), dim=-1)
    labels = torch.arange(50) % 4 - 1  # -1, 0, 1, 2, -1, ...
    path = write_segmented_point_cloud(tmp_path / "s.ply", points, labels, normals)
    cloud = read_point_cloud(path)
    assert np.array_equal(cloud.points, points.numpy()) and np.array_equal(cloud.labels, labels.numpy())
    np.testing.assert_allclose(cloud.normals, normals.numpy(), atol=1e-6)
    colors = np.asarray(trimesh.load(path).colors)
    expected = [UNLABELLED if lab < 0 else PALETTE[lab] for lab in labels.tolist()]
    assert [_hex(c) for c in colors] == expected
    with pytest.raises(ValueError, match="labels must be"):
        write_segmented_point_cloud(tmp_path / "s.ply", points, labels[:10])
    with pytest.raises(ValueError, match="written as .ply"):
        write_segmented_point_cloud(tmp_path / "s.txt", points, labels)


# ----------------------------------------------------------------------------------------------
# Whole results and the HTML view
# ----------------------------------------------------------------------------------------------


@pytest.fixture()
def result(cuboids) -> Abstraction:
    g = torch.Generator().manual_seed(3)
    points = (torch.rand(30, 3, generator=g) - 0.5).numpy()
    return Abstraction(cuboids, center=np.array([10.0, 0.0, -5.0]), scale=2.0, points=points,
                             labels=np.arange(30) % 2, source="thing.obj", method={"name": "test"})


def test_result_is_written_in_original_coordinates_by_default(tmp_path, result):
    files = result.save(tmp_path, "thing", formats=("glb", "obj", "ply"))
    assert {k: p.name for k, p in files.items()} == {
        "points": "thing_segmentation.ply", "json": "thing.json", "glb": "thing.glb", "obj": "thing.obj",
        "mtl": "thing.mtl", "ply": "thing.ply",
    }
    read, meta = read_cuboids_json(files["json"])
    assert meta["coordinates"] == "original" and meta["points_file"] == "thing_segmentation.ply"
    expected = denormalize_cuboids(result.cuboids, result.center, result.scale)
    torch.testing.assert_close(read.centers.float(), expected.centers)
    cloud = read_point_cloud(files["points"])
    np.testing.assert_allclose(cloud.points, result.points * 2.0 + result.center, atol=1e-5)
    mesh = trimesh.load(files["ply"], process=False)
    assert mesh.bounds[0, 0] > 8  # the meshes moved with the cuboids (x around 10 +- 1.2)
    normalized = result.save(tmp_path / "n", "thing", normalized=True)
    read_n, meta_n = read_cuboids_json(normalized["json"])
    assert meta_n["coordinates"] == "normalized"
    _assert_same(read_n, result.cuboids)
    np.testing.assert_allclose(read_point_cloud(normalized["points"]).points, result.points, atol=1e-7)


def test_result_rejects_batches_and_unknown_formats(tmp_path, result, cuboids):
    with pytest.raises(ValueError, match="unknown mesh format"):
        result.save(tmp_path, formats=("stl",))
    two = Cuboids(cuboids.centers.expand(2, 4, 3), cuboids.quaternions.expand(2, 4, 4),
                  cuboids.half_sizes.expand(2, 4, 3))
    with pytest.raises(ValueError, match="ONE shape"):
        Abstraction(two)


def test_view_html_is_self_contained_and_shows_every_cuboid(tmp_path, result):
    result.save(tmp_path / "one", "thing")
    (page,) = write_view_html(tmp_path / "one")
    assert page == tmp_path / "one" / "view.html"
    html = page.read_text()
    assert "<script src=" not in html.replace(" ", "")  # plotly.js is embedded, nothing is fetched
    assert "plotly.js v" in html and len(html) > 1_000_000
    figure = html[html.index("Plotly.newPlot("):]
    for m in (0, 1, 3):
        assert f'"cuboid {m}"' in figure
    assert '"cuboid 2"' not in figure  # not existing: no mesh and no points
    assert "thing.obj: 3 of 4 cuboids" in figure


def test_view_legend_names_the_part_of_each_cuboid_when_known(tmp_path, result):
    import dataclasses

    named = dataclasses.replace(result, part_labels=np.array([1, 0, -1, -1]), part_names=("seat", "leg"))
    named.save(tmp_path / "named", "thing")
    (page,) = write_view_html(tmp_path / "named")
    figure = page.read_text()
    figure = figure[figure.index("Plotly.newPlot("):]
    assert '"cuboid 0: leg"' in figure and '"cuboid 1: seat"' in figure
    assert '"cuboid 3"' in figure, "a cuboid without a known part keeps its plain name"
    assert "cuboid 0: leg" in str(named.plot().to_dict()), "Abstraction.plot names the parts too"


def test_view_of_a_folder_of_results_draws_a_grid(tmp_path, cuboids):
    for k in range(3):
        Abstraction(cuboids, method={"name": "generate"}).save(tmp_path, f"generated_{k:02d}", normalized=True)
    (tmp_path / "notes.json").write_text('{"something": "else"}')  # other JSON files are skipped
    (page,) = write_view_html(tmp_path, tmp_path / "page.html")
    html = page.read_text()
    assert '"scene3"' in html and '"scene4"' not in html
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="holds no cuboidlib result"):
        write_view_html(tmp_path / "empty")
    with pytest.raises(FileNotFoundError, match="no such result folder"):
        write_view_html(tmp_path / "missing")


def test_corner_sets_match_for_a_quarter_turn(tmp_path):
    """A cube turned by 45 degrees about y has corners at radius s * sqrt(2) in the xz plane."""
    q = torch.tensor([[[math.cos(math.pi / 8), 0.0, math.sin(math.pi / 8), 0.0]]])
    one = Cuboids(torch.zeros(1, 1, 3), q, torch.full((1, 1, 3), 0.5))
    scene = trimesh.load(write_cuboid_mesh(tmp_path / "q.glb", one), process=False)
    vertices = scene.geometry["cuboid_00"].vertices
    np.testing.assert_allclose(np.hypot(vertices[:, 0], vertices[:, 2]), 0.5 * math.sqrt(2), rtol=1e-6)
    np.testing.assert_allclose(np.abs(vertices[:, 1]), 0.5, rtol=1e-6)


def test_view_of_many_results_is_split_into_linked_pages(tmp_path, cuboids):
    for k in range(7):
        Abstraction(cuboids, method={"name": "generate"}).save(tmp_path, f"generated_{k:02d}", normalized=True)
    pages = write_view_html(tmp_path, per_page=3, max_points=10)
    assert [p.name for p in pages] == ["view.html", "view_2.html", "view_3.html"]
    last = pages[-1].read_text()
    assert "7 results, page 3 of 3" in last and 'href="view.html"' in last and 'href="view_2.html"' in last


def test_a_manifest_decides_which_results_a_folder_shows(tmp_path, cuboids):
    from cuboidlib.export import prepare_output_folder, read_manifest, write_manifest

    files = []
    for k in range(2):
        files += Abstraction(cuboids).save(tmp_path, f"r{k}", normalized=True).values()
    Abstraction(cuboids).save(tmp_path, "stale", normalized=True)  # an earlier run's file, not listed
    write_manifest(tmp_path, files, "test", complete=False)
    assert read_manifest(tmp_path)["complete"] is False
    (page,) = write_view_html(tmp_path)
    assert '"scene2"' in page.read_text() and '"scene3"' not in page.read_text()
    with pytest.raises(ValueError, match="already holds"):
        prepare_output_folder(tmp_path)
    prepare_output_folder(tmp_path, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stale.glb", "stale.json", "view.html"]


def test_a_failed_write_leaves_no_file(tmp_path, cuboids, monkeypatch):
    import trimesh

    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(trimesh.Scene, "export", broken)
    with pytest.raises(OSError, match="disk full"):
        write_cuboid_mesh(tmp_path / "c.glb", cuboids)
    assert list(tmp_path.iterdir()) == []
