"""The procedural airplanes of :mod:`cuboidlib.shapes`: fuselage, wings, tail and engines.
"""

from __future__ import annotations

import math

import numpy as np

from .shapes_common import DEG, pick, wing_corners
from .solids import Capsule, Cylinder, Ellipsoid, Hexahedron, Solid, box, rotation_z

__all__ = ["airplane"]


# ------------------------------------------------------------------------------------ airplane
# Fuselage capsule, or cylinder with an ellipsoidal nose and a tail cone; tapered swept wings (low,
# mid or high, with dihedral); stabiliser and fin (conventional or T-tail); 0, 2 or 4 engines
# (nacelle + pylon) under the wings, or 2 on the rear fuselage (always with a T-tail).


def _airplane_tail(rng, fin_te: float, rf: float, t_tail: bool, parts: list, TAIL: int) -> None:
    """The tail: a fin (span along +y, root inside the fuselage, trailing edge at z = fin_te) and a
    horizontal stabiliser, on top of the fin (T-tail) or at the fuselage."""
    U = rng.uniform
    cf, hf, fin_taper = U(0.10, 0.20), U(0.10, 0.22), U(0.4, 0.8)
    fin_sweep, tf = U(20, 50) * DEG, 0.1 * cf
    fin = wing_corners(fin_te + cf, cf, fin_taper, hf, fin_sweep, tf)[:, [1, 0, 2]]  # swap x <-> y
    parts.append(Hexahedron(fin, TAIL))
    cs, bs = U(0.08, 0.15), U(0.12, 0.25)
    if t_tail:
        tip_le = fin_te + cf - hf * math.tan(fin_sweep)
        tip_te = tip_le - fin_taper * cf
        margin = U(0.02, 0.05)
        ts = max(0.1 * cs, 0.012)
        parts.append(box([0, hf, (tip_le + tip_te) / 2], [bs, ts / 2, (tip_le - tip_te) / 2 + margin], label=TAIL))
    else:
        st_taper, st_sweep = U(0.4, 0.8), U(10, 40) * DEG
        st_le = fin_te + cs + U(0.0, 0.04)
        y_s = U(-0.3, 0.3) * rf
        halfs = wing_corners(st_le, cs, st_taper, bs, st_sweep, 0.1 * cs) @ rotation_z(U(0, 8) * DEG).T + [0, y_s, 0]
        parts.append(Hexahedron(halfs, TAIL))
        parts.append(Hexahedron(halfs * [-1, 1, 1], TAIL))


def airplane(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    BODY, WING, TAIL, ENGINE = range(4)
    U = rng.uniform
    L, rf = 1.0, U(0.035, 0.07)
    parts: list[Solid] = []

    # Fuselage along z (nose at +z). [z0, z1] is the straight section of radius rf; at most
    # `allow` behind z0 the body is still at least 0.78 rf thick (for tail roots).
    if rng.random() < 0.5:
        z0, z1 = -L / 2 + rf, L / 2 - rf
        parts.append(Capsule([0, 0, z0], [0, 0, z1], rf, BODY))
        allow = 0.6 * rf
    else:
        nose, tail = U(1.2, 3.0) * rf, U(2.5, 5.0) * rf
        z0, z1 = -L / 2 + tail, L / 2 - nose
        parts.append(Cylinder.between([0, 0, z0], [0, 0, z1], rf, BODY))
        parts.append(Ellipsoid([0, 0, z1], np.eye(3), [0.98 * rf, 0.98 * rf, nose], BODY))
        parts.append(Ellipsoid([0, 0, z0], np.eye(3), [0.98 * rf, 0.98 * rf, tail], BODY))
        allow = 0.5 * tail

    # Wings: two tapered swept halves whose root faces lie inside the fuselage.
    c_r, taper, b = U(0.12, 0.28), U(0.25, 0.8), U(0.35, 0.65)
    sweep, dihedral = U(0, 38) * DEG, U(-4, 7) * DEG
    t_r = U(0.08, 0.13) * c_r
    wing_pos = pick(rng, ("low", "mid", "high"), (0.4, 0.3, 0.3))
    y_room = 0.85 * rf - t_r / 2
    y_w = {"low": -1.0, "mid": 0.0, "high": 1.0}[wing_pos] * y_room * U(0.6, 1.0)
    z_le = float(np.clip(U(-0.05, 0.12) + c_r / 2, z0 + c_r + 0.01, z1 - 0.01))
    half = wing_corners(z_le, c_r, taper, b, sweep, t_r) @ rotation_z(dihedral).T + [0, y_w, 0]
    parts.append(Hexahedron(half, WING))
    parts.append(Hexahedron(half * [-1, 1, 1], WING))

    n_eng = int(pick(rng, ("0", "2", "4"), (0.3, 0.45, 0.25)))
    rear = n_eng == 2 and rng.random() < 0.3
    t_tail = rear or rng.random() < 0.3
    re, le = U(0.025, 0.045), U(0.12, 0.22)
    if n_eng and not rear:
        eta_min = (rf + re + 0.02) / b
        etas = [max(U(0.25, 0.4), eta_min)]
        if n_eng == 4:
            etas.append(max(U(0.55, 0.7), etas[0] + (2 * re + 0.03) / b))
        for eta in etas:
            xe = eta * b
            chord, thick = c_r * (1 - eta * (1 - taper)), t_r * (1 - eta * (1 - taper))
            le_z = z_le - xe * math.tan(sweep)
            wy = y_w + xe * math.sin(dihedral)
            cy = wy - thick / 2 - U(0.2, 0.6) * re - re
            z_front = le_z + U(0.3, 0.6) * le
            zp0 = max(z_front - le + 0.01, le_z - 0.6 * chord)
            zp1 = le_z - 0.1 * chord
            for s in (-1, 1):
                x = s * xe * math.cos(dihedral)
                parts.append(Cylinder.between([x, cy, z_front - le], [x, cy, z_front], re, ENGINE))
                parts.append(box([x, (cy + wy) / 2, (zp0 + zp1) / 2], [0.25 * re, (wy - cy) / 2, (zp1 - zp0) / 2],
                                 label=ENGINE))
    elif rear:
        xn, yn = rf + re * U(0.6, 1.2), rf * U(0.1, 0.5)
        zc = z0 + U(0.05, 0.12)
        for s in (-1, 1):
            parts.append(Cylinder.between([s * xn, yn, zc - le / 2], [s * xn, yn, zc + le / 2], re, ENGINE))
            zp = min(0.3 * le, zc - z0 - 0.01)
            parts.append(box([s * xn / 2, yn, zc], [xn / 2, 0.3 * re, zp], label=ENGINE))

    _airplane_tail(rng, z0 - allow, rf, t_tail, parts, TAIL)

    coarse = f"engines{n_eng}" + ("+t-tail" if t_tail else "")
    structure = f"engines{n_eng}" + ("-rear" if rear else "") + ("+t-tail" if t_tail else "") + f"+{wing_pos}-wing"
    return parts, structure, coarse
