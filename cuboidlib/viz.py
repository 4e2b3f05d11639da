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
