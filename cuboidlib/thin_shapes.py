"""The thin-structure set: procedural shapes with thinner and more numerous parts than the training
categories (legs, struts, antennae, handles, rails and spokes), to measure the per-shape fit, the
refinement and the network check of :func:`cuboidlib.abstraction.abstract` off the training categories.

The set is fixed: :data:`THIN_KINDS` kinds, :data:`THIN_PER_KIND` shapes each, shape i of a kind drawn
from a generator seeded with (kind, i). Each shape is a union of analytic solids (:mod:`cuboidlib.solids`)
sampled area-uniformly on its outer surface and normalised (:mod:`cuboidlib.normalization`), +y up like
the training shapes. Part labels are not recorded (no part names for these kinds).
"""

from __future__ import annotations

import math

import numpy as np

from .normalization import normalize
from .solids import Capsule, Cylinder, Ellipsoid, Solid, bar, box, rotation_y, sample_union_surface

__all__ = ["THIN_KINDS", "THIN_PER_KIND", "thin_shape", "thin_structure_set"]

#: The kinds of the thin-structure set, each with its thin parts.
THIN_KINDS: tuple[str, ...] = ("insect", "spider", "stool", "wheel", "mug", "ladder", "drone", "lamp")
#: Shapes of each kind in the set.
THIN_PER_KIND = 2


def _insect(rng: np.random.Generator, legs_per_side: int = 3, leg_len: float = 1.0) -> list[Solid]:
    body = [Ellipsoid([0, 0.35, z], np.eye(3), r, 0) for z, r in
            ((-0.7, [0.28, 0.22, 0.5]), (0.0, [0.2, 0.18, 0.28]), (0.42, [0.15, 0.14, 0.15]))]
    width = rng.uniform(0.03, 0.05)
    parts = list(body)
    for side in (-1, 1):
        for j in range(legs_per_side):
            z = np.linspace(-0.25, 0.25, legs_per_side)[j] if legs_per_side > 1 else 0.0
            root = np.array([side * 0.15, 0.35, z])
            knee = root + np.array([side * 0.45 * leg_len, rng.uniform(0.15, 0.3), z * 0.8])
            foot = knee + np.array([side * 0.3 * leg_len, -0.35 - knee[1] + 0.35 + 0.0, z * 0.8])
            foot[1] = 0.0
            parts += [Capsule(root, knee, width / 2, 1), Capsule(knee, foot, width / 2, 1)]
    for side in (-1, 1):  # antennae
        tip = np.array([side * rng.uniform(0.2, 0.35), 0.35 + rng.uniform(0.3, 0.5), 0.42 + rng.uniform(0.4, 0.6)])
        parts.append(Capsule([side * 0.05, 0.42, 0.5], tip, width / 3, 2))
    return parts


def _spider(rng: np.random.Generator) -> list[Solid]:
    return _insect(rng, legs_per_side=4, leg_len=rng.uniform(1.1, 1.4))[:-2]


def _stool(rng: np.random.Generator) -> list[Solid]:
    h, r, w = rng.uniform(0.7, 0.9), rng.uniform(0.22, 0.3), rng.uniform(0.025, 0.035)
    legs = int(rng.integers(3, 5))
    parts: list[Solid] = [Cylinder([0, h, 0], rotation_y(0) @ np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]]), r, 0.025, 0)]
    feet = [np.array([1.3 * r * math.cos(2 * math.pi * k / legs), 0.0, 1.3 * r * math.sin(2 * math.pi * k / legs)])
            for k in range(legs)]
    tops = [np.array([0.8 * r * math.cos(2 * math.pi * k / legs), h, 0.8 * r * math.sin(2 * math.pi * k / legs)])
            for k in range(legs)]
    parts += [bar(f, t, w, 1) for f, t in zip(feet, tops)]
    for frac in (0.3,):  # a ring of rails between the legs
        ring = [f + frac * (t - f) for f, t in zip(feet, tops)]
        parts += [bar(ring[k], ring[(k + 1) % legs], w * 0.8, 2) for k in range(legs)]
    return parts


def _wheel(rng: np.random.Generator) -> list[Solid]:
    spokes, r, w = int(rng.integers(5, 9)), 0.5, rng.uniform(0.02, 0.03)
    segments = 16
    rim = [np.array([r * math.cos(2 * math.pi * k / segments), 0.5 + r * math.sin(2 * math.pi * k / segments), 0])
           for k in range(segments)]
    parts: list[Solid] = [Cylinder([0, 0.5, 0], np.eye(3), 0.07, 0.06, 0)]
    parts += [bar(rim[k] * [1.02, 1, 1] + [0, 0, 0], rim[(k + 1) % segments], 2.2 * w, 1, up=(0, 0, 1))
              for k in range(segments)]
    parts += [bar([0, 0.5, 0], [r * math.cos(2 * math.pi * k / spokes + 0.3), 0.5 + r * math.sin(2 * math.pi * k / spokes + 0.3), 0],
                  w, 2, up=(0, 0, 1)) for k in range(spokes)]
    return parts


def _mug(rng: np.random.Generator) -> list[Solid]:
    r, h, w = rng.uniform(0.25, 0.32), rng.uniform(0.35, 0.5), rng.uniform(0.035, 0.05)
    up = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], dtype=float)  # local z -> +y
    parts: list[Solid] = [Cylinder([0, h, 0], up, r, h, 0)]
    out = r + rng.uniform(0.15, 0.22)
    pts = [np.array([r - 0.02, 1.6 * h, 0]), np.array([out, 1.5 * h, 0]), np.array([out, 0.5 * h, 0]),
           np.array([r - 0.02, 0.4 * h, 0])]
    parts += [bar(a, b, w, 1, up=(0, 0, 1)) for a, b in zip(pts[:-1], pts[1:])]
    return parts


def _ladder(rng: np.random.Generator) -> list[Solid]:
    rungs, half, h, w = int(rng.integers(5, 8)), rng.uniform(0.18, 0.25), 1.0, rng.uniform(0.025, 0.035)
    lean = rng.uniform(0.1, 0.25)
    parts: list[Solid] = [bar([s * half, 0, 0], [s * half, h, lean], w, 0) for s in (-1, 1)]
    for k in range(rungs):
        t = (k + 0.5) / rungs
        parts.append(bar([-half, t * h, t * lean], [half, t * h, t * lean], w * 0.8, 1))
    return parts


def _drone(rng: np.random.Generator) -> list[Solid]:
    arm, w = rng.uniform(0.4, 0.55), rng.uniform(0.025, 0.035)
    up = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], dtype=float)
    parts: list[Solid] = [box([0, 0.1, 0], [0.12, 0.05, 0.16], label=0)]
    for k in range(4):
        a = math.pi / 4 + k * math.pi / 2
        tip = np.array([arm * math.cos(a), 0.12, arm * math.sin(a)])
        parts += [bar([0, 0.12, 0], tip, w, 1), Cylinder(tip + [0, 0.04, 0], up, w * 0.8, 0.04, 1),
                  Cylinder(tip + [0, 0.085, 0], up, rng.uniform(0.15, 0.2), 0.006, 2)]
    parts += [bar([s * 0.1, 0.06, -0.12], [s * 0.14, 0.0, -0.12], w * 0.7, 3) for s in (-1, 1)]
    return parts


def _lamp(rng: np.random.Generator) -> list[Solid]:
    up = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], dtype=float)
    h, w = rng.uniform(0.6, 0.8), rng.uniform(0.02, 0.03)
    reach = rng.uniform(0.3, 0.45)
    parts: list[Solid] = [Cylinder([0, 0.02, 0], up, rng.uniform(0.15, 0.2), 0.02, 0), bar([0, 0, 0], [0, h, 0], w, 1)]
    elbow = np.array([reach, h + 0.2, 0])
    parts += [bar([0, h, 0], elbow, w, 1, up=(0, 0, 1)),
              Cylinder(elbow + [0.05, -0.08, 0], up, 0.1, 0.07, 2)]
    return parts


_GENERATORS = {"insect": _insect, "spider": _spider, "stool": _stool, "wheel": _wheel, "mug": _mug,
               "ladder": _ladder, "drone": _drone, "lamp": _lamp}


def thin_shape(kind: str, index: int = 0, n_points: int = 2048) -> tuple[np.ndarray, np.ndarray]:
    """Shape ``index`` of a kind of the thin-structure set, sampled and normalised.

    Args:
        kind: one of :data:`THIN_KINDS`.
        index: the shape's index, >= 0.
        n_points: N, surface points.

    Returns:
        (points (N, 3) float32, outward unit normals (N, 3) float32), +y up, normalised.
    """
    if kind not in THIN_KINDS:
        raise ValueError(f"kind must be one of {THIN_KINDS}, got {kind!r}")
    if isinstance(index, bool) or not isinstance(index, int) or index < 0:
        raise ValueError(f"index must be a non-negative integer, got {index!r}")
    if isinstance(n_points, bool) or not isinstance(n_points, int) or n_points < 1:
        raise ValueError(f"n_points must be a positive integer, got {n_points!r}")
    rng = np.random.default_rng([THIN_KINDS.index(kind), index, 7])
    solids = _GENERATORS[kind](rng)
    p, nn, _ = sample_union_surface(solids, n_points, np.random.default_rng([THIN_KINDS.index(kind), index, 8]))
    p, _, _ = normalize(p)
    return p.astype(np.float32), nn.astype(np.float32)


def thin_structure_set(n_points: int = 2048) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The whole thin-structure set.

    Args:
        n_points: N, surface points per shape.

    Returns:
        {"<kind>_<i>": (points (N, 3), normals (N, 3))} for every kind and i < :data:`THIN_PER_KIND`.
    """
    return {f"{kind}_{i}": thin_shape(kind, i, n_points) for kind in THIN_KINDS for i in range(THIN_PER_KIND)}
