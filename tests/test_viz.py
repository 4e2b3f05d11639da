"""Tests of cuboidlib.viz: the palette, the plotly figures and the matplotlib pictures."""

from __future__ import annotations

import json
import re

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
from matplotlib.colors import to_rgb  # noqa: E402

from cuboidlib.geometry import Cuboids, cuboid_corners  # noqa: E402
from cuboidlib.viz import (  # noqa: E402
    PALETTE,
    cuboid_color,
    figure_bundle,
    plot_cuboids_matplotlib,
    plot_cuboids_matplotlib_grid,
    plot_cuboids_plotly,
    plot_cuboids_plotly_grid,
    plot_cuboids_plotly_slider,
)


@pytest.fixture()
def scene():
    """Three axis-aligned cuboids (the last one not existing) and 30 points labelled 0, 0, 1, 1, 2, ..."""
    centers = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    quaternions = torch.tensor([[[1.0, 0.0, 0.0, 0.0]] * 3])
    half_sizes = torch.tensor([[[0.1, 0.2, 0.3], [0.2, 0.2, 0.2], [0.3, 0.1, 0.1]]])
    exists = torch.tensor([[True, True, False]])
    g = torch.Generator().manual_seed(0)
    points = torch.rand(30, 3, generator=g)
    labels = torch.arange(30) % 3
    return points, labels, Cuboids(centers, quaternions, half_sizes, exists)


def _traces(fig, kind):
    return [t for t in fig.data if t.type == kind]


# ----------------------------------------------------------------------------------------------
# Palette
# ----------------------------------------------------------------------------------------------


def test_palette_has_at_least_24_distinct_valid_hex_colours():
    assert len(PALETTE) >= 24
    assert all(re.fullmatch(r"#[0-9a-f]{6}", c) for c in PALETTE)
    assert len(set(PALETTE)) == len(PALETTE)
    # distinct enough to tell apart: no two colours closer than 0.05 in RGB (unit cube)
    rgb = np.array([to_rgb(c) for c in PALETTE])
    gaps = np.linalg.norm(rgb[:, None] - rgb[None], axis=-1) + np.eye(len(PALETTE))
    assert gaps.min() > 0.05


def test_cuboid_color_is_fixed_per_index_and_cycles():
    assert [cuboid_color(m) for m in range(len(PALETTE))] == list(PALETTE)
    assert cuboid_color(len(PALETTE) + 3) == PALETTE[3]
    assert cuboid_color(np.int64(2)) == PALETTE[2]
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="cuboid index must be a non-negative integer"):
            cuboid_color(bad)


# ----------------------------------------------------------------------------------------------
# Plotly
# ----------------------------------------------------------------------------------------------


def test_plotly_figure_has_one_point_trace_per_label_and_a_mesh_per_existing_cuboid(scene):
    points, labels, cuboids = scene
    fig = plot_cuboids_plotly(points, labels, cuboids, title="three cuboids")
    markers = [t for t in _traces(fig, "scatter3d") if t.mode == "markers"]
    meshes = _traces(fig, "mesh3d")
    edges = [t for t in _traces(fig, "scatter3d") if t.mode == "lines"]
    assert [t.name for t in markers] == ["cuboid 0", "cuboid 1", "cuboid 2"]
    assert [t.marker.color for t in markers] == [PALETTE[0], PALETTE[1], PALETTE[2]]
    assert sum(len(t.x) for t in markers) == 30
    assert [t.name for t in meshes] == ["cuboid 0", "cuboid 1"]  # cuboid 2 does not exist
    assert [t.color for t in meshes] == [PALETTE[0], PALETTE[1]]
    assert all(t.opacity == 0.25 and len(t.x) == 8 and len(t.i) == 12 for t in meshes)
    assert len(edges) == 2 and all(len(t.x) == 36 for t in edges)  # 12 segments, each (a, b, gap)
    assert fig.layout.scene.aspectmode == "data"
    assert fig.layout.title.text == "three cuboids"


def test_plotly_mesh_vertices_are_the_cuboid_corners(scene):
    points, labels, cuboids = scene
    mesh = _traces(plot_cuboids_plotly(points, labels, cuboids, decimals=6), "mesh3d")[1]
    corners = cuboid_corners(cuboids.centers, cuboids.quaternions, cuboids.half_sizes)[0, 1].numpy()
    np.testing.assert_allclose(np.stack([mesh.x, mesh.y, mesh.z], axis=1), corners, atol=1e-6)


def test_plotly_accepts_a_tuple_an_explicit_mask_and_no_labels(scene):
    points, _, cuboids = scene
    as_tuple = (cuboids.centers[0], cuboids.quaternions[0], cuboids.half_sizes[0])
    fig = plot_cuboids_plotly(points.numpy(), None, as_tuple, exists=np.array([False, True, True]))
    assert [t.name for t in _traces(fig, "mesh3d")] == ["cuboid 1", "cuboid 2"]
    markers = [t for t in _traces(fig, "scatter3d") if t.mode == "markers"]
    assert len(markers) == 1 and markers[0].name == "points"


def test_plotly_figure_is_small_subsampled_and_rounded(scene):
    _, _, cuboids = scene
    g = torch.Generator().manual_seed(1)
    many = torch.rand(10000, 3, generator=g, dtype=torch.float64)
    fig = plot_cuboids_plotly(many, torch.zeros(10000, dtype=torch.long), cuboids, max_points=500, decimals=4)
    marker = [t for t in _traces(fig, "scatter3d") if t.mode == "markers"][0]
    assert len(marker.x) == 500
    np.testing.assert_allclose(np.asarray(marker.x, dtype=np.float64), np.round(np.asarray(marker.x, np.float64), 4),
                               atol=1e-6)
    assert len(json.dumps(fig.to_plotly_json(), default=str)) < 60_000


def test_plotly_grid_has_one_scene_per_shape(scene):
    points, labels, cuboids = scene
    items = [(points, labels, cuboids), (points, labels, cuboids, torch.tensor([True, False, False]))]
    fig = plot_cuboids_plotly_grid(items, titles=["a", "b"], cols=2)
    meshes = _traces(fig, "mesh3d")
    assert [t.scene for t in meshes] == ["scene", "scene", "scene2"]
    assert fig.layout.scene2.aspectmode == "data"
    assert [a.text for a in fig.layout.annotations] == ["a", "b"]
    assert fig.layout.showlegend is False


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        ({"points": torch.zeros(5, 2)}, ValueError, r"points \(one shape\) must have shape \(N, 3\)"),
        ({"labels": torch.zeros(7, dtype=torch.long)}, ValueError, r"labels must have shape \(N,\)"),
        ({"labels": torch.zeros(30)}, ValueError, "labels must hold integer cuboid indices"),
        ({"cuboids": "boxes"}, TypeError, "cuboids must be a Cuboids batch"),
        ({"index": 3}, IndexError, "index 3 is out of range"),
        ({"opacity": 2.0}, ValueError, r"opacity must lie in \[0, 1\]"),
        ({"max_points": 0}, ValueError, "max_points must be a positive integer"),
        ({"exists": np.array([True, False])}, ValueError, "exists must have shape"),
    ],
)
def test_plotly_rejects_bad_inputs(scene, kwargs, error, match):
    points, labels, cuboids = scene
    args = {"points": points, "labels": labels, "cuboids": cuboids, **kwargs}
    with pytest.raises(error, match=match):
        plot_cuboids_plotly(**args)


def test_plotly_rejects_batched_cuboid_tuples_and_nan_points(scene):
    points, labels, cuboids = scene
    with pytest.raises(ValueError, match="centers must describe ONE shape"):
        plot_cuboids_plotly(points, labels, (cuboids.centers, cuboids.quaternions, cuboids.half_sizes))
    points = points.clone()
    points[4, 1] = float("nan")
    with pytest.raises(ValueError, match="points contains 1 NaN"):
        plot_cuboids_plotly(points, labels, cuboids)


def test_grids_reject_empty_or_mismatched_items(scene):
    points, labels, cuboids = scene
    for grid in (plot_cuboids_plotly_grid, plot_cuboids_matplotlib_grid):
        with pytest.raises(ValueError, match="items is empty"):
            grid([])
        with pytest.raises(ValueError, match="titles has 2 entries for 1 items"):
            grid([(points, labels, cuboids)], titles=["a", "b"])
        with pytest.raises(ValueError, match=r"item 0 must be a tuple"):
            grid([(points, labels)])


def _sequence(scene):
    """Three steps of one cuboid batch: 2, 1 and 3 existing cuboids, no points, the last one moved."""
    _, _, cuboids = scene
    moved = Cuboids(cuboids.centers + torch.tensor([2.0, 0.0, -1.0]), cuboids.quaternions, cuboids.half_sizes)
    empty = np.zeros((0, 3))
    return [(empty, None, cuboids), (empty, None, cuboids, torch.tensor([False, True, False])), (empty, None, moved)]


def test_plotly_slider_shows_exactly_one_item_per_step(scene):
    items = _sequence(scene)
    fig = plot_cuboids_plotly_slider(items, step_labels=["t = 0", "t = 0.5", "t = 1"], title="path", active=1)
    (slider,) = fig.layout.sliders
    assert [s.label for s in slider.steps] == ["t = 0", "t = 0.5", "t = 1"]
    assert slider.active == 1 and fig.layout.title.text == "path"
    assert all(s.method == "restyle" for s in slider.steps)
    # a mesh and its edges per existing cuboid, and no point trace for empty point sets
    per_item = [2, 1, 3]
    assert len(fig.data) == 2 * sum(per_item) and not any(t.mode == "markers" for t in _traces(fig, "scatter3d"))
    owner = np.repeat(np.arange(3), [2 * n for n in per_item])
    for k, step in enumerate(slider.steps):
        assert step.args[0]["visible"] == (owner == k).tolist()
    assert [bool(t.visible) for t in fig.data] == (owner == 1).tolist()  # the active item is shown first
    meshes = _traces(fig, "mesh3d")
    assert [t.name for t in meshes] == ["cuboid 0", "cuboid 1", "cuboid 1", "cuboid 0", "cuboid 1", "cuboid 2"]


def test_plotly_slider_axes_are_one_fixed_cube_around_every_item(scene):
    items = _sequence(scene)
    fig = plot_cuboids_plotly_slider(items)
    scene_layout = fig.layout.scene
    assert scene_layout.aspectmode == "cube"
    ranges = np.array([scene_layout.xaxis.range, scene_layout.yaxis.range, scene_layout.zaxis.range])
    assert not any(a.autorange for a in (scene_layout.xaxis, scene_layout.yaxis, scene_layout.zaxis))
    np.testing.assert_allclose(ranges[:, 1] - ranges[:, 0], ranges[0, 1] - ranges[0, 0])  # a cube
    # every corner of every item (existing cuboids) lies inside the cube
    corners = []
    for _, _, cub, *rest in items:
        ex = rest[0] if rest else cub.existing()[0]  # what is drawn: the item's mask, else the batch's
        corners.append(cuboid_corners(cub.centers, cub.quaternions, cub.half_sizes)[0, ex].reshape(-1, 3))
    corners = torch.cat(corners).numpy()
    assert (corners >= ranges[:, 0] - 1e-6).all() and (corners <= ranges[:, 1] + 1e-6).all()
    # and the cube is not much larger than the items: the widest extent fills at least 90 % of it
    assert (corners.max(0) - corners.min(0)).max() >= 0.9 * (ranges[0, 1] - ranges[0, 0])
    assert [s.label for s in fig.layout.sliders[0].steps] == ["0", "1", "2"]


def test_plotly_slider_keeps_points_and_rejects_bad_inputs(scene):
    points, labels, cuboids = scene
    fig = plot_cuboids_plotly_slider([(points, labels, cuboids), (points, None, cuboids)])
    markers = [t for t in _traces(fig, "scatter3d") if t.mode == "markers"]
    assert [t.name for t in markers] == ["cuboid 0", "cuboid 1", "cuboid 2", "points"]
    with pytest.raises(ValueError, match="items is empty"):
        plot_cuboids_plotly_slider([])
    with pytest.raises(ValueError, match="step_labels has 1 entries for 2 items"):
        plot_cuboids_plotly_slider([(points, labels, cuboids)] * 2, step_labels=["a"])
    with pytest.raises(ValueError, match=r"active must be an item index in \[0, 2\)"):
        plot_cuboids_plotly_slider([(points, labels, cuboids)] * 2, active=2)
    with pytest.raises(ValueError, match="item 1 must be a tuple"):
        plot_cuboids_plotly_slider([(points, labels, cuboids), (points,)])


# ----------------------------------------------------------------------------------------------
# Matplotlib
# ----------------------------------------------------------------------------------------------


def test_matplotlib_draws_points_and_one_box_per_existing_cuboid(scene):
    points, labels, cuboids = scene
    fig = plt.figure()
    ax = fig.add_subplot(projection="3d")
    plot_cuboids_matplotlib(ax, points, labels, cuboids, title="t")
    boxes = [c for c in ax.collections if type(c).__name__ == "Poly3DCollection"]
    assert len(boxes) == 2
    face_colors = [tuple(np.round(b.get_facecolor()[0][:3], 3)) for b in boxes]
    assert face_colors == [tuple(np.round(to_rgb(PALETTE[m]), 3)) for m in (0, 1)]
    scatter = [c for c in ax.collections if type(c).__name__ == "Path3DCollection"][0]
    assert len(scatter.get_offsets()) == 30
    assert ax.get_title() == "t"
    plt.close(fig)


def test_matplotlib_grid_makes_one_3d_panel_per_shape(scene):
    points, labels, cuboids = scene
    fig = plot_cuboids_matplotlib_grid([(points, labels, cuboids)] * 4, titles=list("abcd"), cols=3)
    assert len(fig.axes) == 4 and all(ax.name == "3d" for ax in fig.axes)
    assert [ax.get_title() for ax in fig.axes] == list("abcd")
    plt.close(fig)


def test_matplotlib_needs_a_3d_axes(scene):
    points, labels, cuboids = scene
    fig, ax = plt.subplots()
    with pytest.raises(TypeError, match="ax must be a matplotlib 3D axes"):
        plot_cuboids_matplotlib(ax, points, labels, cuboids)
    plt.close(fig)


def test_figure_bundle_holds_the_interactive_figure_and_a_png_twin():
    import base64

    import plotly.graph_objects as go

    fig = go.Figure(go.Scatter3d(x=[0, 1], y=[0, 1], z=[0, 1]))
    static = plt.figure(figsize=(3, 3))
    static.add_subplot(projection="3d").plot([0, 1], [0, 1], [0, 1])
    bundle = figure_bundle(fig, static, dpi=100)
    assert bundle["application/vnd.plotly.v1+json"]["data"][0]["type"] == "scatter3d"
    png = base64.b64decode(bundle["image/png"])
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    assert width >= 250 and height >= 250   # 3 inches at 100 dpi, less the tight crop's margins
    assert not plt.fignum_exists(static.number)   # the static twin is closed once rendered


def test_figure_bundle_rejects_a_missing_twin_and_a_low_resolution():
    import plotly.graph_objects as go

    with pytest.raises(TypeError, match="static must be a matplotlib Figure"):
        figure_bundle(go.Figure(), None)
    with pytest.raises(ValueError, match="dpi must be an integer of at least 100"):
        figure_bundle(go.Figure(), plt.figure(), dpi=72)
    with pytest.raises(TypeError, match="fig must be a plotly Figure"):
        figure_bundle(plt.figure(), plt.figure())


def test_draw_network_reads_the_shapes_from_a_forward_pass():
    from cuboidlib.model import CuboidAbstractionNet, ModelConfig
    from cuboidlib.viz import draw_network

    torch.manual_seed(0)
    net = CuboidAbstractionNet(ModelConfig.small()).train()
    fig, shapes = draw_network(net, torch.rand(2, 64, 3))
    m = net.config.num_cuboids
    assert len(fig.axes) == 1 and not fig.axes[0].axison
    assert shapes["affinity"] == (2, 64, m) and shapes["quaternions"] == (2, m, 4)
    assert shapes["point_features"][-1] == shapes["edge1"][-1] + shapes["edge2"][-1]
    texts = " ".join(t.get_text() for t in fig.axes[0].texts)
    assert "(B, N, M)" in texts and "EdgeConv 1" in texts and "B = 2 shapes, N = 64 points" in texts
    assert net.training   # the training mode is restored
    plt.close(fig)


def test_plot_log_draws_one_labelled_panel_per_column():
    from cuboidlib.viz import LOG_PANELS, plot_log

    keys = ["step", *LOG_PANELS]
    train = [{k: str(0.5 + 0.01 * s) if k != "step" else str(s) for k in keys} for s in range(1, 31)]
    val = [dict(row) for row in train[9::10]]
    fig = plot_log(train, val)
    assert len(fig.axes) == len(LOG_PANELS) == 8
    for ax, (title, ylabel, _, _) in zip(fig.axes, LOG_PANELS.values()):
        assert ax.get_title() == title and ax.get_ylabel() == ylabel and ax.get_xlabel() == "training step"
        assert len(ax.lines) == 3   # per step, running mean, validation
    assert [t.get_text() for t in fig.legends[0].texts] == ["train (per step)", "train (mean of 10 steps)",
                                                           "validation"]
    with pytest.raises(ValueError, match="smooth must be a positive integer"):
        plot_log(train, val, smooth=0)
    plt.close("all")
