"""What the procedural categories of :mod:`cuboidlib.shapes` build their parts with: a seeded choice, a
hexahedron on three axes, a tapered swept wing (also the airplanes' fins and stabilisers).

Every generator of ``shapes_<category>.py`` takes a ``numpy.random.Generator`` and returns ``(solids, structure,
coarse)``; the draws are made in a fixed order, so one seed gives one shape.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .solids import Hexahedron

__all__ = ["DEG", "pick", "frame_block", "wing_corners"]

#: One degree in radians.
DEG = math.pi / 180


def pick(rng: np.random.Generator, options: Sequence[str], probs: Sequence[float]) -> str:
    """One of ``options``, drawn with weights ``probs`` (one uniform draw of ``rng``)."""
    return options[int(np.searchsorted(np.cumsum(probs), rng.random() * sum(probs), side="right"))]


def frame_block(origin, axes, x, a, b, label: int) -> Hexahedron:
    """A hexahedron spanning ranges ``x``, ``a``, ``b`` along the three ``axes`` from ``origin``."""
    ex, eu, ev = (np.asarray(v, dtype=float) for v in axes)
    corners = [
        origin + x[i & 1] * ex + a[(i >> 1) & 1] * eu + b[(i >> 2) & 1] * ev for i in range(8)
    ]
    return Hexahedron(np.array(corners), label)


def wing_corners(root_le_z: float, chord: float, taper: float, span: float, sweep: float, thickness: float) -> np.ndarray:
    """Corners (8, 3) of a tapered swept wing half along +x, root at x = 0, centred on y = 0.

    Root and tip chords are parallel to z, so every face is planar. Corner bits: x (root/tip),
    y (bottom/top), z (trailing/leading edge).
    """
    corners = np.empty((8, 3))
    for i in range(8):
        tip = i & 1
        c = chord * (taper if tip else 1.0)
        t = thickness * (taper if tip else 1.0)
        le = root_le_z - (span * math.tan(sweep) if tip else 0.0)
        corners[i] = (span if tip else 0.0, t / 2 if (i >> 1) & 1 else -t / 2, le if (i >> 2) & 1 else le - c)
    return corners
