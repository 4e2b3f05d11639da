"""The procedural four-legged animals of :mod:`cuboidlib.shapes`: body, head and neck, legs, tail.
"""

from __future__ import annotations

import math

import numpy as np

from .shapes_common import DEG, pick
from .solids import Capsule, Ellipsoid, Solid, rotation_x

__all__ = ["animal"]


# -------------------------------------------------------------------------------------- animal
# Ellipsoid body; four legs of two capsules each (bent at the knee); neck capsule, head and snout
# ellipsoids, optional ears; tail of one or two capsules. Body plans: standard, long-neck, low-long,
# stocky.

_ANIMAL_PLANS = {
    # body half-height, half-width, hip height, leg radius, neck length, neck angle (deg),
    # neck radius, head radii (x, y, z) ranges
    "standard": ((0.15, 0.22), (0.12, 0.20), (0.45, 0.80), (0.035, 0.06), (0.15, 0.30), (30, 60),
                 (0.05, 0.08), ((0.07, 0.10), (0.07, 0.10), (0.12, 0.18))),
    "long-neck": ((0.15, 0.20), (0.12, 0.17), (0.80, 1.20), (0.03, 0.05), (0.55, 0.90), (55, 75),
                  (0.04, 0.06), ((0.05, 0.08), (0.06, 0.09), (0.10, 0.15))),
    "low-long": ((0.10, 0.14), (0.10, 0.14), (0.12, 0.25), (0.03, 0.045), (0.05, 0.15), (10, 30),
                 (0.05, 0.08), ((0.07, 0.10), (0.06, 0.09), (0.12, 0.20))),
    "stocky": ((0.25, 0.33), (0.22, 0.30), (0.25, 0.40), (0.06, 0.09), (0.15, 0.25), (15, 35),
               (0.10, 0.14), ((0.10, 0.14), (0.10, 0.14), (0.14, 0.20))),
}


def animal(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    BODY, HEAD, LEG, TAIL = range(4)
    U = rng.uniform
    plan = pick(rng, tuple(_ANIMAL_PLANS), (1, 1, 1, 1))
    ry_r, rx_r, hip_r, lr_r, nl_r, na_r, nr_r, head_r = _ANIMAL_PLANS[plan]
    long_tail = rng.random() < {"low-long": 0.8, "stocky": 0.2}.get(plan, 0.5)
    ears = rng.random() < 0.5
    rz, ry, rx = 0.5, U(*ry_r), U(*rx_r)
    hip_y = U(*hip_r)
    hb = hip_y + 0.4 * ry
    pitch = U(-5, 5) * DEG
    parts: list[Solid] = [Ellipsoid([0, hb, 0], rotation_x(pitch), [rx, ry, rz], BODY)]

    leg_r = U(*lr_r)
    for sz in (1, -1):  # front legs (+z), hind legs (-z)
        for sx in (-1, 1):
            hip = np.array([sx * 0.55 * rx, hip_y, sz * 0.62 * rz])
            knee = np.array([hip[0], hip_y * U(0.4, 0.6), hip[2] + sz * U(-0.06, 0.06)])
            foot = np.array([hip[0] * U(1.0, 1.15), 0.75 * leg_r, hip[2] + U(-0.04, 0.04)])
            parts.append(Capsule(hip, knee, leg_r, LEG))
            parts.append(Capsule(knee, foot, 0.75 * leg_r, LEG))

    # Neck (labelled head) and head.
    ang = U(*na_r) * DEG
    base = np.array([0.0, hb + 0.45 * ry, 0.75 * rz])
    end = base + U(*nl_r) * np.array([0.0, math.sin(ang), math.cos(ang)])
    parts.append(Capsule(base, end, U(*nr_r), HEAD))
    hr = np.array([U(*r) for r in head_r])
    head_rot = rotation_x(U(0, 25) * DEG)
    hc = end + head_rot @ np.array([0.0, 0.3 * hr[1], 0.3 * hr[2]])
    parts.append(Ellipsoid(hc, head_rot, hr, HEAD))
    parts.append(Ellipsoid(hc + head_rot @ np.array([0, -0.2 * hr[1], 0.8 * hr[2]]), head_rot, hr * [0.55, 0.5, 0.5], HEAD))
    if ears:
        for s in (-1, 1):
            parts.append(Ellipsoid(hc + head_rot @ np.array([s * 0.5 * hr[0], 0.85 * hr[1], -0.2 * hr[2]]), head_rot,
                                   hr * [0.25, 0.45, 0.15], HEAD))

    # Tail: one short capsule up and back, or two capsules curving down.
    t0 = np.array([0.0, hb + 0.2 * ry, -0.85 * rz])
    if long_tail:
        tr = U(0.02, 0.04)
        b1 = U(10, 50) * DEG
        t1 = t0 + U(0.2, 0.35) * np.array([0, -math.sin(b1), -math.cos(b1)])
        b2 = b1 + U(10, 40) * DEG
        t2 = t1 + U(0.15, 0.3) * np.array([0, -math.sin(b2), -math.cos(b2)])
        t1[1], t2[1] = max(t1[1], tr + 0.2 * hip_y), max(t2[1], 0.8 * tr + 0.15 * hip_y)  # clear of the floor
        parts.append(Capsule(t0, t1, tr, TAIL))
        parts.append(Capsule(t1, t2, 0.8 * tr, TAIL))
    else:
        b1 = -U(10, 40) * DEG
        parts.append(Capsule(t0, t0 + U(0.06, 0.15) * np.array([0, -math.sin(b1), -math.cos(b1)]),
                             U(0.025, 0.045), TAIL))

    structure = plan + ("+long-tail" if long_tail else "+short-tail") + ("+ears" if ears else "")
    return parts, structure, plan
