"""Measures of the 2D toy's fits (lesson 01): which rectangles are used, how thin, how well they recover the shape.

A fit of :func:`cuboidlib.toy2d.fit_rectangles` is degenerate when its used rectangles are thin plates along the
boundary, and it recovers the shape when their union covers the true rectangles (:func:`union_iou`) with the right
orientation (:func:`orientation_error`). :func:`draw_abstraction` draws one fit. Conventions are those of
:mod:`cuboidlib.toy2d`.
"""

from __future__ import annotations

import math

import torch

from ._checks import as_float_tensor, check_positive, check_shape
from .toy2d import _inside, _validate, rectangle_corners

__all__ = [
    "used_rectangles",
    "aspect_ratios",
    "thin_fraction",
    "union_iou",
    "orientation_error",
    "draw_abstraction",
]


def used_rectangles(portions: torch.Tensor, eps_ext: float = 0.05) -> torch.Tensor:
    """Rectangles that get more than ``eps_ext`` of the points: the existence target delta_m^gt of Sec. 3.4.3.

    Args:
        portions: (B, K) allocation portions w_k.
        eps_ext: threshold on w_k.

    Returns:
        (B, K) bool.
    """
    portions = as_float_tensor(portions, "portions")
    check_shape(portions, ("B", "K"), "portions")
    return portions > eps_ext


def aspect_ratios(half_sizes: torch.Tensor) -> torch.Tensor:
    """Long side over short side of each rectangle.

    Args:
        half_sizes: (B, K, 2), > 0.

    Returns:
        (B, K) ratios, >= 1.
    """
    half_sizes = as_float_tensor(half_sizes, "half_sizes")
    check_shape(half_sizes, ("B", "K", 2), "half_sizes")
    check_positive(half_sizes, "half_sizes")
    return half_sizes.amax(dim=-1) / half_sizes.amin(dim=-1)


def thin_fraction(half_sizes: torch.Tensor, used: torch.Tensor, min_thickness) -> torch.Tensor:
    """Fraction of the used rectangles whose short side 2 * min(half_sizes) is below ``min_thickness``.

    Args:
        half_sizes: (B, K, 2).
        used: (B, K) bool.
        min_thickness: a number, or (B,) one threshold per shape (e.g. a fraction of its thinnest part).

    Returns:
        (B,) fractions; 0 for a shape with no used rectangle.
    """
    half_sizes = as_float_tensor(half_sizes, "half_sizes")
    check_shape(half_sizes, ("B", "K", 2), "half_sizes")
    used = torch.as_tensor(used, dtype=torch.bool, device=half_sizes.device)
    check_shape(used, tuple(half_sizes.shape[:2]), "used")
    limit = as_float_tensor(min_thickness, "min_thickness", dtype=half_sizes.dtype, device=half_sizes.device)
    if limit.dim() == 1:
        check_shape(limit, (half_sizes.shape[0],), "min_thickness")
        limit = limit[:, None]
    elif limit.dim() != 0:
        raise ValueError(f"min_thickness must be a number or have shape (B,), got shape {tuple(limit.shape)}")
    thin = (2 * half_sizes.amin(dim=-1) < limit) & used
    return thin.sum(dim=-1).to(half_sizes.dtype) / used.sum(dim=-1).clamp_min(1).to(half_sizes.dtype)


def union_iou(
    rects_a: tuple,
    rects_b: tuple,
    used_a: torch.Tensor | None = None,
    used_b: torch.Tensor | None = None,
    resolution: int = 200,
    extent: float = 1.5,
) -> torch.Tensor:
    """Area IoU of the union of rectangles A with the union of rectangles B, on a pixel grid.

    An area measure sees what boundary distances cannot: thin rectangles hugging the edges cover
    almost nothing.

    Args:
        rects_a: (centers (B, K_a, 2), angles (B, K_a), half_sizes (B, K_a, 2)).
        rects_b: (centers (B, K_b, 2), angles (B, K_b), half_sizes (B, K_b, 2)), the same B.
        used_a: optional (B, K_a) bool mask of the rectangles of A to include.
        used_b: optional (B, K_b) bool mask of the rectangles of B to include.
        resolution: grid cells per side.
        extent: the grid covers [-extent, extent]^2 (the presets lie in [-1, 1]^2).

    Returns:
        (B,) IoU values.
    """
    ca, aa, ha, _, _, sa = _validate(*rects_a)
    cb, ab, hb, _, _, sb = _validate(*rects_b)
    if sa["B"] != sb["B"]:
        raise ValueError(f"rects_a and rects_b must have the same batch size, got {sa['B']} and {sb['B']}")
    B = sa["B"]
    axis = (torch.arange(resolution, dtype=ca.dtype, device=ca.device) + 0.5) / resolution * 2 * extent - extent
    gy, gx = torch.meshgrid(axis, axis, indexing="ij")
    grid = torch.stack([gx, gy], dim=-1).reshape(1, -1, 2).expand(B, -1, 2)  # (B, G, 2), G = resolution^2

    def occupancy(c, a, h, used):
        inside = _inside(grid, c, a, h)  # (B, G, K)
        if used is not None:
            inside = inside & torch.as_tensor(used, dtype=torch.bool, device=c.device)[:, None, :]
        return inside.any(dim=-1)

    oa, ob = occupancy(ca, aa, ha, used_a), occupancy(cb, ab, hb, used_b)
    union = (oa | ob).sum(dim=-1)
    return (oa & ob).sum(dim=-1).to(ca.dtype) / union.clamp_min(1).to(ca.dtype)


def orientation_error(angles: torch.Tensor, used: torch.Tensor, reference: float = 0.0) -> torch.Tensor:
    """Mean angle between the used rectangles and the reference axes, modulo a quarter turn.

    Args:
        angles: (B, K) in radians.
        used: (B, K) bool.
        reference: the reference axes' angle in radians.

    Returns:
        (B,) mean errors in [0, pi/4] radians; 0 for a shape with no used rectangle.
    """
    angles = as_float_tensor(angles, "angles")
    check_shape(angles, ("B", "K"), "angles")
    used = torch.as_tensor(used, dtype=torch.bool, device=angles.device)
    check_shape(used, tuple(angles.shape), "used")
    quarter = math.pi / 2
    r = torch.remainder(angles - reference, quarter)
    err = torch.minimum(r, quarter - r) * used
    return err.sum(dim=-1) / used.sum(dim=-1).clamp_min(1).to(angles.dtype)


def draw_abstraction(
    ax,
    points: torch.Tensor | None = None,
    normals: torch.Tensor | None = None,
    rectangles: tuple | None = None,
    used: torch.Tensor | None = None,
    labels: torch.Tensor | None = None,
    normal_length: float = 0.12,
    title: str | None = None,
    show_unused: bool = True,
) -> None:
    """Draw ONE shape on a matplotlib Axes: points, their normals as arrows, rectangles as outlines.

    Args:
        ax: a matplotlib Axes.
        points: optional (N, 2).
        normals: optional (N, 2), drawn at the points.
        rectangles: optional (centers (K, 2), angles (K,), half_sizes (K, 2)).
        used: optional (K,) bool; unused rectangles are drawn dotted and grey.
        labels: optional (N,) integers that colour the points.
        normal_length: arrow length.
        title: optional title.
        show_unused: draw the unused rectangles (False: only the used ones, in their own colours).
    """
    import matplotlib.pyplot as plt  # imported here so that cuboidlib.toy2d does not need a display

    if points is not None:
        p = as_float_tensor(points, "points").detach().cpu()
        check_shape(p, ("N", 2), "points")
        colors = None if labels is None else [plt.cm.tab10(int(i) % 10) for i in labels]
        ax.scatter(p[:, 0], p[:, 1], s=5, c=colors if colors is not None else "k", zorder=3)
        if normals is not None:
            nrm = as_float_tensor(normals, "normals").detach().cpu()
            check_shape(nrm, (p.shape[0], 2), "normals")
            ax.quiver(
                p[:, 0], p[:, 1], nrm[:, 0] * normal_length, nrm[:, 1] * normal_length,
                angles="xy", scale_units="xy", scale=1, width=0.003, color="tab:gray", zorder=2,
            )
    if rectangles is not None:
        names = ("centers", "angles", "half_sizes")
        c, a, h = (as_float_tensor(t, name).detach().cpu() for t, name in zip(rectangles, names))
        corners = rectangle_corners(c[None], a[None], h[None])[0]  # (K, 4, 2)
        mask = torch.ones(c.shape[0], dtype=torch.bool) if used is None else torch.as_tensor(used).cpu()
        for k in range(corners.shape[0]):
            loop = torch.cat([corners[k], corners[k, :1]])
            if mask[k]:
                ax.plot(loop[:, 0], loop[:, 1], "-", color=plt.cm.tab10(k % 10), lw=1.8, zorder=4)
            elif show_unused:
                ax.plot(loop[:, 0], loop[:, 1], ":", color="0.6", lw=1.0, zorder=1)
    ax.set_aspect("equal")
    if title:
        ax.set_title(title, fontsize=9)
