"""Frames: the rotation R that turns a shape into the course's frame (+y up, facing +z), ``p_course = R @ p``.

The networks were trained upright, so a shape is turned upright before the network sees it, and its result is
written back in the input's own axes (:class:`cuboidlib.results.Abstraction`'s ``frame``). A frame is named by
its axes (:func:`frame_rotation`, the 24 of :func:`candidate_frames`) or, for a shape in any rotation, found by
``abstract(..., up="auto")``: the geometry of that search is here, the network's scores come from
:mod:`cuboidlib.abstraction`, which runs it in two batched passes.

1. The mirror plane (:func:`mirror_normal`). Chairs, tables, airplanes and four-legged animals are
   symmetric left to right, so the normal of their mirror plane is the side axis x (about a degree off on
   the procedural and the real shapes of ``benchmarks/bench_rotation.py``). The up lies in that plane.
2. :func:`coarse_frames`: the up every :data:`COARSE_STEP` degrees in that plane, for both signs of x (24
   frames); the network's best reconstruction is within 15 degrees of upright.
3. :func:`refined_frames`: that frame's three half turns (up and down, front and back), and for each of the
   four the up of the ground the shape stands on (:func:`support_up`) and the normal of its flat area
   (:func:`flat_up`), measured on the points instead of searched. :func:`choose_frame` takes the half turn the
   network reconstructs best, the Chamfer distance weighed with how unlike its training shapes the network
   finds the shape (the latent distance tells up from down where the Chamfer distance hardly does, as for
   airplanes), then in it the ground, else the flat area, when the network reconstructs it nearly as well: the
   network's own optimum can lie 10-20 degrees off upright on real meshes, where the ground does not.

With ``front`` given, the same search turns the shape about that axis instead of the mirror normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .neighbors import nearest_index
from .normalization import normalize

__all__ = ["AXES", "frame_rotation", "default_front", "candidate_frames", "check_rotation", "is_axis_frame", "turn",
           "mirror_normal", "coarse_frames", "refined_frames", "support_up", "flat_up", "choose_frame", "Candidate",
           "COARSE_STEP", "LATENT_WEIGHT", "CUE_TOLERANCE", "CUE_ANGLE", "SNAP_DEGREES", "MIRROR_POINTS"]

AXES = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1), "-x": (-1, 0, 0), "-y": (0, -1, 0), "-z": (0, 0, -1)}

#: Degrees between the ups of :func:`coarse_frames` (12 ups in the mirror plane, 24 frames with both signs of x).
COARSE_STEP = 30
#: :func:`choose_frame` ranks the half turns by log(Chamfer) + LATENT_WEIGHT * latent distance (measured by
#: ``python benchmarks/bench_rotation.py``: the Chamfer distance alone took 2 of 27 real airplanes upside down).
LATENT_WEIGHT = 0.2
#: ... and takes the ground's or the flat area's frame when the network's Chamfer distance in it is at most this
#: many times the best of its half turn.
CUE_TOLERANCE = 1.3
#: The ground and the flat area count when their up lies within this many degrees of the network's best.
CUE_ANGLE = 25.0
#: An axis frame within this many degrees of the ground's or the flat area's frame is tried too, and preferred
#: in the same way: a file modelled upright in its own axes gets exactly those.
SNAP_DEGREES = 5.0
#: Points used to find the mirror plane (evenly spaced in the input's order).
MIRROR_POINTS = 512


def frame_rotation(up: str = "y", front: str | None = None) -> np.ndarray:
    """The rotation R that takes a shape with axes ``up`` and ``front`` into the course's frame (+y up, facing +z).

    Args:
        up, front: "x", "y", "z", "-x", "-y" or "-z", at right angles. The default front is +z, or -y for a
            z-up shape (Blender and many CAD exports), +y for -z up.

    Returns:
        (3, 3) float64, a signed permutation with ``p_course = R @ p``. Example: ``frame_rotation("z")`` maps
        (0, 0, 1) to (0, 1, 0) and (0, -1, 0) to (0, 0, 1).
    """
    if not isinstance(up, str) or up not in AXES:
        raise ValueError(f"up must be one of {', '.join(AXES)}, got {up!r}")
    if front is None:
        front = default_front(up)
    if not isinstance(front, str) or front not in AXES:
        raise ValueError(f"front must be one of {', '.join(AXES)}, got {front!r}")
    u, f = np.array(AXES[up], dtype=np.float64), np.array(AXES[front], dtype=np.float64)
    if abs(float(u @ f)) > 0.5:
        raise ValueError(f"front {front!r} must be perpendicular to up {up!r}")
    return np.stack([np.cross(u, f), u, f])  # rows: the input axes that become x, y (up) and z (front)


def default_front(up: str) -> str:
    """The front :func:`frame_rotation` takes for ``up``: +z, or -y for z up, +y for -z up."""
    return {"z": "-y", "-z": "y"}.get(up, "z")


def candidate_frames(front: str | None = None) -> list[tuple[str, str]]:
    """The (up, front) pairs of axes at right angles: all 24, or the 4 with the given ``front``.

    Args:
        front: an axis of :data:`AXES`, or None.

    Returns:
        A list of (up, front) pairs of axis names.
    """
    pairs = [(u, f) for u in AXES for f in AXES if abs(int(np.dot(AXES[u], AXES[f]))) == 0]
    return [(u, f) for u, f in pairs if front is None or f == front]


def check_rotation(rotation, name: str = "rotation") -> np.ndarray:
    """A (3, 3) rotation matrix (orthonormal rows, determinant +1), as float64.

    Args:
        rotation: array-like.
        name: its name in the error.

    Returns:
        The matrix.

    Raises:
        ValueError: on another shape, non-finite entries, rows that are not orthonormal (1e-6) or a reflection.
    """
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3) or not np.isfinite(r).all() or not np.allclose(r @ r.T, np.eye(3), atol=1e-6):
        raise ValueError(f"{name} must be a 3 x 3 rotation matrix (orthonormal rows), got {r.tolist()}")
    if np.linalg.det(r) < 0:
        raise ValueError(f"{name} must be a rotation, not a reflection (its determinant is -1)")
    return r


def is_axis_frame(rotation: np.ndarray) -> bool:
    """Whether a rotation is a signed permutation (one of the 24 axis frames)."""
    r = np.asarray(rotation, dtype=np.float64)
    return bool(np.allclose(np.abs(r), np.round(np.abs(r)), atol=1e-9))


def turn(points: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Points turned into a frame and normalised there (:mod:`cuboidlib.normalization`).

    Args:
        points: (N, 3) points (normalised in their own axes, as :func:`cuboidlib.abstract` keeps them).
        rotation: (3, 3) R, ``p_course = R @ p``.

    Returns:
        ``(turned, shift, scale)``: (N, 3) float32 ``(R p - shift) / scale``, bounding box centred with diagonal
        1. An axis frame keeps a normalised cloud normalised: shift 0 and scale 1 exactly.
    """
    rotation = np.asarray(rotation, dtype=np.float64)
    if np.allclose(rotation, np.eye(3)):
        return np.asarray(points, dtype=np.float32), np.zeros(3), 1.0
    turned = np.asarray(points, dtype=np.float64) @ rotation.T
    if is_axis_frame(rotation):
        return turned.astype(np.float32), np.zeros(3), 1.0
    normalised, shift, scale = normalize(turned)
    return normalised.astype(np.float32), shift, float(scale)


# ----------------------------------------------------------------------------------------------
# The mirror plane
# ----------------------------------------------------------------------------------------------


def _reflected(points: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    return points - 2.0 * np.outer(points @ normal - offset, normal)


def _mirror_error(points: np.ndarray, normals: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(K,) mean distance from the points reflected in K planes to their nearest point."""
    reflected = np.stack([_reflected(points, n, d) for n, d in zip(normals, offsets)])
    ref = torch.as_tensor(reflected)
    cloud = torch.as_tensor(points)[None].expand(len(normals), -1, -1)
    nearest = nearest_index(ref, cloud)
    found = torch.gather(cloud, 1, nearest[..., None].expand(-1, -1, 3))
    return (ref - found).norm(dim=-1).mean(dim=1).numpy()


def mirror_normal(points: np.ndarray, normals: np.ndarray, iterations: int = 8) -> tuple[np.ndarray, float]:
    """The normal of the plane the shape is most nearly mirror-symmetric in.

    The candidates are the principal axes of the points and of their normals (a mirror plane's normal is one of
    both); the best one is refined: each point is paired with the point nearest its reflection, and the plane
    through the pairs' midpoints (their least principal axis) replaces it while the error goes down.

    Args:
        points: (N, 3) points, normalised (:func:`cuboidlib.normalization.normalize`); at most
            :data:`MIRROR_POINTS` of them, evenly spaced, are used.
        normals: (N, 3) unit normals.
        iterations: most refinement steps.

    Returns:
        ``(normal, error)``: the unit normal (3,) float64, and the mean distance from the reflected points to the
        nearest point (a fraction of the diagonal: near the points' spacing for a symmetric shape).
    """
    step = max(1, -(-len(points) // MIRROR_POINTS))
    p = np.asarray(points, dtype=np.float64)[::step]
    centred = p - p.mean(axis=0)
    n = np.asarray(normals, dtype=np.float64)
    axes = np.concatenate([np.linalg.eigh(centred.T @ centred)[1].T, np.linalg.eigh(n.T @ n)[1].T])
    offsets = axes @ p.mean(axis=0)
    errors = _mirror_error(p, axes, offsets)
    k = int(np.argmin(errors))
    normal, offset, error = axes[k], float(offsets[k]), float(errors[k])
    for _ in range(iterations):
        reflected = _reflected(p, normal, offset)
        nearest = nearest_index(torch.as_tensor(reflected)[None], torch.as_tensor(p)[None])[0].numpy()
        gap = np.linalg.norm(reflected - p[nearest], axis=1)
        keep = gap <= np.quantile(gap, 0.8)  # the pairs that found their mirror image
        mid = (p[keep] + p[nearest[keep]]) / 2
        centred_mid = mid - mid.mean(axis=0)
        candidate = np.linalg.eigh(centred_mid.T @ centred_mid)[1][:, 0]
        candidate = candidate if candidate @ normal >= 0 else -candidate
        candidate_offset = float(mid.mean(axis=0) @ candidate)
        candidate_error = float(_mirror_error(p, candidate[None], np.array([candidate_offset]))[0])
        if candidate_error >= error:
            break
        normal, offset, error = candidate, candidate_offset, candidate_error
    return normal / np.linalg.norm(normal), error


# ----------------------------------------------------------------------------------------------
# Candidate frames
# ----------------------------------------------------------------------------------------------


def _frame(axis: np.ndarray, up: np.ndarray, fixed: str) -> np.ndarray:
    """The frame with ``up`` (made perpendicular to ``axis``) and ``axis`` as the side (x) or the front (z)."""
    u = up - (up @ axis) * axis
    u = u / np.linalg.norm(u)
    return np.stack([axis, u, np.cross(axis, u)]) if fixed == "side" else np.stack([np.cross(u, axis), u, axis])


def _plane_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.cross(axis, [1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.cross(axis, [0, 1.0, 0])
    a /= np.linalg.norm(a)
    return a, np.cross(axis, a)


def _check_fixed(axis, fixed: str) -> np.ndarray:
    if fixed not in ("side", "front"):
        raise ValueError(f"fixed must be 'side' or 'front', got {fixed!r}")
    a = np.asarray(axis, dtype=np.float64)
    if a.shape != (3,) or not np.isfinite(a).all() or not np.isclose(np.linalg.norm(a), 1.0, atol=1e-6):
        raise ValueError(f"axis must be a unit 3-vector, got {a.tolist()}")
    return a


def coarse_frames(axis: np.ndarray, fixed: str = "side", step: float = COARSE_STEP) -> list[np.ndarray]:
    """The frames of the first pass: the up every ``step`` degrees about ``axis``.

    Args:
        axis: (3,) unit vector, the mirror normal (``fixed="side"``) or the given front (``fixed="front"``).
        fixed: which axis of the course's frame ``axis`` becomes: "side" (x, both signs tried) or "front" (z).
        step: degrees between the ups.

    Returns:
        360 / step rotations for "front", twice as many for "side".
    """
    axis = _check_fixed(axis, fixed)
    a, b = _plane_basis(axis)
    signs = (1.0, -1.0) if fixed == "side" else (1.0,)
    angles = np.radians(np.arange(0.0, 360.0, step))
    return [_frame(s * axis, np.cos(t) * a + np.sin(t) * b, fixed) for s in signs for t in angles]


@dataclass
class Candidate:
    """A frame of the second pass: ``rotation``, ``kind`` ("network": the first pass's best or one of its half
    turns; "ground", "flat" or "axis") and ``variant``, the half turn it belongs to (0: the first pass's best)."""

    rotation: np.ndarray
    kind: str
    variant: int


def _variants(fixed: str) -> list[tuple[float, float]]:
    """(sign of the fixed axis, sign of up) of the half turns: itself, about the front, about x, about up."""
    return [(1.0, 1.0), (-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0)] if fixed == "side" else [(1.0, 1.0), (1.0, -1.0)]


def _nearest_axis_frame(rotation: np.ndarray) -> tuple[np.ndarray, float]:
    """The axis frame nearest a rotation, and the angle between them in degrees."""
    best, angle = None, 180.0
    for up, front in candidate_frames():
        r = frame_rotation(up, front)
        a = float(np.degrees(np.arccos(np.clip((np.trace(r @ rotation.T) - 1) / 2, -1.0, 1.0))))
        if a < angle:
            best, angle = r, a
    return best, angle


def refined_frames(points: np.ndarray, normals: np.ndarray, rotation: np.ndarray,
                   fixed: str = "side") -> list[Candidate]:
    """The frames of the second pass, around the first pass's best.

    Args:
        points, normals: (N, 3) the shape, normalised, in its own axes.
        rotation: (3, 3) the first pass's best frame (rows x, up, front).
        fixed: as in :func:`coarse_frames`: the axis kept ("side": row 0, "front": row 2).

    Returns:
        Candidates: ``rotation`` itself first, then its half turns (kind "network"), and for each half turn its
        ground (:func:`support_up`), flat area (:func:`flat_up`) and an axis frame within :data:`SNAP_DEGREES`
        of either (kinds "ground", "flat", "axis").
    """
    rotation = check_rotation(rotation)
    axis = _check_fixed(rotation[0] if fixed == "side" else rotation[2], fixed)
    up = rotation[1]
    out = [Candidate(rotation, "network", 0)]
    out += [Candidate(_frame(sa * axis, su * up, fixed), "network", v)
            for v, (sa, su) in enumerate(_variants(fixed)) if v > 0]
    cues = []
    for v, (sa, su) in enumerate(_variants(fixed)):
        for kind, found in (("ground", support_up(points, axis, su * up)), ("flat", flat_up(normals, axis, su * up))):
            if found is not None:
                cues.append(Candidate(_frame(sa * axis, found, fixed), kind, v))
    snapped = []
    for c in cues:
        frame, angle = _nearest_axis_frame(c.rotation)
        if angle <= SNAP_DEGREES and not any(np.allclose(frame, s.rotation) for s in snapped):
            snapped.append(Candidate(frame, "axis", c.variant))
    return out + cues + snapped


def _in_plane(axis: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(a, b): a the up made perpendicular to axis, b = axis x a."""
    a = up - (up @ axis) * axis
    a = a / np.linalg.norm(a)
    return a, np.cross(axis, a)


def _hull_2d(xy: np.ndarray) -> np.ndarray:
    """Indices of the convex hull of 2D points, counter-clockwise (Andrew's monotone chain)."""
    order = np.lexsort((xy[:, 1], xy[:, 0]))

    def chain(indices) -> list[int]:
        hull: list[int] = []
        for i in indices:
            while len(hull) >= 2:
                o, a = xy[hull[-2]], xy[hull[-1]]
                if (a[0] - o[0]) * (xy[i, 1] - o[1]) - (a[1] - o[1]) * (xy[i, 0] - o[0]) > 0:
                    break
                hull.pop()
            hull.append(int(i))
        return hull

    lower, upper = chain(order), chain(order[::-1])
    return np.array(lower[:-1] + upper[:-1])


def support_up(points: np.ndarray, axis: np.ndarray, up: np.ndarray, within: float = CUE_ANGLE) -> np.ndarray | None:
    """The up of the ground the shape stands on, seen along ``axis``.

    The points are projected along ``axis`` (the mirror normal: the shape seen from its side); the edge of their
    convex hull below the centroid, along ``-up``, is the ground line through the feet (four legs, a pedestal,
    hooves), and its normal is the up.

    Args:
        points: (N, 3) the shape.
        axis: (3,) unit vector seen along (the up found is perpendicular to it).
        up: (3,) the approximate up.
        within: degrees; a ground farther from ``up`` is not one (None).

    Returns:
        (3,) unit up, or None.
    """
    a, b = _in_plane(axis, np.asarray(up, dtype=np.float64))
    p = np.asarray(points, dtype=np.float64)
    p = p - p.mean(axis=0)
    xy = np.stack([p @ b, p @ a], axis=1)  # horizontal, vertical; the centroid at the origin
    hull = xy[_hull_2d(xy)]
    if len(hull) < 3:
        return None
    ends = np.roll(hull, -1, axis=0)
    for v, w in zip(hull, ends):
        if min(v[0], w[0]) <= 0.0 <= max(v[0], w[0]) and v[0] != w[0]:
            height = v[1] + (w[1] - v[1]) * (-v[0]) / (w[0] - v[0])
            if height < 0:  # the edge below the centroid
                edge = w - v
                normal = np.array([-edge[1], edge[0]]) / np.linalg.norm(edge)
                normal = normal if normal[1] > 0 else -normal
                found = normal[0] * b + normal[1] * a
                return found if normal[1] >= np.cos(np.radians(within)) else None
    return None


def flat_up(normals: np.ndarray, axis: np.ndarray, up: np.ndarray, within: float = CUE_ANGLE) -> np.ndarray | None:
    """The direction perpendicular to ``axis`` that most of the surface faces (up or down), near ``up``.

    The principal axis of the normals projected along ``axis``: an airplane's wings and fuselage and a table's
    top face up and down.

    Args:
        normals: (N, 3) unit normals (their sign does not matter).
        axis, up, within: as in :func:`support_up`.

    Returns:
        (3,) unit up, or None.
    """
    a, b = _in_plane(axis, np.asarray(up, dtype=np.float64))
    n = np.asarray(normals, dtype=np.float64)
    flat = np.stack([n @ a, n @ b], axis=1)
    vectors = np.linalg.eigh(flat.T @ flat)[1].T
    v = max(vectors, key=lambda e: abs(e[0]))  # the principal direction nearer up
    v = v if v[0] > 0 else -v
    return v[0] * a + v[1] * b if v[0] >= np.cos(np.radians(within)) else None


# ----------------------------------------------------------------------------------------------
# The choice
# ----------------------------------------------------------------------------------------------


def choose_frame(candidates: list[Candidate], chamfer: np.ndarray, latent: np.ndarray | None) -> int:
    """The frame :func:`cuboidlib.abstract` keeps among the second pass's candidates.

    First the half turn: the one whose best frame has the lowest log(Chamfer) + :data:`LATENT_WEIGHT` *
    latent distance (Chamfer alone without the network's latent statistics). Then in it: an axis frame, else the
    ground's frame, else the flat area's, the first whose Chamfer distance is at most :data:`CUE_TOLERANCE` times
    the half turn's best; else the frame with the lowest Chamfer distance.

    Args:
        candidates: from :func:`refined_frames`.
        chamfer: (K,) the network's Chamfer distance in each.
        latent: (K,) the latent distance of each, or None.

    Returns:
        The index of the frame kept.
    """
    chamfer = np.asarray(chamfer, dtype=np.float64)
    score = np.log(np.maximum(chamfer, 1e-300))
    if latent is not None:
        score = score + LATENT_WEIGHT * np.asarray(latent, dtype=np.float64)
    variants = sorted({c.variant for c in candidates})
    best = min(variants, key=lambda v: min(score[i] for i, c in enumerate(candidates) if c.variant == v))
    members = [i for i, c in enumerate(candidates) if c.variant == best]
    lowest = min(chamfer[i] for i in members)
    for kind in ("axis", "ground", "flat"):
        for i in members:
            if candidates[i].kind == kind and chamfer[i] <= CUE_TOLERANCE * lowest:
                return i
    return min(members, key=lambda i: chamfer[i])
