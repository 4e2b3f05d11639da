"""A 2D toy of cuboid abstraction: oriented rectangles fitted to boundary points (lesson 01).

One file, because the toy's geometry, losses and fit belong together; how a fit is measured (used rectangles,
thin ones, IoU with the true shape) and drawn is :mod:`cuboidlib.toy2d_measures`.

It reproduces the ambiguity of the paper's Fig. 2 and the degenerate solutions of Fig. 9, and shows
how the normal-aware distance (Eq. (5), Sec. 3.4.1), the soft allocation (Eq. (3)-(4)) and the
compactness loss (Eq. (6)) avoid them. Conventions mirror the 3D ones with one dimension less:
rectangles are ``centers`` (B, K, 2), ``angles`` (B, K) in radians (counter-clockwise) and
``half_sizes`` (B, K, 2), with ``p = center + R(angle) @ p_local``; points and unit outward normals
are (B, N, 2); distances and the allocation W (a softmax over rectangles) are (B, N, K). Edges are
numbered by their local outward normal: 0 = +x, 1 = +y, 2 = -x, 3 = -y (:data:`EDGE_NORMALS`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from ._checks import (
    as_float_tensor,
    check_finite,
    check_positive,
    check_same_leading,
    check_shape,
    check_unit_vectors,
)
from .losses import allocation_portions, compactness_loss

__all__ = [
    "EDGE_NORMALS",
    "Rectangles",
    "rotation_2d",
    "rectangle_corners",
    "sample_rectangle_boundary",
    "sample_union_boundary",
    "boxes_to_rectangles",
    "inside_rectangles",
    "rectangle_shape",
    "l_shape",
    "t_shape",
    "u_shape",
    "stack_rectangles",
    "nearest_edge_distance",
    "best_matching_edge",
    "normal_aware_distance",
    "FitResult",
    "fit_rectangles",
]

#: Outward normals of the four edges in the rectangle's local frame, shape (4, 2).
EDGE_NORMALS = torch.tensor([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])


class Rectangles(NamedTuple):
    """A batch of K oriented rectangles; a tuple, so ``nearest_edge_distance(points, *rects)`` works.

    Args:
        centers: (B, K, 2).
        angles: (B, K) counter-clockwise rotations in radians.
        half_sizes: (B, K, 2) half extents along the local axes.
    """

    centers: torch.Tensor
    angles: torch.Tensor
    half_sizes: torch.Tensor


# --------------------------------------------------------------------------------------------------
# Validation helpers (cheap; skipped with validate=False in the fitting loop)


def _validate(centers, angles, half_sizes, points=None, normals=None, allow_zero: bool = True) -> tuple:
    """Convert and check rectangles (and optionally points (B, N, 2) and unit normals (B, N, 2)).

    Everything is converted to the dtype and device of ``centers``. Returns (centers, angles,
    half_sizes, points, normals, sizes) where sizes maps "B", "K" (and "N") to their values.
    """
    centers = as_float_tensor(centers, "centers")
    like = {"dtype": centers.dtype, "device": centers.device}
    angles = as_float_tensor(angles, "angles", **like)
    half_sizes = as_float_tensor(half_sizes, "half_sizes", **like)
    named = {
        "centers": check_shape(centers, ("B", "K", 2), "centers"),
        "angles": check_shape(angles, ("B", "K"), "angles"),
        "half_sizes": check_shape(half_sizes, ("B", "K", 2), "half_sizes"),
    }
    if points is not None:
        points = as_float_tensor(points, "points", **like)
        named["points"] = check_shape(points, ("B", "N", 2), "points")
    if normals is not None:
        normals = as_float_tensor(normals, "normals", **like)
        named["normals"] = check_shape(normals, ("B", "N", 2), "normals")
    sizes: dict = {}
    check_same_leading(named, sizes, "rectangles, points and normals")
    if sizes["K"] == 0:
        raise ValueError("rectangles: K = 0; at least one rectangle is needed")
    if sizes.get("N") == 0:
        raise ValueError("points is empty (N = 0); at least one point is needed")
    for t, name in ((centers, "centers"), (angles, "angles"), (half_sizes, "half_sizes"), (points, "points")):
        if t is not None:
            check_finite(t, name)
    check_positive(half_sizes, "half_sizes", allow_zero=allow_zero)
    if normals is not None:
        check_finite(normals, "normals")
        check_unit_vectors(normals, "normals")
    return centers, angles, half_sizes, points, normals, sizes


# --------------------------------------------------------------------------------------------------
# Geometry


def rotation_2d(angles: torch.Tensor) -> torch.Tensor:
    """Rotation matrices R(angle) = [[cos, -sin], [sin, cos]].

    Args:
        angles: (...) in radians.

    Returns:
        (..., 2, 2); the columns are the rectangle's local x and y axes in world coordinates.
    """
    angles = as_float_tensor(angles, "angles")
    c, s = torch.cos(angles), torch.sin(angles)
    return torch.stack([torch.stack([c, -s], dim=-1), torch.stack([s, c], dim=-1)], dim=-2)


def rectangle_corners(centers: torch.Tensor, angles: torch.Tensor, half_sizes: torch.Tensor) -> torch.Tensor:
    """The four corners of each rectangle, counter-clockwise.

    Args:
        centers: (B, K, 2); angles: (B, K); half_sizes: (B, K, 2), >= 0.

    Returns:
        (B, K, 4, 2); corner e is where edge e starts: local (+hx, -hy), (+hx, +hy), (-hx, +hy), (-hx, -hy).
    """
    centers, angles, half_sizes, _, _, _ = _validate(centers, angles, half_sizes)
    signs = torch.tensor(
        [[1.0, -1.0], [1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0]], dtype=centers.dtype, device=centers.device
    )
    local = signs * half_sizes[:, :, None, :]  # (B, K, 4, 2)
    return centers[:, :, None, :] + torch.einsum("bkij,bkcj->bkci", rotation_2d(angles), local)


def _local_xy(points: torch.Tensor, centers: torch.Tensor, angles: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World points (B, N, 2) -> their coordinates x, y (B, N, K) in each rectangle's frame, R^T (p - t)."""
    dx = points[:, :, None, 0] - centers[:, None, :, 0]
    dy = points[:, :, None, 1] - centers[:, None, :, 1]
    c, s = torch.cos(angles)[:, None, :], torch.sin(angles)[:, None, :]
    return c * dx + s * dy, c * dy - s * dx


def _local_dir(vectors: torch.Tensor, angles: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World directions (B, N, 2) -> their components x, y (B, N, K) in each rectangle's frame, R^T v."""
    c, s = torch.cos(angles)[:, None, :], torch.sin(angles)[:, None, :]
    vx, vy = vectors[:, :, None, 0], vectors[:, :, None, 1]
    return c * vx + s * vy, c * vy - s * vx


def _boundary_at(half_sizes: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Local point and outward normal at arc length u in [0, perimeter) along the boundary.

    half_sizes (..., 2), u (...). The walk starts at corner 0 and goes counter-clockwise.
    """
    hx, hy = half_sizes[..., 0], half_sizes[..., 1]
    ends = torch.stack([2 * hy, 2 * hy + 2 * hx, 4 * hy + 2 * hx], dim=-1)  # where edges 0, 1, 2 end
    edge = (u[..., None] >= ends).sum(dim=-1)  # (...,) in 0..3
    starts = torch.cat([torch.zeros_like(ends[..., :1]), ends], dim=-1)
    t = u - starts.gather(-1, edge[..., None]).squeeze(-1)
    corner_x = torch.stack([hx, hx, -hx, -hx], dim=-1).gather(-1, edge[..., None]).squeeze(-1)
    corner_y = torch.stack([-hy, hy, hy, -hy], dim=-1).gather(-1, edge[..., None]).squeeze(-1)
    normals = EDGE_NORMALS.to(device=u.device, dtype=u.dtype)[edge]  # (..., 2)
    # walking direction = outward normal rotated by +90 degrees: (-n_y, n_x)
    x = corner_x - normals[..., 1] * t
    y = corner_y + normals[..., 0] * t
    return torch.stack([x, y], dim=-1), normals


def _to_world(local: torch.Tensor, centers: torch.Tensor, angles: torch.Tensor) -> torch.Tensor:
    """Local coordinates (..., 2) with matching centers (..., 2) and angles (...) -> world (..., 2)."""
    c, s = torch.cos(angles), torch.sin(angles)
    x, y = local[..., 0], local[..., 1]
    return torch.stack([c * x - s * y, s * x + c * y], dim=-1) + centers


def sample_rectangle_boundary(
    centers: torch.Tensor,
    angles: torch.Tensor,
    half_sizes: torch.Tensor,
    n: int,
    generator: torch.Generator | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Sample n points uniformly by length on the boundary of each rectangle, with outward normals.

    Args:
        centers: (B, K, 2); angles: (B, K); half_sizes: (B, K, 2), > 0.
        n: points per rectangle.
        generator: source of randomness.

    Returns:
        ``(points, normals)``, each (B, K, n, 2).
    """
    centers, angles, half_sizes, _, _, sizes = _validate(centers, angles, half_sizes, allow_zero=False)
    if not isinstance(n, int) or n < 1:
        raise ValueError(f"n must be a positive integer (points per rectangle), got {n!r}")
    B, K = sizes["B"], sizes["K"]
    perimeter = 4 * half_sizes.sum(dim=-1)  # (B, K)
    u = torch.rand(B, K, n, generator=generator, dtype=centers.dtype, device=centers.device) * perimeter[..., None]
    local, local_normals = _boundary_at(half_sizes[:, :, None, :].expand(B, K, n, 2), u)
    points = _to_world(local, centers[:, :, None, :], angles[:, :, None])
    normals = _to_world(local_normals, torch.zeros_like(centers[:, :, None, :]), angles[:, :, None])
    return points, normals


def _inside(
    points: torch.Tensor, centers: torch.Tensor, angles: torch.Tensor, half_sizes: torch.Tensor
) -> torch.Tensor:
    x, y = _local_xy(points, centers, angles)
    return (x.abs() <= half_sizes[:, None, :, 0]) & (y.abs() <= half_sizes[:, None, :, 1])


def inside_rectangles(
    points: torch.Tensor, centers: torch.Tensor, angles: torch.Tensor, half_sizes: torch.Tensor
) -> torch.Tensor:
    """Closed point-in-rectangle test (points on the boundary are inside).

    Args:
        points: (B, N, 2).
        centers: (B, K, 2); angles: (B, K); half_sizes: (B, K, 2), >= 0.

    Returns:
        (B, N, K) bool.
    """
    centers, angles, half_sizes, points, _, _ = _validate(centers, angles, half_sizes, points)
    return _inside(points, centers, angles, half_sizes)


def sample_union_boundary(
    centers: torch.Tensor,
    angles: torch.Tensor,
    half_sizes: torch.Tensor,
    n: int,
    generator: torch.Generator | None = None,
    step: float = 1e-4,
    max_rounds: int = 100,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Sample n points uniformly by length on the OUTER boundary of the union of K rectangles.

    Candidates on all edges are kept when a point just outside them, p + step * diameter * n, lies in
    no other rectangle; an edge piece shared by two rectangles is kept once, for the first.

    Args:
        centers: (B, K, 2); angles: (B, K); half_sizes: (B, K, 2), > 0.
        n: points per shape.
        generator: source of randomness.
        step: the probe's offset, as a fraction of the largest rectangle diagonal, in (0, 0.01).
        max_rounds: rounds of rejection sampling before giving up.

    Returns:
        ``(points, normals, labels)``: (B, n, 2) points, (B, n, 2) unit outward normals and (B, n)
        int64 indices of the rectangle whose edge each point lies on.

    Raises:
        ValueError: when ``max_rounds`` rounds do not yield n points (a degenerate union).
    """
    centers, angles, half_sizes, _, _, sizes = _validate(centers, angles, half_sizes, allow_zero=False)
    if not isinstance(n, int) or n < 1:
        raise ValueError(f"n must be a positive integer (number of points), got {n!r}")
    if not 0 < step < 0.01:
        raise ValueError(f"step must be in (0, 0.01) (a small fraction of the shape size), got {step}")
    B, K = sizes["B"], sizes["K"]
    dtype, device = centers.dtype, centers.device
    perimeter = 4 * half_sizes.sum(dim=-1)  # (B, K)
    cumulative = perimeter.cumsum(dim=-1)  # (B, K)
    delta = step * 2 * half_sizes.norm(dim=-1).amax(dim=-1)  # (B,)
    earlier = torch.ones(K, K, dtype=torch.bool, device=device).tril(-1)  # earlier[k, j]: j < k
    other = ~torch.eye(K, dtype=torch.bool, device=device)
    kept: list[list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]] = [[] for _ in range(B)]
    counts = [0] * B
    m = 2 * n
    for _ in range(max_rounds):
        u = torch.rand(B, m, generator=generator, dtype=dtype, device=device) * cumulative[:, -1:]
        label = torch.searchsorted(cumulative.contiguous(), u, right=True).clamp_max(K - 1)  # (B, m)
        u_local = u - (cumulative - perimeter).gather(1, label)
        h = half_sizes.gather(1, label[..., None].expand(B, m, 2))
        local, local_normals = _boundary_at(h, u_local)
        a = angles.gather(1, label)
        points = _to_world(local, centers.gather(1, label[..., None].expand(B, m, 2)), a)
        normals = _to_world(local_normals, torch.zeros_like(points), a)
        outside = points + delta[:, None, None] * normals
        inner = points - delta[:, None, None] * normals
        covered = (_inside(outside, centers, angles, half_sizes) & other[label]).any(dim=-1)
        duplicate = (_inside(inner, centers, angles, half_sizes) & earlier[label]).any(dim=-1)
        keep = ~(covered | duplicate)  # (B, m)
        for b in range(B):
            if counts[b] < n:
                sel = keep[b]
                kept[b].append((points[b, sel], normals[b, sel], label[b, sel]))
                counts[b] += int(sel.sum())
        if min(counts) >= n:
            break
    else:
        raise ValueError(
            f"sample_union_boundary: could not collect n = {n} boundary points in {max_rounds} rounds "
            f"(kept {min(counts)}); is the union boundary degenerate?"
        )
    out = [tuple(torch.cat([c[i] for c in kept[b]])[:n] for i in range(3)) for b in range(B)]
    return tuple(torch.stack([o[i] for o in out]) for i in range(3))  # type: ignore[return-value]


def boxes_to_rectangles(boxes: list[tuple[float, float, float, float]], dtype: torch.dtype | None = None) -> Rectangles:
    """Axis-aligned rectangles from boxes.

    Args:
        boxes: K boxes ``(xmin, xmax, ymin, ymax)``, xmin < xmax, ymin < ymax.
        dtype: float dtype; None: torch's default.

    Returns:
        :class:`Rectangles` with B = 1: centers (1, K, 2), angles (1, K) zeros, half_sizes (1, K, 2).
    """
    t = as_float_tensor(boxes, "boxes", dtype=dtype)
    if t.dim() != 2 or t.shape[1] != 4 or t.shape[0] == 0:
        raise ValueError(f"boxes must be a non-empty list of (xmin, xmax, ymin, ymax), got shape {tuple(t.shape)}")
    if not bool((t[:, 1] > t[:, 0]).all() and (t[:, 3] > t[:, 2]).all()):
        raise ValueError("boxes must have xmin < xmax and ymin < ymax")
    centers = torch.stack([(t[:, 0] + t[:, 1]) / 2, (t[:, 2] + t[:, 3]) / 2], dim=-1)[None]
    half_sizes = torch.stack([(t[:, 1] - t[:, 0]) / 2, (t[:, 3] - t[:, 2]) / 2], dim=-1)[None]
    return Rectangles(centers, torch.zeros(1, len(boxes), dtype=t.dtype), half_sizes)


def rectangle_shape(dtype: torch.dtype | None = None) -> Rectangles:
    """One part, the paper's Fig. 2 example: the rectangle [-1, 1] x [-0.6, 0.6].

    Args:
        dtype: float dtype; None: torch's default.

    Returns:
        :class:`Rectangles` with B = 1, K = 1.
    """
    return boxes_to_rectangles([(-1.0, 1.0, -0.6, 0.6)], dtype)


def l_shape(dtype: torch.dtype | None = None) -> Rectangles:
    """An L in [-1, 1]^2 of two parts 1 thick: a 1 x 2 upright and a 1 x 1 foot to its right.

    Args:
        dtype: float dtype; None: torch's default.

    Returns:
        :class:`Rectangles` with B = 1, K = 2.
    """
    return boxes_to_rectangles([(-1.0, 0.0, -1.0, 1.0), (0.0, 1.0, -1.0, 0.0)], dtype)


def t_shape(dtype: torch.dtype | None = None) -> Rectangles:
    """A T in [-1, 1]^2 of two parts 0.8 thick: a 2 x 0.8 top bar and a 0.8 x 1.2 stem.

    Args:
        dtype: float dtype; None: torch's default.

    Returns:
        :class:`Rectangles` with B = 1, K = 2.
    """
    return boxes_to_rectangles([(-1.0, 1.0, 0.2, 1.0), (-0.4, 0.4, -1.0, 0.2)], dtype)


def u_shape(dtype: torch.dtype | None = None) -> Rectangles:
    """A U in [-1, 1]^2 of three parts: two 0.6 x 2 uprights and a 0.8 x 0.7 base between them.

    Args:
        dtype: float dtype; None: torch's default.

    Returns:
        :class:`Rectangles` with B = 1, K = 3.
    """
    return boxes_to_rectangles([(-1.0, -0.4, -1.0, 1.0), (0.4, 1.0, -1.0, 1.0), (-0.4, 0.4, -1.0, -0.3)], dtype)


def stack_rectangles(shapes: list[tuple]) -> tuple[Rectangles, torch.Tensor]:
    """Stack shapes with different numbers of parts into one batch, padded with zero-size rectangles.

    Args:
        shapes: S tuples (centers (1, K_i, 2), angles (1, K_i), half_sizes (1, K_i, 2)), e.g. the presets.

    Returns:
        ``(rectangles, present)``: :class:`Rectangles` of S shapes and K_max = max K_i rectangles, and
        an (S, K_max) bool mask of the real ones (pass it as ``used`` to :func:`cuboidlib.toy2d_measures.union_iou`).
    """
    if len(shapes) == 0:
        raise ValueError("shapes is empty; at least one shape is needed")
    checked = [_validate(*shape) for shape in shapes]
    for i, c in enumerate(checked):
        if c[5]["B"] != 1:
            raise ValueError(f"shapes[{i}] must hold one shape (B = 1), got B = {c[5]['B']}")
    k_max = max(c[5]["K"] for c in checked)
    out = []
    for j, pad_shape in enumerate(((2,), (), (2,))):
        parts = []
        for c in checked:
            t = c[j]
            pad = torch.zeros(1, k_max - t.shape[1], *pad_shape, dtype=t.dtype, device=t.device)
            parts.append(torch.cat([t, pad], dim=1))
        out.append(torch.cat(parts))
    present = torch.stack([torch.arange(k_max, device=out[0].device) < c[5]["K"] for c in checked])
    return Rectangles(*out), present


# --------------------------------------------------------------------------------------------------
# Point-to-rectangle distances (the 2D version of d(p, C) in Sec. 3.4.1)


def nearest_edge_distance(
    points: torch.Tensor,
    centers: torch.Tensor,
    angles: torch.Tensor,
    half_sizes: torch.Tensor,
    validate: bool = True,
) -> torch.Tensor:
    """Squared distance from each point to the NEAREST edge of each rectangle, ignoring normals.

    The "closest plane" distance the paper argues against (Sec. 3.4.1, Fig. 9): zero for a point on
    any edge, whichever side the shape is on.

    Args:
        points: (B, N, 2).
        centers: (B, K, 2); angles: (B, K); half_sizes: (B, K, 2), >= 0.
        validate: check the inputs; False expects tensors of one dtype and device.

    Returns:
        (B, N, K) squared distances.
    """
    if validate:
        centers, angles, half_sizes, points, _, _ = _validate(centers, angles, half_sizes, points)
    x, y = _local_xy(points, centers, angles)
    qx = x.abs() - half_sizes[:, None, :, 0]
    qy = y.abs() - half_sizes[:, None, :, 1]
    # outside only the positive parts count; inside (both q < 0) only the larger q does:
    # relu(q_x)^2 + relu(q_y)^2 + relu(-max(q_x, q_y))^2, each (B, N, K)
    q_max = torch.where(qx > qy, qx, qy)
    return torch.relu(qx).square() + torch.relu(qy).square() + torch.relu(-q_max).square()


def _matching_edge(nx: torch.Tensor, ny: torch.Tensor) -> torch.Tensor:
    """argmax over edges of the cosine (nx, ny, -nx, -ny) with the local normal, first edge on ties."""
    m = torch.maximum(nx.abs(), ny.abs())
    three = torch.full_like(nx, 3, dtype=torch.long)
    return torch.where(nx == m, 0, torch.where(ny == m, 1, torch.where(-nx == m, 2, three)))


def best_matching_edge(normals: torch.Tensor, angles: torch.Tensor) -> torch.Tensor:
    """The edge of each rectangle whose outward normal is most similar to the point's normal (Sec. 3.4.1).

    Args:
        normals: (B, N, 2) unit normals.
        angles: (B, K).

    Returns:
        (B, N, K) int64 edge indices (:data:`EDGE_NORMALS` order; the first on ties), without gradient.
    """
    normals = as_float_tensor(normals, "normals")
    angles = as_float_tensor(angles, "angles", dtype=normals.dtype, device=normals.device)
    sizes: dict = {}
    check_same_leading(
        {
            "normals": check_shape(normals, ("B", "N", 2), "normals"),
            "angles": check_shape(angles, ("B", "K"), "angles"),
        },
        sizes,
        "normals and angles",
    )
    check_finite(normals, "normals")
    check_unit_vectors(normals, "normals")
    check_finite(angles, "angles")
    return _matching_edge(*_local_dir(normals.detach(), angles.detach()))


def normal_aware_distance(
    points: torch.Tensor,
    normals: torch.Tensor,
    centers: torch.Tensor,
    angles: torch.Tensor,
    half_sizes: torch.Tensor,
    sigma_s: float = 0.05,
    offsets: torch.Tensor | None = None,
    generator: torch.Generator | None = None,
    validate: bool = True,
) -> torch.Tensor:
    """The paper's point-to-primitive distance d(p, C) = |q - p|^2, Eq. (5), for rectangles.

    The edge is chosen by :func:`best_matching_edge` (no gradient); p^s = p + e n, e ~ N(0, sigma_s^2),
    is sampled along the normal; q is the point of that edge SEGMENT nearest to p^s; d is measured to
    the ORIGINAL point p. On an edge tilted by theta from n, E[d] = sigma_s^2 sin^2 theta.

    Args:
        points: (B, N, 2).
        normals: (B, N, 2) unit normals of the points.
        centers: (B, K, 2); angles: (B, K); half_sizes: (B, K, 2), >= 0.
        sigma_s: standard deviation of e; 0 (with no offsets) is the unsampled variant.
        offsets: optional (B, N) values of e, one per point shared by all rectangles (then sigma_s is unused).
        generator: source of e when ``offsets`` is None.
        validate: check the inputs; False expects tensors of one dtype and device.

    Returns:
        (B, N, K) squared distances.
    """
    if validate:
        centers, angles, half_sizes, points, normals, _ = _validate(centers, angles, half_sizes, points, normals)
        if not (math.isfinite(sigma_s) and sigma_s >= 0):
            raise ValueError(f"sigma_s must be a finite non-negative number, got {sigma_s}")
    B, N = points.shape[:2]
    if offsets is not None:
        if validate:
            offsets = as_float_tensor(offsets, "offsets", dtype=points.dtype, device=points.device)
            check_shape(offsets, (B, N), "offsets")
            check_finite(offsets, "offsets")
    elif sigma_s > 0:
        offsets = sigma_s * torch.randn(B, N, generator=generator, dtype=points.dtype, device=points.device)
    x, y = _local_xy(points, centers, angles)  # the original point p, each (B, N, K)
    nx, ny = _local_dir(normals, angles)
    if offsets is None:
        sx, sy = x, y
    else:  # the sampled point p^s = p + e n, in each rectangle's frame
        sx, sy = x + offsets[:, :, None] * nx, y + offsets[:, :, None] * ny
    with torch.no_grad():  # the edge choice of _matching_edge, as two masks
        m = torch.maximum(nx.abs(), ny.abs())
        plus_x, plus_y = nx == m, ny == m
        on_x = (plus_x | (~plus_y & (-nx == m))).to(x.dtype)  # 1 for edges 0 and 2 (x = +-hx)
        sign = 2 * (plus_x | plus_y).to(x.dtype) - 1  # +1 for edges 0 and 1, -1 for edges 2 and 3
    hx, hy = half_sizes[:, None, :, 0], half_sizes[:, None, :, 1]
    # q lies on the edge line (x = sign * hx, say) and, along the edge, at p^s clamped to the segment
    d_x_edge = (sign * hx - x).square() + (torch.clamp(sy, min=-hy, max=hy) - y).square()
    d_y_edge = (sign * hy - y).square() + (torch.clamp(sx, min=-hx, max=hx) - x).square()
    return on_x * d_x_edge + (1 - on_x) * d_y_edge


# --------------------------------------------------------------------------------------------------
# Fitting K rectangles to one point set per batch element


class FitResult(NamedTuple):
    """Output of :func:`fit_rectangles`, all detached.

    Attributes:
        centers: (B, K, 2); angles: (B, K); half_sizes: (B, K, 2): the fitted rectangles.
        W: (B, N, K) final allocation: the softmax for "soft", for "min" one-hot of the rectangle at
            the smallest unsampled distance.
        portions: (B, K), w_k = mean_n W_nk.
        history: (steps, B), the objective at every step.
    """

    centers: torch.Tensor
    angles: torch.Tensor
    half_sizes: torch.Tensor
    W: torch.Tensor
    portions: torch.Tensor
    history: torch.Tensor

    @property
    def rectangles(self) -> Rectangles:
        """The fitted rectangles as one (centers, angles, half_sizes) tuple."""
        return Rectangles(self.centers, self.angles, self.half_sizes)


def _check_fit_inputs(points, normals, K, distance, assignment, steps, init_size, non_negative: dict):
    """The checks of :func:`fit_rectangles`; returns points (B, N, 2) and normals (or None) as tensors."""
    if distance not in ("nearest", "normal"):
        raise ValueError(f'distance must be "nearest" or "normal", got {distance!r}')
    if assignment not in ("min", "soft"):
        raise ValueError(f'assignment must be "min" or "soft", got {assignment!r}')
    if distance == "normal" and normals is None:
        raise ValueError('normals (B, N, 2) are required for distance="normal"')
    points = as_float_tensor(points, "points")
    named = {"points": check_shape(points, ("B", "N", 2), "points")}
    if normals is not None:
        normals = as_float_tensor(normals, "normals", dtype=points.dtype, device=points.device)
        named["normals"] = check_shape(normals, ("B", "N", 2), "normals")
    sizes: dict = {}
    check_same_leading(named, sizes, "points and normals")
    if sizes["N"] == 0:
        raise ValueError("points is empty (N = 0); at least one point is needed")
    check_finite(points, "points")
    if normals is not None:
        check_finite(normals, "normals")
        check_unit_vectors(normals, "normals")
    if not isinstance(K, int) or K < 1:
        raise ValueError(f"K must be a positive integer (number of rectangles), got {K!r}")
    if not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps must be a positive integer, got {steps!r}")
    for name, value in non_negative.items():
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite non-negative number, got {value}")
    low, high = init_size
    if not 0 < low <= high:
        raise ValueError(f"init_size must be (low, high) with 0 < low <= high, got {init_size}")
    return points, normals


def _random_start(points: torch.Tensor, K: int, init_size, gen: torch.Generator):
    """Random rectangles for every shape: centres (B, K, 2) uniform in the points' bounding box, angles
    (B, K) uniform in [0, pi/2), log half sizes (B, K, 2) from sizes uniform in ``init_size`` (fractions of
    the larger half extent of the bounding box)."""
    B, dtype, device = points.shape[0], points.dtype, points.device
    low, high = init_size
    lo, hi = points.amin(dim=1), points.amax(dim=1)  # (B, 2)
    scale = ((hi - lo) / 2).amax(dim=-1).clamp_min(1e-6)  # (B,)
    centers = lo[:, None, :] + (hi - lo)[:, None, :] * torch.rand(B, K, 2, generator=gen, dtype=dtype, device=device)
    angles = torch.rand(B, K, generator=gen, dtype=dtype, device=device) * (math.pi / 2)
    sizes0 = low + (high - low) * torch.rand(B, K, 2, generator=gen, dtype=dtype, device=device)
    return centers, angles, torch.log(sizes0 * scale[:, None, None])


def fit_rectangles(
    points: torch.Tensor,
    normals: torch.Tensor | None,
    K: int,
    distance: str = "normal",
    assignment: str = "soft",
    compactness_weight: float = 0.03,
    sigma_s: float = 0.05,
    steps: int = 400,
    lr: float = 0.05,
    logit_lr: float = 0.03,
    bias_lr: float = 0.1,
    init_size: tuple[float, float] = (0.1, 0.4),
    seed: int = 0,
) -> FitResult:
    """Fit K rectangles to each point set of the batch by Adam from a random start.

    "soft" minimises Eq. (4) + lambda_1 Eq. (6) with W = softmax_k(a_nk + b_k): free logits per point
    and rectangle, plus one per rectangle that moves a whole group of points at once (the role of the
    network's cuboid feature). "min" minimises mean_n min_k d(p_n, R_k), the hard assignment of
    P2C-Dis (Sec. 4.3). Batch elements are independent fits: repeat one shape along the batch axis
    to run several random starts at once.

    Args:
        points: (B, N, 2).
        normals: (B, N, 2) unit normals; may be None for distance="nearest".
        K: rectangles per shape.
        distance: "normal" (:func:`normal_aware_distance`, a fresh e per step) or "nearest"
            (:func:`nearest_edge_distance`).
        assignment: "soft" or "min" (no compactness term).
        compactness_weight: lambda_1; 0.03 suits shapes about 2 units across (distances scale with
            the size squared, the compactness term does not).
        sigma_s: standard deviation of the sampling along the normal (the paper's 0.05).
        steps: Adam steps, with all learning rates decayed to 0 on a cosine schedule.
        lr: learning rate of the rectangles (half sizes are exp of a free parameter).
        logit_lr: learning rate of the logits a_nk, which start at -d_nk / mean(d).
        bias_lr: learning rate of the logits b_k, which start at 0.
        init_size: (low, high), starting half sizes as fractions of the larger half extent of the
            points' bounding box; centres start uniform in the box, angles in [0, pi/2).
        seed: the random start, the same for every distance and assignment.

    Returns:
        A :class:`FitResult`.
    """
    points, normals = _check_fit_inputs(points, normals, K, distance, assignment, steps, init_size, {
        "compactness_weight": compactness_weight, "sigma_s": sigma_s, "lr": lr, "logit_lr": logit_lr, "bias_lr": bias_lr
    })
    B = points.shape[0]
    dtype, device = points.dtype, points.device
    gen = torch.Generator(device=device).manual_seed(seed)
    centers, angles, log_half = _random_start(points, K, init_size, gen)
    params = [centers.requires_grad_(), angles.requires_grad_(), log_half.requires_grad_()]

    def distances(sampled: bool = True) -> torch.Tensor:
        half = log_half.exp()
        if distance == "nearest":
            return nearest_edge_distance(points, centers, angles, half, validate=False)
        return normal_aware_distance(
            points, normals, centers, angles, half, sigma_s=sigma_s if sampled else 0.0, generator=gen, validate=False
        )

    groups = [{"params": params, "lr": lr}]
    if assignment == "soft":
        # logits are stored as (B, K, N): a softmax over a middle axis is much faster on CPU than
        # over a short last axis; W is the (B, N, K) view of the result
        with torch.no_grad():
            d0 = distances(sampled=False).transpose(1, 2)
            logits = (-d0 / d0.mean(dim=(1, 2), keepdim=True).clamp_min(1e-12)).contiguous()
        bias = torch.zeros(B, K, 1, dtype=dtype, device=device)
        groups.append({"params": [logits.requires_grad_()], "lr": logit_lr})
        groups.append({"params": [bias.requires_grad_()], "lr": bias_lr})
    optimizer = torch.optim.Adam(groups)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda i: 0.5 * (1 + math.cos(math.pi * i / steps)))

    def objective() -> torch.Tensor:  # (B,): Eq. (4) (+ lambda_1 Eq. (6)), or the min-assignment loss
        d = distances()
        if assignment == "min":
            return d.min(dim=-1).values.mean(dim=1)
        W = torch.softmax(logits + bias, dim=1).transpose(1, 2)
        value = (W * d).sum(dim=-1).mean(dim=1)
        if compactness_weight > 0:
            value = value + compactness_weight * compactness_loss(allocation_portions(W))
        return value

    history = torch.empty(steps, B, dtype=dtype)
    for i in range(steps):
        value = objective()
        optimizer.zero_grad(set_to_none=True)
        value.sum().backward()
        optimizer.step()
        schedule.step()
        history[i] = value.detach().cpu()

    with torch.no_grad():
        if assignment == "min":
            W = torch.nn.functional.one_hot(distances(sampled=False).argmin(dim=-1), K).to(dtype)
        else:
            W = torch.softmax(logits + bias, dim=1).transpose(1, 2).contiguous()
        return FitResult(
            centers.detach(), angles.detach(), log_half.detach().exp(), W, allocation_portions(W), history
        )
