"""Figures of cuboid abstractions: points coloured by cuboid, translucent cuboids (Figs. 1, 6, 7, 9, 13).

Interactive plotly figures, their static matplotlib twins, and :func:`show_figure` to show both in one
notebook output. Cuboid m is drawn in ``PALETTE[m]`` in every figure and export, as in the paper ("the same
colour represents the cuboids of the same serial number"). Axes: +y up, shapes facing +z
(:mod:`cuboidlib.normalization`); at most ``max_points`` evenly spaced points are drawn per shape.

Inputs of every function: ``points`` (N, 3) and ``labels`` (N,) (cuboid index of every point, or None) of
ONE shape, numpy or torch; ``cuboids`` a :class:`~cuboidlib.geometry.Cuboids` batch with the ``index`` of the
shape, or a tuple ``(centers (M, 3), quaternions (M, 4), half_sizes (M, 3))``; ``exists`` an optional (M,)
bool mask (default: the batch's ``exists`` if set, else all).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from ._checks import as_float_tensor, check_finite, check_shape
from .geometry import CUBOID_TRIANGLES, Cuboids, cuboid_corners, validate_cuboids

__all__ = [
    "PALETTE",
    "UNLABELLED",
    "cuboid_color",
    "plot_cuboids_plotly",
    "plot_cuboids_plotly_grid",
    "plot_cuboids_plotly_slider",
    "plot_cuboids_matplotlib",
    "plot_cuboids_matplotlib_grid",
    "figure_bundle",
    "show_figure",
    "draw_network",
    "plot_log",
]

#: 30 distinct colours (hex); cuboid m is drawn in PALETTE[m % 30]. The first ten are matplotlib's
#: "tab10", then the light "tab20" companions and ten darker or muted tones of "tab20b".
PALETTE: tuple[str, ...] = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
    "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
    "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5",
    "#c49c94", "#f7b6d2", "#c7c7c7", "#dbdb8d", "#9edae5",
    "#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173",
    "#5254a3", "#8ca252", "#bd9e39", "#ad494a", "#a55194",
)  # fmt: skip

#: Colour of points whose label is unknown (labels=None) or negative.
UNLABELLED = "#555555"

#: The 12 edges of a cuboid as pairs of corner indices (CORNER_SIGNS order: corners differing in one bit).
_EDGES = tuple((a, a | (1 << bit)) for a in range(8) for bit in range(3) if not a & (1 << bit))


def cuboid_color(m: int) -> str:
    """Hex colour of cuboid index ``m``, the same in every figure of the course.

    Args:
        m: a cuboid index >= 0.

    Returns:
        ``PALETTE[m % 30]``, e.g. ``"#1f77b4"``.
    """
    if not isinstance(m, (int, np.integer)) or isinstance(m, bool) or m < 0:
        raise ValueError(f"cuboid index must be a non-negative integer, got {m!r}")
    return PALETTE[int(m) % len(PALETTE)]


# ----------------------------------------------------------------------------------------------
# Input handling shared by the plotly and matplotlib versions
# ----------------------------------------------------------------------------------------------


def _to_numpy(x) -> np.ndarray:
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def _one_shape_cuboids(cuboids, exists, index: int) -> tuple[np.ndarray, np.ndarray]:
    """(corners (M, 8, 3) float64, exists (M,) bool) of one shape."""
    if isinstance(cuboids, Cuboids):
        if not -cuboids.batch_size <= index < cuboids.batch_size:
            raise IndexError(f"index {index} is out of range for a batch of {cuboids.batch_size} shapes")
        c, q, s = cuboids.centers[index], cuboids.quaternions[index], cuboids.half_sizes[index]
        if exists is None and cuboids.exists is not None:
            exists = cuboids.exists[index]
    elif isinstance(cuboids, (tuple, list)) and len(cuboids) == 3:
        c, q, s = cuboids
    else:
        raise TypeError(
            "cuboids must be a Cuboids batch (with index) or a tuple (centers (M, 3), quaternions (M, 4), "
            f"half_sizes (M, 3)), got {type(cuboids).__name__}"
        )
    c, q, s = (as_float_tensor(_to_numpy(x), name) for x, name in ((c, "centers"), (q, "quaternions"),
                                                                    (s, "half_sizes")))
    for x, name in ((c, "centers"), (q, "quaternions"), (s, "half_sizes")):
        if x.dim() != 2:
            raise ValueError(f"{name} must describe ONE shape, shape (M, ...), got shape {tuple(x.shape)}")
    mask = None if exists is None else _to_numpy(exists)[None]
    c, q, s, mask = validate_cuboids(c[None], q[None], s[None], mask)
    corners = cuboid_corners(c, q, s, validate=False)[0].double().numpy()  # (M, 8, 3)
    keep = np.ones(c.shape[1], dtype=bool) if mask is None else mask[0].numpy()
    return corners, keep


def _one_shape_points(points, labels, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """(points (K, 3), labels (K,) int, -1 = unlabelled), an evenly spaced subset of K <= max_points."""
    p = as_float_tensor(_to_numpy(points), "points")
    check_shape(p, ("N", 3), "points (one shape)")
    check_finite(p, "points")
    n = p.shape[0]
    if labels is None:
        lab = np.full(n, -1, dtype=np.int64)
    else:
        lab = _to_numpy(labels)
        if lab.shape != (n,):
            raise ValueError(f"labels must have shape (N,) = ({n},) like the points, got {lab.shape}")
        if not np.issubdtype(lab.dtype, np.integer):
            raise ValueError(f"labels must hold integer cuboid indices, got dtype {lab.dtype}")
        lab = lab.astype(np.int64)
    if not isinstance(max_points, int) or max_points < 1:
        raise ValueError(f"max_points must be a positive integer, got {max_points!r}")
    keep = np.unique(np.linspace(0, n - 1, min(n, max_points)).round().astype(np.int64)) if n else np.zeros(0, int)
    return p.double().numpy()[keep], lab[keep]


def _unpack(item, k: int) -> tuple:
    """(points, labels, cuboids, exists, index) from a 3-, 4- or 5-tuple grid item."""
    if not isinstance(item, (tuple, list)) or not 3 <= len(item) <= 5:
        raise ValueError(f"item {k} must be a tuple (points, labels, cuboids[, exists[, index]])")
    return (*item, None, 0)[:5] if len(item) == 3 else (*item, 0)[:5]


def _groups(labels: np.ndarray) -> list[int]:
    """Distinct labels in increasing order (-1, the unlabelled group, first)."""
    return sorted(int(v) for v in np.unique(labels))


# ----------------------------------------------------------------------------------------------
# Plotly
# ----------------------------------------------------------------------------------------------


def _plotly_traces(points, labels, cuboids, exists, index, opacity, max_points, point_size, decimals, showlegend,
                   names=None):
    import plotly.graph_objects as go

    def name(m: int) -> str:  # "cuboid 3", or "cuboid 3: leg" when the cuboid's part is known
        part = names[m] if names is not None and 0 <= m < len(names) else None
        return f"cuboid {m}: {part}" if part else f"cuboid {m}"

    if not 0 <= opacity <= 1:
        raise ValueError(f"opacity must lie in [0, 1], got {opacity!r}")
    pts, lab = _one_shape_points(points, labels, max_points)
    corners, keep = _one_shape_cuboids(cuboids, exists, index)
    rnd = lambda x: np.round(x, decimals).astype(np.float32)  # noqa: E731 - compact figure JSON
    traces = []
    for m in _groups(lab):
        sel = lab == m
        color = UNLABELLED if m < 0 else cuboid_color(m)
        traces.append(go.Scatter3d(
            x=rnd(pts[sel, 0]), y=rnd(pts[sel, 1]), z=rnd(pts[sel, 2]), mode="markers",
            marker=dict(size=point_size, color=color), name="points" if m < 0 else name(m),
            legendgroup=f"cuboid {m}", showlegend=showlegend,
        ))
    tri = CUBOID_TRIANGLES.numpy()
    for m in np.nonzero(keep)[0]:
        color, v = cuboid_color(int(m)), rnd(corners[m])
        traces.append(go.Mesh3d(
            x=v[:, 0], y=v[:, 1], z=v[:, 2], i=tri[:, 0], j=tri[:, 1], k=tri[:, 2], color=color,
            opacity=opacity, flatshading=True, name=name(int(m)), legendgroup=f"cuboid {m}",
            showlegend=False, hoverinfo="name",
        ))
        edge = np.full((3 * len(_EDGES), 3), np.nan, dtype=np.float32)  # segments separated by gaps
        edge[0::3] = v[[a for a, _ in _EDGES]]
        edge[1::3] = v[[b for _, b in _EDGES]]
        traces.append(go.Scatter3d(
            x=edge[:, 0], y=edge[:, 1], z=edge[:, 2], mode="lines", line=dict(color=color, width=3),
            name=name(int(m)), legendgroup=f"cuboid {m}", showlegend=False, hoverinfo="skip",
        ))
    return traces


def _scene_layout() -> dict:
    """A 3D scene with equal axis scales, +y up and the shape's front (+z) towards the viewer."""
    axis = dict(showbackground=False, showticklabels=False, title="", showgrid=True, zeroline=False)
    return dict(
        aspectmode="data", xaxis=axis, yaxis=axis, zaxis=axis,
        camera=dict(up=dict(x=0, y=1, z=0), eye=dict(x=1.1, y=0.8, z=1.6)),
    )


def plot_cuboids_plotly(
    points,
    labels,
    cuboids,
    exists=None,
    index: int = 0,
    opacity: float = 0.25,
    max_points: int = 2000,
    point_size: float = 2.0,
    decimals: int = 4,
    title: str | None = None,
    width: int = 520,
    height: int = 460,
    names=None,
):
    """Interactive 3D figure of one shape: points coloured by cuboid and translucent cuboids.

    One legend entry per cuboid m toggles its points and its cuboid together.

    Args:
        points, labels, cuboids, exists, index: the shape (module docstring).
        opacity: of the cuboids' faces, in [0, 1]; edges are opaque.
        max_points: points drawn at most.
        point_size: marker size.
        decimals: coordinates are rounded to this many places (a smaller figure).
        title: optional title.
        width, height: in pixels.
        names: optional part name of every cuboid index (None where unknown); the legend then reads
            "cuboid m: NAME".

    Returns:
        A ``plotly.graph_objects.Figure``.
    """
    import plotly.graph_objects as go

    traces = _plotly_traces(points, labels, cuboids, exists, index, opacity, max_points, point_size, decimals,
                            showlegend=True, names=names)
    fig = go.Figure(traces)
    fig.update_layout(
        scene=_scene_layout(), width=width, height=height, margin=dict(l=0, r=0, t=30 if title else 0, b=0),
        title=dict(text=title, x=0.5, font=dict(size=14)) if title else None,
        legend=dict(itemsizing="constant", font=dict(size=10)), template="plotly_white",
    )
    return fig


def plot_cuboids_plotly_grid(
    items: Sequence,
    titles: Sequence[str] | None = None,
    cols: int = 3,
    opacity: float = 0.25,
    max_points: int = 1000,
    point_size: float = 2.0,
    decimals: int = 4,
    size: int = 320,
):
    """Several shapes side by side in one interactive figure (one 3D scene each, no legend).

    Args:
        items: ``(points, labels, cuboids[, exists[, index]])`` tuples, each as in :func:`plot_cuboids_plotly`.
        titles: optional, one per item.
        cols: panels per row.
        opacity, max_points, point_size, decimals: as for :func:`plot_cuboids_plotly`, per panel.
        size: width and height of one panel in pixels.

    Returns:
        A ``plotly.graph_objects.Figure``.
    """
    from plotly.subplots import make_subplots

    if not items:
        raise ValueError("items is empty; give at least one (points, labels, cuboids) tuple")
    if titles is not None and len(titles) != len(items):
        raise ValueError(f"titles has {len(titles)} entries for {len(items)} items")
    if not isinstance(cols, int) or cols < 1:
        raise ValueError(f"cols must be a positive integer, got {cols!r}")
    cols = min(cols, len(items))
    rows = -(-len(items) // cols)
    fig = make_subplots(rows=rows, cols=cols, specs=[[{"type": "scene"}] * cols] * rows,
                        subplot_titles=list(titles) if titles else None,
                        horizontal_spacing=0.01, vertical_spacing=0.04)
    for k, item in enumerate(items):
        points, labels, cuboids, exists, index = _unpack(item, k)
        for trace in _plotly_traces(points, labels, cuboids, exists, index, opacity, max_points, point_size,
                                    decimals, showlegend=False):
            fig.add_trace(trace, row=k // cols + 1, col=k % cols + 1)
    fig.update_scenes(**_scene_layout())
    fig.update_layout(width=size * cols, height=size * rows + 20, margin=dict(l=0, r=0, t=30, b=0),
                      showlegend=False, template="plotly_white")
    return fig


def _data_extent(traces) -> tuple[np.ndarray, np.ndarray]:
    """(lower corner (3,), upper corner (3,)) of every coordinate drawn by ``traces`` (NaN gaps ignored)."""
    coords = [np.stack([np.asarray(t.x, dtype=float), np.asarray(t.y, dtype=float), np.asarray(t.z, dtype=float)], 1)
              for t in traces if t.x is not None and len(t.x)]
    xyz = np.concatenate(coords) if coords else np.zeros((1, 3))
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    return (xyz.min(axis=0), xyz.max(axis=0)) if len(xyz) else (np.zeros(3), np.zeros(3))


def plot_cuboids_plotly_slider(
    items: Sequence,
    step_labels: Sequence[str] | None = None,
    title: str | None = None,
    active: int = 0,
    opacity: float = 0.25,
    max_points: int = 2000,
    point_size: float = 2.0,
    decimals: int = 4,
    width: int = 560,
    height: int = 540,
):
    """A sequence of shapes in ONE interactive scene, one at a time, chosen with a slider (Fig. 13).

    The slider restyles visibility only, so the camera stays where the user turned it, and the axes are
    one cube that encloses every item, so the shapes keep their scale and position from step to step.

    Args:
        items: ``(points, labels, cuboids[, exists[, index]])`` tuples as in :func:`plot_cuboids_plotly_grid`
            (points may be an empty (0, 3) array for decoded shapes).
        step_labels: the slider's label of every item (default "0", "1", ...).
        title: optional title.
        active: the item shown first.
        opacity, max_points, point_size, decimals, width, height: as for :func:`plot_cuboids_plotly`.

    Returns:
        A ``plotly.graph_objects.Figure``.
    """
    import plotly.graph_objects as go

    if not items:
        raise ValueError("items is empty; give at least one (points, labels, cuboids) tuple")
    if step_labels is not None and len(step_labels) != len(items):
        raise ValueError(f"step_labels has {len(step_labels)} entries for {len(items)} items")
    if isinstance(active, bool) or not isinstance(active, (int, np.integer)) or not 0 <= active < len(items):
        raise ValueError(f"active must be an item index in [0, {len(items)}), got {active!r}")
    labels = [str(k) for k in range(len(items))] if step_labels is None else [str(s) for s in step_labels]
    traces, owner = [], []
    for k, item in enumerate(items):
        points, point_labels, cuboids, exists, index = _unpack(item, k)
        for trace in _plotly_traces(points, point_labels, cuboids, exists, index, opacity, max_points, point_size,
                                    decimals, showlegend=False):
            trace.visible = k == active
            traces.append(trace)
            owner.append(k)
    lo, hi = _data_extent(traces)
    mid, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-6) * 1.05
    scene = _scene_layout()
    scene["aspectmode"] = "cube"
    for axis, name in enumerate(("xaxis", "yaxis", "zaxis")):
        scene[name] = dict(scene[name], range=[float(mid[axis] - half), float(mid[axis] + half)], autorange=False)
    owner = np.array(owner, dtype=np.int64)
    steps = [dict(method="restyle", label=label, args=[{"visible": (owner == k).tolist()}])
             for k, label in enumerate(labels)]
    fig = go.Figure(traces)
    fig.update_layout(
        scene=scene, width=width, height=height, showlegend=False, template="plotly_white",
        margin=dict(l=0, r=0, t=30 if title else 0, b=0),
        title=dict(text=title, x=0.5, font=dict(size=14)) if title else None,
        sliders=[dict(active=int(active), steps=steps, currentvalue=dict(prefix=""), pad=dict(t=10, b=10))],
    )
    return fig


# ----------------------------------------------------------------------------------------------
# Matplotlib
# ----------------------------------------------------------------------------------------------


def _mpl(v: np.ndarray) -> np.ndarray:
    """World (x, y, z) with +y up -> matplotlib (x, -z, y), so that y is vertical and +z faces the viewer."""
    return np.stack([v[..., 0], -v[..., 2], v[..., 1]], axis=-1)


def plot_cuboids_matplotlib(
    ax,
    points,
    labels,
    cuboids,
    exists=None,
    index: int = 0,
    alpha: float = 0.15,
    max_points: int = 2000,
    point_size: float = 2.0,
    title: str | None = None,
    view: tuple[float, float] = (20.0, -60.0),
):
    """Static version of :func:`plot_cuboids_plotly` on a matplotlib 3D axes (+y vertical, axes equal and hidden).

    Args:
        ax: a 3D axes, e.g. ``fig.add_subplot(projection="3d")``.
        points, labels, cuboids, exists, index: the shape (module docstring).
        alpha: opacity of the cuboids' faces, in [0, 1]; edges are opaque.
        max_points, point_size: as for :func:`plot_cuboids_plotly`.
        title: optional title.
        view: (elevation, azimuth) in degrees.

    Returns:
        ``ax``.
    """
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    if getattr(ax, "name", None) != "3d":
        raise TypeError("ax must be a matplotlib 3D axes, e.g. fig.add_subplot(projection='3d')")
    if not 0 <= alpha <= 1:
        raise ValueError(f"alpha must lie in [0, 1], got {alpha!r}")
    pts, lab = _one_shape_points(points, labels, max_points)
    corners, keep = _one_shape_cuboids(cuboids, exists, index)
    colors = np.array([UNLABELLED if m < 0 else cuboid_color(int(m)) for m in lab])
    p = _mpl(pts)
    ax.scatter(p[:, 0], p[:, 1], p[:, 2], c=colors, s=point_size, linewidths=0, depthshade=False)
    quads = np.array([[0, 1, 3, 2], [4, 5, 7, 6], [0, 1, 5, 4], [2, 3, 7, 6], [0, 2, 6, 4], [1, 3, 7, 5]])
    boxes = [_mpl(corners[m]) for m in np.nonzero(keep)[0]]
    for m, v in zip(np.nonzero(keep)[0], boxes):
        color = cuboid_color(int(m))
        ax.add_collection3d(Poly3DCollection(v[quads], facecolors=color, edgecolors=color, alpha=alpha,
                                             linewidths=0.8))
    extent = np.concatenate([p] + boxes) if boxes else p
    lo, hi = extent.min(axis=0), extent.max(axis=0)
    mid, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-9)
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=view[0], azim=view[1])
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=9)
    return ax


def plot_cuboids_matplotlib_grid(
    items: Sequence,
    titles: Sequence[str] | None = None,
    cols: int = 3,
    panel_size: float = 3.0,
    **kwargs,
):
    """A matplotlib figure with one 3D panel per shape.

    Args:
        items: as for :func:`plot_cuboids_plotly_grid`.
        titles: optional, one per item.
        cols: panels per row.
        panel_size: width and height of one panel in inches (3.0 at 100 dpi gives 300 pixels).
        **kwargs: passed to :func:`plot_cuboids_matplotlib`.

    Returns:
        A matplotlib ``Figure``.
    """
    import matplotlib.pyplot as plt

    if not items:
        raise ValueError("items is empty; give at least one (points, labels, cuboids) tuple")
    if titles is not None and len(titles) != len(items):
        raise ValueError(f"titles has {len(titles)} entries for {len(items)} items")
    if not isinstance(cols, int) or cols < 1:
        raise ValueError(f"cols must be a positive integer, got {cols!r}")
    cols = min(cols, len(items))
    rows = -(-len(items) // cols)
    fig = plt.figure(figsize=(panel_size * cols, panel_size * rows))
    for k, item in enumerate(items):
        points, labels, cuboids, exists, index = _unpack(item, k)
        ax = fig.add_subplot(rows, cols, k + 1, projection="3d", proj_type="ortho")
        plot_cuboids_matplotlib(ax, points, labels, cuboids, exists, index,
                                title=None if titles is None else titles[k], **kwargs)
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.93, wspace=0, hspace=0.08)
    return fig


# ----------------------------------------------------------------------------------------------
# Display: the interactive figure and its static twin in one output
# ----------------------------------------------------------------------------------------------


def figure_bundle(fig, static, dpi: int = 110) -> dict:
    """The MIME bundle of a plotly figure with a PNG of its static twin.

    Args:
        fig: a ``plotly.graph_objects.Figure``.
        static: a matplotlib ``Figure`` that draws the same content (for example from
            :func:`plot_cuboids_matplotlib_grid`); it is closed after rendering.
        dpi: resolution of the PNG, at least 100.

    Returns:
        A dict with the keys ``application/vnd.plotly.v1+json`` (what JupyterLab draws),
        ``image/png`` (base64, what viewers without JavaScript draw) and ``text/plain``.
    """
    import base64
    import io

    import matplotlib.pyplot as plt
    import plotly.graph_objects as go
    import plotly.io as pio
    from matplotlib.figure import Figure

    if not isinstance(fig, go.Figure):
        raise TypeError(f"fig must be a plotly Figure, got {type(fig).__name__}")
    if not isinstance(static, Figure):
        raise TypeError(f"static must be a matplotlib Figure, got {type(static).__name__}")
    if isinstance(dpi, bool) or not isinstance(dpi, int) or dpi < 100:
        raise ValueError(f"dpi must be an integer of at least 100, got {dpi!r}")
    buffer = io.BytesIO()
    static.savefig(buffer, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(static)
    bundle = dict(pio.renderers["plotly_mimetype"].to_mimebundle(fig.to_dict()))
    bundle["image/png"] = base64.b64encode(buffer.getvalue()).decode("ascii")
    bundle["text/plain"] = f"<plotly figure with a static twin, {len(fig.data)} traces>"
    return bundle


def show_figure(fig, static, dpi: int = 110) -> None:
    """Display a plotly figure and its static matplotlib twin as one notebook output.

    JupyterLab draws the plotly figure, GitHub and nbconvert HTML the PNG. Outside IPython nothing is shown.

    Args:
        fig, static, dpi: as for :func:`figure_bundle`.
    """
    bundle = figure_bundle(fig, static, dpi)
    try:
        from IPython.display import display
    except ImportError:  # pragma: no cover - IPython ships with jupyterlab
        return
    display(bundle, raw=True)


# ----------------------------------------------------------------------------------------------
# Lesson 04: the network's diagram (Fig. 3) and a training log
# ----------------------------------------------------------------------------------------------


def _traced_shapes(net, points: torch.Tensor) -> dict[str, tuple[int, ...]]:
    """Run ``net`` once in evaluation mode and record the shape of what each piece returns (forward hooks)."""
    shapes: dict[str, tuple[int, ...]] = {}
    pieces = {"edge1": net.embedding.edge_convs[0], "edge2": net.embedding.edge_convs[1],
              "code": net.abstraction.E_cb, "g_p": net.segmentation.point_proj,
              "g_c": net.segmentation.cuboid_proj}
    hooks = [m.register_forward_hook(lambda m, i, o, name=name: shapes.__setitem__(name, tuple(o.shape)))
             for name, m in pieces.items()]
    hooks.append(net.abstraction.E_cb.register_forward_hook(
        lambda m, i, o: shapes.__setitem__("onehot", tuple(i[0].shape))))
    was_training = net.training
    try:
        with torch.no_grad():
            out = net.eval()(points)
    finally:
        for h in hooks:
            h.remove()
        net.train(was_training)
    for name in ("point_features", "global_feature", "z", "cuboid_features", "half_sizes", "quaternions",
                 "centers", "exist_logits", "affinity"):
        shapes[name] = tuple(getattr(out, name).shape)
    shapes["input"] = tuple(points.shape)
    return shapes


def _diagram_box(ax, x, y, text, color, w, h, size):
    """A rounded box centred at (x, y) with its text; returns (x, y, w, h) for :func:`_diagram_arrow`."""
    from matplotlib.patches import FancyBboxPatch

    ax.add_patch(FancyBboxPatch((x - w / 2, y - h / 2), w, h, boxstyle="round,pad=0.05", fc=color, ec="0.3"))
    ax.text(x, y, text, ha="center", va="center", fontsize=size)
    return x, y, w, h


def _diagram_arrow(ax, a, b, label="", vertical=False):
    """An arrow from box a to box b, labelled beside (vertical) or above (horizontal) its middle."""
    (xa, ya, wa, ha), (xb, yb, wb, hb) = a, b
    if vertical:  # from the bottom of a to the top of b
        p, q = (xa, ya - ha / 2 - 0.05), (xb, yb + hb / 2 + 0.05)
    else:  # between the facing sides
        sign = 1 if xb > xa else -1
        p, q = (xa + sign * (wa / 2 + 0.05), ya), (xb - sign * (wb / 2 + 0.05), yb)
    ax.annotate("", xy=q, xytext=p, arrowprops=dict(arrowstyle="-|>", color="0.25", lw=1.2))
    mx, my = (p[0] + q[0]) / 2, (p[1] + q[1]) / 2
    if vertical:
        ax.text(mx + 0.12, my, label, ha="left", va="center", fontsize=8)
    else:
        ax.text(mx, my + 0.12, label, ha="center", va="bottom", fontsize=8)


def draw_network(net, points: torch.Tensor):
    """Draw the network as the paper's Fig. 3 does, with tensor shapes read from one forward pass.

    The shapes on the arrows are not typed by hand: forward hooks record what each piece returns. The batch,
    point and cuboid axes are written B, N and M, after checking their sizes; the other numbers are channels.

    Args:
        net: a :class:`~cuboidlib.model.CuboidAbstractionNet` (any :class:`~cuboidlib.model.ModelConfig`
            with two EdgeConv layers); its training mode is restored afterwards.
        points: (B, N, 3) point clouds to run through ``net``.

    Returns:
        ``(fig, shapes)``: the matplotlib ``Figure`` (one axes, axis off) and a dict from the name of each
        piece (``"input"``, ``"edge1"``, ``"edge2"``, ``"point_features"``, ``"global_feature"``, ``"z"``,
        ``"onehot"``, ``"code"``, ``"cuboid_features"``, ``"half_sizes"``, ``"quaternions"``, ``"centers"``,
        ``"exist_logits"``, ``"g_p"``, ``"g_c"``, ``"affinity"``) to the shape of its output.
    """
    import matplotlib.pyplot as plt

    s = _traced_shapes(net, points)
    sizes = {"B": points.shape[0], "N": points.shape[1], "M": net.config.num_cuboids}

    def dims(name, axes):  # dims("affinity", "BNM") -> "(B, N, M)", after checking those axes' sizes
        shape = s[name]
        if [sizes[a] for a in axes] != list(shape[: len(axes)]):
            raise AssertionError(f"{name} has shape {shape}, expected leading axes {axes} = {sizes}")
        return "(" + ", ".join(list(axes) + [str(d) for d in shape[len(axes):]]) + ")"

    fig, ax = plt.subplots(figsize=(14, 6.2))
    ax.set(xlim=(-0.2, 21.4), ylim=(-0.9, 8.0))
    ax.axis("off")
    enc, cub, seg = "#dbe9f6", "#fde3c8", "#d9f0d3"

    def box(x, y, text, color, w=2.2, h=1.1, size=9):
        return _diagram_box(ax, x, y, text, color, w, h, size)

    def arrow(a, b, label="", vertical=False):
        _diagram_arrow(ax, a, b, label, vertical)

    y1, y2, y3 = 7.0, 4.2, 1.4  # encoder, cuboid branch, segmentation branch
    inp = box(0.9, y1, "input points\n$x$", "white", w=1.6)
    e1 = box(3.7, y1, "EdgeConv 1\n(kNN in space)", enc, w=2.0)
    e2 = box(6.9, y1, "EdgeConv 2\n(kNN in features)", enc, w=2.0)
    fp = box(10.1, y1, "concatenate:\npoint features $f^p$", enc, w=2.1)
    fg = box(13.6, y1, "shared layer,\nmax over points:\nglobal feature $f^g$", enc, h=1.3)
    vae = box(17.3, y1, "VAE head (Eq. 1)\n$\\mu$, $\\log\\sigma^2$,\n$z = \\mu + \\sigma n$", enc, h=1.3)
    arrow(inp, e1, dims("input", "BN"))
    arrow(e1, e2, dims("edge1", "BN"))
    arrow(e2, fp, dims("edge2", "BN"))
    ax.annotate("", xy=(fp[0] - 0.5, y1 + 0.6), xytext=(e1[0], y1 + 0.6),
                arrowprops=dict(arrowstyle="-|>", color="0.25", lw=1.0, connectionstyle="arc3,rad=-0.2"))
    arrow(fp, fg, dims("point_features", "BN"))
    arrow(fg, vae, dims("global_feature", "B"))

    onehot = box(11.6, y2, "one-hot codes\n$v_1, \\dots, v_M$", cub, w=1.9)
    ecb = box(14.3, y2, "$E_{cb}$:\ncuboid codes", cub, w=1.7)
    ecf = box(17.3, y2, "$E_{cf}$: per-cuboid\nMLP on $[z;\\ E_{cb}(v_m)]$", cub, w=2.4)
    arrow(onehot, ecb, dims("onehot", "M"))
    arrow(ecb, ecf, dims("code", "M"))
    arrow(vae, ecf, "$z$ " + dims("z", "B"), vertical=True)
    heads = (("half sizes $s$", "half_sizes"), ("rotation $r$", "quaternions"), ("centre $t$", "centers"),
             ("existence $\\delta$", "exist_logits"))
    for i, (label, name) in enumerate(heads):  # D_cp: four heads on every cuboid feature
        y = y2 + 1.15 - 0.77 * i
        box(20.4, y, f"{label}\n{dims(name, 'BM')}", cub, w=1.7, h=0.62, size=8)
        ax.annotate("", xy=(20.4 - 0.9, y), xytext=(ecf[0] + ecf[2] / 2 + 0.05, y2),
                    arrowprops=dict(arrowstyle="-|>", color="0.25", lw=0.9))

    gp = box(10.1, y3, "point projection\n$g^p$", seg)
    aff = box(13.7, y3, "affinity (Eq. 2)\n$A = g^p \\cdot g^c$", seg)
    gc = box(17.3, y3, "cuboid projection\n$g^c$", seg)
    out = box(13.7, -0.35, "softmax over the cuboids (Eq. 3):\nallocation $W$ and segmentation", seg, w=3.6, h=0.9)
    arrow(fp, gp, "$f^p$", vertical=True)
    arrow(ecf, gc, "$f^c$ " + dims("cuboid_features", "BM"), vertical=True)
    arrow(gp, aff, dims("g_p", "BN"))
    arrow(gc, aff, dims("g_c", "BM"))
    arrow(aff, out, dims("affinity", "BNM"), vertical=True)
    for i, (text, color) in enumerate((("encoder $E_{pp}$ (Sec. 3.1)", enc), ("cuboid branch (Sec. 3.2)", cub),
                                       ("segmentation branch (Sec. 3.3)", seg))):
        box(2.6, 4.6 - 0.75 * i, text, color, w=4.2, h=0.55)
    ax.text(0.5, 1.3, "B = {B} shapes, N = {N} points, M = {M} cuboids:\nshapes read from a forward pass".format(**sizes),
            fontsize=9, va="center")
    return fig, s


#: Panels of :func:`plot_log`: column of log.csv -> (title, y-axis label, scale, log y-axis).
LOG_PANELS: dict[str, tuple[str, str, float, bool]] = {
    "total": ("total loss $L$", "loss", 1, True),
    "reconstruction": ("$L_{recons}$", "loss", 1, True),
    "compactness": (r"$L_{compact}$ (averaged)", "loss", 1, False),
    "existence": ("$L_{exist}$", "cross-entropy", 1, False),
    "kl": ("$L_{KL}$", "nats", 1, True),
    "n_existing": (r"cuboids with $\delta_m > 0.5$", "cuboids", 1, False),
    "saturated": ("saturated points", "% of the points", 100, False),
    "affinity_gap": ("median affinity gap", "logit difference", 1, False),
}


def _column(rows, key: str) -> np.ndarray:
    return np.array([float(r[key]) for r in rows])


def plot_log(train_rows: Sequence[dict], val_rows: Sequence[dict], smooth: int = 10):
    """The loss terms and diagnostics of a training log (``log.csv`` of :class:`cuboidlib.train.Trainer`).

    One panel per entry of :data:`LOG_PANELS` (2 x 4): the training rows per step, their running mean over
    ``smooth`` steps, and the validation rows. Integer quantities get integer ticks; one legend below the panels.

    Args:
        train_rows: the ``train`` rows of the log, dicts with ``step`` and every key of :data:`LOG_PANELS`
            (as ``csv.DictReader`` returns them: strings are fine).
        val_rows: the ``val`` rows, with the same keys.
        smooth: width of the running mean, in steps (at least 1).

    Returns:
        A matplotlib ``Figure`` with 8 axes, each titled and with both axes labelled.
    """
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    if not isinstance(smooth, int) or smooth < 1:
        raise ValueError(f"smooth must be a positive integer, got {smooth!r}")
    steps, val_steps = _column(train_rows, "step"), _column(val_rows, "step")
    fig, axes = plt.subplots(2, 4, figsize=(13, 5.8))
    for ax, (key, (title, ylabel, scale, log_axis)) in zip(axes.flat, LOG_PANELS.items()):
        v = scale * _column(train_rows, key)
        ax.plot(steps, v, color=PALETTE[0], alpha=0.3, lw=0.8, label="train (per step)")
        if len(v) >= smooth:
            running = np.convolve(v, np.ones(smooth) / smooth, mode="valid")
            ax.plot(steps[smooth - 1:], running, color=PALETTE[0], label=f"train (mean of {smooth} steps)")
        ax.plot(val_steps, scale * _column(val_rows, key), "o-", color=PALETTE[1], ms=4, label="validation")
        ax.set(title=title, xlabel="training step", ylabel=ylabel, yscale="log" if log_axis else "linear")
        if key == "n_existing":
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="lower center", ncol=3, fontsize=8)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig
