"""The procedural four-legged animals of :mod:`cuboidlib.shapes`: body, head and neck, legs, tail.

Version 2 (:func:`animal_v2`) changes what the real animals of ``benchmarks/real_meshes/`` show and version 1
(:func:`animal_v1`) lacks (``experiments/transfer_causes.py``): their skins label the thighs and shoulders as
leg far up the body's side (49-79 % of its height; version 1's leg labels reach 26-40 %), their tails hang,
lie level or rise (about -80 to +70 degrees) and are longer, and their bodies are wider. Version 3
(:func:`animal_v3`) keeps version 2's tails and bodies without its thighs: the networks trained on version 2 lost
ground on both versions' test splits (``experiments/generator_v2.py``). The four labels stay body, head, leg, tail.
"""

from __future__ import annotations

import math

import numpy as np

from .shapes_common import DEG, pick
from .solids import Capsule, Ellipsoid, Solid, rotation_x

__all__ = ["animal_v1", "animal_v2", "animal_v3", "TAIL_POSES", "WIDE_SHARE"]

BODY, HEAD, LEG, TAIL = range(4)

#: Version 2's tail poses: (name, weight, range of the root-to-tip angle above the horizontal in degrees).
TAIL_POSES: tuple[tuple[str, float, tuple[float, float]], ...] = (
    ("hanging", 0.45, (-85.0, -45.0)), ("level", 0.35, (-40.0, 10.0)), ("raised", 0.2, (10.0, 75.0)))
#: Version 2: the share of bodies drawn 1.15-1.3 times wider.
WIDE_SHARE = 0.35


# -------------------------------------------------------------------------------------- animal
# Ellipsoid body; four legs of two capsules each (bent at the knee); neck capsule, head and snout
# ellipsoids, optional ears; tail of one or two capsules. Body plans: standard, long-neck, low-long,
# stocky. Version 2: a thick upper leg (thigh or shoulder) from the hip up the body's side, tails posed
# from hanging to raised and longer, wider bodies in part of the draws.

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


def animal_v1(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    """A four-legged animal: version 1 of the generator.

    Args:
        rng: the shape's random generator.

    Returns:
        ``(solids, structure, coarse)``: the solids (labels body 0, head 1, leg 2, tail 3), the structure string
        (e.g. ``"standard+long-tail+ears"``) and the coarse group, the body plan.
    """
    U = rng.uniform
    plan = pick(rng, tuple(_ANIMAL_PLANS), (1, 1, 1, 1))
    ry_r, rx_r, hip_r, lr_r = _ANIMAL_PLANS[plan][:4]
    long_tail = rng.random() < {"low-long": 0.8, "stocky": 0.2}.get(plan, 0.5)
    ears = rng.random() < 0.5
    rz, ry, rx = 0.5, U(*ry_r), U(*rx_r)
    hip_y = U(*hip_r)
    hb = hip_y + 0.4 * ry
    pitch = U(-5, 5) * DEG
    parts: list[Solid] = [Ellipsoid([0, hb, 0], rotation_x(pitch), [rx, ry, rz], BODY)]
    leg_r = U(*lr_r)
    _legs(rng, 0.55 * rx, 0.62 * rz, hip_y, leg_r, parts)
    _head(rng, plan, hb, ry, rz, ears, parts)

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


def animal_v2(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    """Version 2: the body plans of version 1 with thighs and shoulders labelled leg up the body's side (their
    labels reach about 45-70 % of the body's height), a posed tail (:data:`TAIL_POSES`, 0.18-0.7 body lengths) and, in
    :data:`WIDE_SHARE` of the draws, a wider body.

    Args:
        rng: the shape's random generator.

    Returns:
        ``(solids, structure, coarse)`` as :func:`animal_v1`; the structure names the tail's pose and a wide body,
        e.g. ``"stocky+hanging-tail+wide+ears"``.
    """
    return _posed_animal(rng, thighs=True)


def animal_v3(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    """Version 3: version 2 without the thighs. The legs are labelled as in version 1 (up to 26-40 % of the body's
    height); the posed tails and the wider bodies stay.

    Args:
        rng: the shape's random generator.

    Returns:
        ``(solids, structure, coarse)`` as :func:`animal_v2`.
    """
    return _posed_animal(rng, thighs=False)


def _posed_animal(rng: np.random.Generator, thighs: bool) -> tuple[list[Solid], str, str]:
    """Versions 2 and 3: a body plan of version 1, maybe wider, a posed tail, and with ``thighs`` the thighs."""
    U = rng.uniform
    plan = pick(rng, tuple(_ANIMAL_PLANS), (1, 1, 1, 1))
    ry_r, rx_r, hip_r, lr_r = _ANIMAL_PLANS[plan][:4]
    ears = rng.random() < 0.5
    pose = pick(rng, [p[0] for p in TAIL_POSES], [p[1] for p in TAIL_POSES])
    wide = rng.random() < WIDE_SHARE
    rz, ry, rx = 0.5, U(*ry_r), U(*rx_r) * (U(1.15, 1.3) if wide else 1.0)
    hip_y = U(*hip_r)
    hb = hip_y + 0.4 * ry
    parts: list[Solid] = [Ellipsoid([0, hb, 0], rotation_x(U(-5, 5) * DEG), [rx, ry, rz], BODY)]
    leg_r = U(*lr_r)
    hip_x, hip_z = U(0.5, 0.65) * rx, 0.62 * rz
    _legs(rng, hip_x, hip_z, hip_y, leg_r, parts)
    if thighs:
        _thighs(rng, (rx, ry, rz), hb, (hip_x, hip_y, hip_z), leg_r, parts)
    _head(rng, plan, hb, ry, rz, ears, parts)
    _posed_tail(rng, dict((p[0], p[2]) for p in TAIL_POSES)[pose], (ry, rz), hb, 0.1 * hip_y, parts)
    structure = plan + f"+{pose}-tail" + ("+wide" if wide else "") + ("+ears" if ears else "")
    return parts, structure, plan


def _legs(rng, hip_x: float, hip_z: float, hip_y: float, leg_r: float, parts: list) -> None:
    """Four legs of two capsules each, bent at the knee, from hips at (+-hip_x, hip_y, +-hip_z) to the floor."""
    U = rng.uniform
    for sz in (1, -1):  # front legs (+z), hind legs (-z)
        for sx in (-1, 1):
            hip = np.array([sx * hip_x, hip_y, sz * hip_z])
            knee = np.array([hip[0], hip_y * U(0.4, 0.6), hip[2] + sz * U(-0.06, 0.06)])
            foot = np.array([hip[0] * U(1.0, 1.15), 0.75 * leg_r, hip[2] + U(-0.04, 0.04)])
            parts.append(Capsule(hip, knee, leg_r, LEG))
            parts.append(Capsule(knee, foot, 0.75 * leg_r, LEG))


def _thighs(rng, radii, hb: float, hip, leg_r: float, parts: list) -> None:
    """Each leg's thigh or shoulder: a capsule labelled leg, 1.3-1.8 leg radii thick, from the hip up to the
    body's side at 38-62 % of the body's height (one height for the four; their labels then reach about 45-70 %), half of it outside the body."""
    U = rng.uniform
    rx, ry, rz = radii
    hip_x, hip_y, hip_z = hip
    top = hb - ry + 2 * ry * U(0.38, 0.62)
    r = min(U(1.3, 1.8) * leg_r, 0.5 * rx)
    side = rx * math.sqrt(max(0.0, 1 - (hip_z / rz) ** 2 - ((top - hb) / ry) ** 2))  # the body's side at that height
    for sz in (1, -1):
        for sx in (-1, 1):
            parts.append(Capsule([sx * hip_x, hip_y, sz * hip_z], [sx * side, top - 0.5 * r, sz * hip_z], r, LEG))


def _head(rng, plan: str, hb: float, ry: float, rz: float, ears: bool, parts: list) -> None:
    """The neck (labelled head), the head and snout ellipsoids and maybe two ears, on the body's front top."""
    U = rng.uniform
    nl_r, na_r, nr_r, head_r = _ANIMAL_PLANS[plan][4:]
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


def _posed_tail(rng, angles, radii, hb: float, floor: float, parts: list) -> None:
    """Two capsules from the body's rear top, 0.18-0.7 body lengths from root to tip, the root-to-tip direction
    ``angles`` (a range, degrees) above the horizontal, backwards: the first capsule at 0.75 of that angle, the second
    at 1.2 of it (a hanging tail falls more steeply towards its tip). A tail that would reach below ``floor`` is
    shortened about its root."""
    U = rng.uniform
    ry, rz = radii
    angle, length, tr = U(*angles) * DEG, U(0.18, 0.7) * 2 * rz, U(0.02, 0.04)
    t0 = np.array([0.0, hb + 0.35 * ry, -0.88 * rz])
    first = U(0.35, 0.5) * length
    ends = [t0]
    for a, piece in ((0.75 * angle, first), (float(np.clip(1.2 * angle, -88 * DEG, 85 * DEG)), length - first)):
        ends.append(ends[-1] + piece * np.array([0.0, math.sin(a), -math.cos(a)]))
    low = min(e[1] for e in ends) - tr
    if low < floor:
        f = (t0[1] - tr - floor) / (t0[1] - tr - low)
        ends = [t0 + f * (e - t0) for e in ends]
    parts.append(Capsule(ends[0], ends[1], tr, TAIL))
    parts.append(Capsule(ends[1], ends[2], 0.8 * tr, TAIL))
