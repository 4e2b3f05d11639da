"""Frames: the rotation R that turns a shape into the course's frame (+y up, facing +z), ``p_course = R @ p``.

The networks were trained upright, so a shape is turned upright before the network sees it, and its result is
written back in the input's own axes (:class:`cuboidlib.results.Abstraction`'s ``frame``). A frame is named by
its axes (:func:`frame_rotation`, the 24 of :func:`candidate_frames`) or, for a shape in any rotation, found by
``abstract(..., up="auto")``: the geometry of that search is here, the network's scores come from
:mod:`cuboidlib.abstraction`, which runs it in one batched pass (two for a shape with two mirror planes).

1. The mirror plane (:func:`mirror_normal`). Chairs, tables, airplanes and four-legged animals are
   symmetric left to right, so the normal of their mirror plane is the side axis x (about a degree off on
   the procedural and the real shapes of ``benchmarks/bench_rotation.py``). The up lies in that plane.
2. The ups in that plane are measured, not searched (:func:`search_frames`): the grounds the shape can stand
   on (:func:`ground_ups`: the edges of its outline seen from the side that the centroid lies above: the line
   through the feet) and the directions its surface faces most (:func:`flat_ups`: an airplane's wings and
   fuselage; an airplane's lowest points are no ground, so where the flat area dominates the grounds are not
   tried). Each up with both signs of x (front and back), and the axis frames near them.
3. :func:`choose_frame`: the network scores every frame in one batch; the orientation it reconstructs best,
   its Chamfer distance weighed with how unlike its training shapes the network finds the shape (the latent
   distance tells up from down where the Chamfer distance hardly does, as for airplanes), and in it an axis frame,
   else the ground, else the flat area, when the network reconstructs it nearly as well: the network's own
   optimum can lie 10-20 degrees off upright on real meshes, where the ground does not.

A shape with a second mirror plane at right angles (a table) gets the same frames about that plane, then a
second pass with the frame kept turned by 45 degrees each way (:func:`yawed_frames`). With ``front`` given, the
ups are measured about that axis instead of the mirror normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .neighbors import nearest_index
from .normalization import normalize

__all__ = ["AXES", "frame_rotation", "default_front", "candidate_frames", "check_rotation", "is_axis_frame", "turn",
           "mirror_normal", "Mirror", "search_frames", "ground_ups", "flat_ups", "yawed_frames", "choose_frame",
           "frame_score", "Candidate", "GROUND_LINES", "LATENT_WEIGHT", "CUE_TOLERANCE", "CUE_ANGLE",
           "FLAT_DOMINANCE", "SECOND_MIRROR", "YAWS", "SNAP_DEGREES", "MIRROR_POINTS"]

AXES = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1), "-x": (-1, 0, 0), "-y": (0, -1, 0), "-z": (0, 0, -1)}

#: At most this many grounds are tried (:func:`ground_ups`), the most stable: a shape seen from the side has 2-6,
#: and the one it stands on was among the 4 most stable wherever it was one of them (``python
#: benchmarks/bench_rotation.py --geometry``: 38 of 40 procedural animals, every chair and table).
GROUND_LINES = 6
#: :func:`choose_frame` ranks the half turns by log(Chamfer) + LATENT_WEIGHT * latent distance (measured by
#: ``python benchmarks/bench_rotation.py``: the Chamfer distance alone took 2 of 27 real airplanes upside down).
LATENT_WEIGHT = 0.2
#: ... and in that orientation an axis frame, else the ground's, else the flat area's, when the network's Chamfer
#: distance in it is at most this many times the orientation's best.
CUE_TOLERANCE = 1.3
#: Frames whose ups lie within this many degrees (and side axes within 45) are one orientation.
CUE_ANGLE = 35.0
#: The grounds are not tried where the normals' spread along their first principal axis is at least this many
#: times their spread along the second: an airplane's lowest points, engines and tail, are no ground, and its wings
#: and fuselage face up and down (``--geometry``: real airplanes 5.4-22, procedural 2.8-15; chairs 1.0-3.3; animals
#: 1.1-5.4, one of 40 procedural animals above 4.5; tables 1.1-16, whose top is both).
FLAT_DOMINANCE = 4.5
#: A second mirror plane at right angles whose error is at most this many times the first's (a table's; an
#: airplane's wing plane can mirror it nearly as well as its own) is searched too (:func:`search_frames`), and
#: adds a second pass: the frame kept turned by 45 degrees each way about its up (:func:`yawed_frames`), for a
#: square table whose mirror planes found are its diagonals.
SECOND_MIRROR = 1.3
#: The turns about up of that second pass, in degrees.
YAWS = (45.0, -45.0)
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


@dataclass
class Mirror:
    """The plane a shape is most nearly mirror-symmetric in (:func:`mirror_normal`): its unit ``normal``; its
    ``error``, the mean distance from the reflected points to the nearest point (a fraction of the diagonal,
    near the points' spacing for a symmetric shape); and ``second``, the normal of the best candidate plane at
    right angles to it (made exactly perpendicular) when that plane's error is at most :data:`SECOND_MIRROR`
    times the first's (a table's two planes; an airplane's wing plane, nearly one), else None."""

    normal: np.ndarray
    error: float
    second: np.ndarray | None = None


def _tilted_to_fit(points: np.ndarray, normal: np.ndarray, error: float) -> tuple[np.ndarray, float]:
    """The normal tilted 4, 2, 1 and 0.5 degrees at a time (four ways, one batch each) while the mirror error
    goes down, the plane through the centroid: the principal axes of 1024 random samples can lie several degrees
    off when two spreads are alike, and pairing points does not always fix it."""
    centroid = points.mean(axis=0)
    for degrees in (4.0, 2.0, 1.0, 0.5):
        t = np.radians(degrees)
        for _ in range(4):
            u, v = _plane_basis(normal)
            tilted = np.stack([np.cos(t) * normal + np.sin(t) * w for w in (u, -u, v, -v)])
            errors = _mirror_error(points, tilted, tilted @ centroid)
            k = int(np.argmin(errors))
            if errors[k] >= error:
                break
            normal, error = tilted[k], float(errors[k])
    return normal, error


def mirror_normal(points: np.ndarray, normals: np.ndarray, iterations: int = 8) -> Mirror:
    """The normal of the plane the shape is most nearly mirror-symmetric in.

    The candidates are the principal axes of the points and of their normals (a mirror plane's normal is one of
    both); the best one is refined: each point is paired with the point nearest its reflection, and the plane
    through the pairs' midpoints (their least principal axis) replaces it while the error goes down; then it is
    tilted a few degrees at a time while the error goes down.

    Args:
        points: (N, 3) points, normalised (:func:`cuboidlib.normalization.normalize`); at most
            :data:`MIRROR_POINTS` of them, evenly spaced, are used.
        normals: (N, 3) unit normals.
        iterations: most refinement steps.

    Returns:
        A :class:`Mirror`.
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
    across = [(e, a) for a, e in zip(axes, errors) if abs(a @ normal) < np.sin(np.radians(30))]
    second = min(across, key=lambda c: c[0]) if across else None
    second = second[1] if second is not None and second[0] <= SECOND_MIRROR * error else None
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
    normal, error = _tilted_to_fit(p, normal / np.linalg.norm(normal), error)
    if second is not None:
        second = second - (second @ normal) * normal
        second = second / np.linalg.norm(second)
    return Mirror(normal, error, second)


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


@dataclass
class Candidate:
    """A frame the network scores: ``rotation``; ``kind``, what proposed it ("ground", "flat" or "axis"); and
    ``variant``, the orientation it belongs to (frames with the side axis and the up within :data:`CUE_ANGLE`
    of each other share one)."""

    rotation: np.ndarray
    kind: str
    variant: int = -1


def _hull_2d(xy: np.ndarray) -> np.ndarray:
    """Indices of the convex hull of 2D points, counter-clockwise (Andrew's monotone chain on the points extreme
    in 360 directions: a hull vertex is missed only where the hull turns by less than a degree)."""
    t = np.linspace(0.0, 2.0 * np.pi, 360, endpoint=False)
    extreme = np.unique(np.argmax(np.outer(np.cos(t), xy[:, 0]) + np.outer(np.sin(t), xy[:, 1]), axis=1))
    order = extreme[np.lexsort((xy[extreme, 1], xy[extreme, 0]))]

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


def ground_ups(points: np.ndarray, axis: np.ndarray, count: int = GROUND_LINES) -> list[np.ndarray]:
    """The ups of the lines the shape can stand on, seen along ``axis``, most stable first.

    The points are projected along ``axis`` (the mirror normal: the shape seen from its side). An edge of their
    convex hull is a ground the shape can rest on when the centroid lies above it, between its ends (four legs, a
    pedestal, hooves); its up points from it to the centroid, and its stability is the angle the shape must tip
    by to fall off it.

    Args:
        points: (N, 3) the shape.
        axis: (3,) unit vector seen along; the ups are perpendicular to it.
        count: at most this many, the most stable.

    Returns:
        Unit ups (3,).
    """
    axis = _check_fixed(axis, "side")
    a, b = _plane_basis(axis)
    p = np.asarray(points, dtype=np.float64)
    p = p - p.mean(axis=0)
    xy = np.stack([p @ a, p @ b], axis=1)  # the centroid at the origin
    hull = xy[_hull_2d(xy)]
    found = []
    for v, w in zip(hull, np.roll(hull, -1, axis=0)):
        edge = w - v
        length = float(np.linalg.norm(edge))
        if length == 0:
            continue
        t = -float(v @ edge) / length ** 2  # where the perpendicular from the centroid meets the edge
        if not 0.0 < t < 1.0:
            continue
        normal = np.array([-edge[1], edge[0]]) / length
        height = -float(v @ normal)  # from the edge's line to the centroid, along normal
        if height < 0:
            normal, height = -normal, -height
        found.append((np.arctan2(min(t, 1.0 - t) * length, max(height, 1e-12)), normal[0] * a + normal[1] * b))
    found.sort(key=lambda f: -f[0])
    return [u for _, u in found[:count]]


def flat_ups(normals: np.ndarray, axis: np.ndarray) -> tuple[list[np.ndarray], float]:
    """The directions perpendicular to ``axis`` that most of the surface faces, both ways.

    The principal axes of the normals projected along ``axis``: an airplane's wings and fuselage and a table's
    top face up and down.

    Args:
        normals: (N, 3) unit normals (their sign does not matter).
        axis: (3,) unit vector.

    Returns:
        ``(ups, dominance)``: the first principal axis both ways, and the second too unless the first dominates;
        and the normals' spread along the first over their spread along the second (:data:`FLAT_DOMINANCE`).
    """
    axis = _check_fixed(axis, "side")
    a, b = _plane_basis(axis)
    n = np.asarray(normals, dtype=np.float64)
    flat = np.stack([n @ a, n @ b], axis=1)
    values, vectors = np.linalg.eigh(flat.T @ flat)
    dominance = float(values[1] / max(values[0], 1e-12))
    ups = [vectors[0, 1] * a + vectors[1, 1] * b]
    if dominance < FLAT_DOMINANCE:
        ups.append(vectors[0, 0] * a + vectors[1, 0] * b)
    return [s * u for u in ups for s in (1.0, -1.0)], dominance


def _nearest_axis_frame(rotation: np.ndarray) -> tuple[np.ndarray, float]:
    """The axis frame nearest a rotation, and the angle between them in degrees."""
    best, angle = None, 180.0
    for up, front in candidate_frames():
        r = frame_rotation(up, front)
        a = float(np.degrees(np.arccos(np.clip((np.trace(r @ rotation.T) - 1) / 2, -1.0, 1.0))))
        if a < angle:
            best, angle = r, a
    return best, angle


def search_frames(points: np.ndarray, normals: np.ndarray, mirror: Mirror | None = None,
                  front: np.ndarray | None = None) -> list[Candidate]:
    """The frames the network scores for ``up="auto"``, measured on the shape rather than searched.

    About the mirror normal (as the side axis x, both ways) or the given front: the ups of the grounds the shape
    can stand on (:func:`ground_ups`, not where the flat area dominates: an airplane's lowest points are no
    ground) and of its flat area (:func:`flat_ups`); the same about a second mirror plane (a table's other one),
    and an axis frame within :data:`SNAP_DEGREES` of any of them. Each frame's ``variant`` groups it with the
    frames of nearly the same orientation.

    Args:
        points, normals: (N, 3) the shape, normalised, in its own axes.
        mirror: its mirror plane (:func:`mirror_normal`), or None with ``front``.
        front: (3,) unit vector the front faces, or None with ``mirror``.

    Returns:
        Candidates, none two of a kind within 2 degrees of each other.
    """
    if (mirror is None) == (front is None):
        raise ValueError("give either the mirror plane or the front")
    if mirror is not None:
        about = [(mirror.normal, "side")] + ([(mirror.second, "side")] if mirror.second is not None else [])
    else:
        about = [(_check_fixed(front, "front"), "front")]
    found: list[Candidate] = []

    def add(candidate: Candidate) -> None:  # unless a frame within 2 degrees is there (an axis frame: of its kind)
        if all(np.trace(candidate.rotation @ c.rotation.T) < 1.0 + 2.0 * np.cos(np.radians(2.0)) for c in found
               if candidate.kind != "axis" or c.kind == "axis"):
            found.append(candidate)

    for axis, fixed in about:
        flats, dominance = flat_ups(normals, axis)
        grounds = ground_ups(points, axis) if dominance < FLAT_DOMINANCE else []
        for kind, ups in (("ground", grounds), ("flat", flats)):
            for up in ups:
                for sign in ((1.0, -1.0) if fixed == "side" else (1.0,)):
                    add(Candidate(_frame(sign * axis, up, fixed), kind))
    for c in list(found):
        frame, angle = _nearest_axis_frame(c.rotation)
        if angle <= SNAP_DEGREES:
            add(Candidate(frame, "axis"))
    representatives: list[np.ndarray] = []
    for c in found:  # the orientations: side axes within 45 degrees and ups within CUE_ANGLE
        for v, r in enumerate(representatives):
            if c.rotation[0] @ r[0] > np.cos(np.radians(45)) and c.rotation[1] @ r[1] >= np.cos(np.radians(CUE_ANGLE)):
                c.variant = v
                break
        else:
            c.variant = len(representatives)
            representatives.append(c.rotation)
    return found


# ----------------------------------------------------------------------------------------------
# The choice
# ----------------------------------------------------------------------------------------------


def yawed_frames(rotation: np.ndarray, degrees=YAWS) -> list[np.ndarray]:
    """The frame turned about its up (the course's y) by each angle: the second pass, for a shape with two mirror
    planes (a square table's mirror planes found may be its diagonals).

    Args:
        rotation: (3, 3) a frame.
        degrees: the turns.

    Returns:
        One rotation per turn.
    """
    rotation = check_rotation(rotation)
    out = []
    for d in degrees:
        t = np.radians(d)
        about_up = np.array([[np.cos(t), 0.0, np.sin(t)], [0.0, 1.0, 0.0], [-np.sin(t), 0.0, np.cos(t)]])
        out.append(about_up @ rotation)
    return out


def frame_score(chamfer: np.ndarray, latent: np.ndarray | None) -> np.ndarray:
    """log(Chamfer) + :data:`LATENT_WEIGHT` * latent distance (Chamfer alone when ``latent`` is None): lower is
    better. The latent distance tells up from down where the Chamfer distance hardly does (airplanes).

    Args:
        chamfer: (K,) the network's Chamfer distances.
        latent: (K,) its latent distances, or None.

    Returns:
        (K,) float64 scores.
    """
    score = np.log(np.maximum(np.asarray(chamfer, dtype=np.float64), 1e-300))
    return score if latent is None else score + LATENT_WEIGHT * np.asarray(latent, dtype=np.float64)


def choose_frame(candidates: list[Candidate], chamfer: np.ndarray, latent: np.ndarray | None) -> int:
    """The frame :func:`cuboidlib.abstract` keeps among the candidates.

    First the orientation (the candidates' ``variant``): the one whose best frame has the lowest
    :func:`frame_score` (Chamfer and latent distance). Then in it: an axis frame, else the ground's frame, else the
    flat area's, the first whose Chamfer distance is at most :data:`CUE_TOLERANCE` times the orientation's best.

    Args:
        candidates: from :func:`search_frames`.
        chamfer: (K,) the network's Chamfer distance in each.
        latent: (K,) the latent distance of each, or None.

    Returns:
        The index of the frame kept.
    """
    chamfer = np.asarray(chamfer, dtype=np.float64)
    score = frame_score(chamfer, latent)
    variants = sorted({c.variant for c in candidates})
    best = min(variants, key=lambda v: min(score[i] for i, c in enumerate(candidates) if c.variant == v))
    members = [i for i, c in enumerate(candidates) if c.variant == best]
    lowest = min(chamfer[i] for i in members)
    for kind in ("axis", "ground", "flat"):
        for i in members:
            if candidates[i].kind == kind and chamfer[i] <= CUE_TOLERANCE * lowest:
                return i
    return min(members, key=lambda i: chamfer[i])  # another kind of candidate
