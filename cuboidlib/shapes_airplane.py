"""The procedural airplanes of :mod:`cuboidlib.shapes`: fuselage, wings, tail and engines.

Version 1 (:func:`airplane_v1`) draws airliners, business jets and engineless gliders. Version 2
(:func:`airplane_v2`) adds what the real airplanes of ``benchmarks/real_meshes/`` show and version 1 lacks
(``experiments/transfer_causes.py``): a light-aircraft family in :data:`LIGHT_AIRCRAFT_SHARE` of the draws (a
thick short fuselage, a straight high or low wing, a nose propeller labelled engine, a fixed gear labelled
body), and a fixed gear on :data:`GEAR_SHARE` of the other airplanes. The four labels stay body, wing, tail,
engine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .shapes_common import DEG, pick, wing_corners
from .solids import Capsule, Cylinder, Ellipsoid, Hexahedron, Solid, bar, box, rotation_z

__all__ = ["airplane_v1", "airplane_v2", "LIGHT_AIRCRAFT_SHARE", "GEAR_SHARE"]

#: Version 2: the share of light aircraft (7 of the 27 real airplanes are single-engine propeller aircraft).
LIGHT_AIRCRAFT_SHARE = 0.25
#: Version 2: the share of the other airplanes drawn with a fixed gear down (7 real airplanes model wheels).
GEAR_SHARE = 0.25

BODY, WING, TAIL, ENGINE = range(4)


# ------------------------------------------------------------------------------------ airplane
# Fuselage capsule, or cylinder with an ellipsoidal nose and a tail cone; tapered swept wings (low,
# mid or high, with dihedral); stabiliser and fin (conventional or T-tail); 0, 2 or 4 engines
# (nacelle + pylon) under the wings, or 2 on the rear fuselage (always with a T-tail).
# Version 2 adds light aircraft (propeller on the nose, straight wing) and fixed tricycle gears.


@dataclass(frozen=True)
class _Fuselage:
    """Where a fixed gear goes: the fuselage (along z, nose at +z, axis at x = y = 0) and the wing root."""

    radius: float  # the straight section's radius
    front: float  # z where the straight section ends at the nose (the nose wheel goes no further forward)
    main_z: float  # z of the main wheels: under the wing root, behind its middle


def _airplane_tail(rng, fin_te: float, rf: float, t_tail: bool, parts: list) -> None:
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


def _airliner(rng: np.random.Generator) -> tuple[list[Solid], str, str, _Fuselage]:
    """Version 1's airplane (:func:`airplane_v1`), and where its gear would go."""
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

    _airplane_tail(rng, z0 - allow, rf, t_tail, parts)

    coarse = f"engines{n_eng}" + ("+t-tail" if t_tail else "")
    structure = f"engines{n_eng}" + ("-rear" if rear else "") + ("+t-tail" if t_tail else "") + f"+{wing_pos}-wing"
    return parts, structure, coarse, _Fuselage(rf, z1, z_le - 0.6 * c_r)


def airplane_v1(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    """An airliner, a business jet or an engineless glider: version 1 of the generator.

    Args:
        rng: the shape's random generator.

    Returns:
        ``(solids, structure, coarse)``: the solids (labels body 0, wing 1, tail 2, engine 3), the structure
        string (e.g. ``"engines2-rear+t-tail+low-wing"``) and the coarse group (e.g. ``"engines2+t-tail"``).
    """
    return _airliner(rng)[:3]


def airplane_v2(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    """Version 2: a light aircraft in :data:`LIGHT_AIRCRAFT_SHARE` of the draws, else version 1's airplane
    with a fixed gear in :data:`GEAR_SHARE` of them (structure ``"+gear"``).

    Args:
        rng: the shape's random generator.

    Returns:
        ``(solids, structure, coarse)`` as :func:`airplane_v1`; a light aircraft's coarse group is
        ``"propeller"``.
    """
    if rng.random() < LIGHT_AIRCRAFT_SHARE:
        return _light_aircraft(rng)
    parts, structure, coarse, fuselage = _airliner(rng)
    if rng.random() < GEAR_SHARE:
        _landing_gear(rng, fuselage, 0.0, parts)
        structure += "+gear"
    return parts, structure, coarse


def _light_aircraft(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    """A single-engine propeller aircraft: a fuselage 0.18-0.30 as thick as it is long that tapers to the tail, a
    straight wing high or low, a spinner and two or three blades (or a disc) on the nose labelled engine, a
    conventional tail or (15 %) a T-tail, a fixed tricycle gear (85 %) labelled body."""
    U = rng.uniform
    rf, nose, tail = U(0.09, 0.15), U(0.8, 1.5), U(0.35, 0.5)
    nose *= rf
    z0, z1 = -0.5 + tail, 0.5 - nose
    parts: list[Solid] = [Cylinder.between([0, 0, z0], [0, 0, z1], rf, BODY),
                          Ellipsoid([0, 0, z1], np.eye(3), [0.98 * rf, 0.98 * rf, nose], BODY),
                          Ellipsoid([0, 0, z0], np.eye(3), [0.98 * rf, 0.98 * rf, tail], BODY)]
    high = rng.random() < 0.55
    c_r, taper, b = U(0.13, 0.2), U(0.6, 1.0), U(0.5, 0.75)
    t_r, sweep = U(0.10, 0.15) * c_r, U(0, 4) * DEG
    dihedral = (U(0, 2) if high else U(3, 7)) * DEG
    y_w = (1.0 if high else -1.0) * (0.85 * rf - t_r / 2) * U(0.85, 1.0)
    z_le = max(z1 - U(0.02, 0.12), z0 + c_r + 0.01)
    half = wing_corners(z_le, c_r, taper, b, sweep, t_r) @ rotation_z(dihedral).T + [0, y_w, 0]
    parts += [Hexahedron(half, WING), Hexahedron(half * [-1, 1, 1], WING)]
    blade_r, propeller = _propeller(rng, rf, parts)
    t_tail = rng.random() < 0.15
    _airplane_tail(rng, z0 - 0.7 * tail, 0.7 * rf, t_tail, parts)
    gear = rng.random() < 0.85
    if gear:
        _landing_gear(rng, _Fuselage(rf, z1, z_le - 0.6 * c_r), -blade_r - 0.01, parts)
    structure = (f"propeller+{propeller}+{'high' if high else 'low'}-wing" + ("+gear" if gear else "")
                 + ("+t-tail" if t_tail else ""))
    return parts, structure, "propeller"


def _propeller(rng, rf: float, parts: list) -> tuple[float, str]:
    """A spinner on the nose tip (z = 0.5) and two blades, three blades or (20 %) a thin disc, labelled engine.

    Returns:
        The blade radius and the kind ("2-blade", "3-blade" or "disc").
    """
    U = rng.uniform
    hub = np.array([0.0, 0.0, 0.5])
    spinner = U(0.3, 0.45) * rf
    parts.append(Ellipsoid(hub, np.eye(3), [spinner, spinner, U(1.0, 1.6) * spinner], ENGINE))
    blade_r, width, depth = U(0.09, 0.14), U(0.012, 0.02), U(0.004, 0.008)
    front = hub + [0, 0, 0.5 * spinner]
    kind = pick(rng, ("2-blade", "3-blade", "disc"), (0.5, 0.3, 0.2))
    phase = U(0, math.pi)
    if kind == "disc":
        parts.append(Cylinder.between(front - [0, 0, depth / 2], front + [0, 0, depth / 2], blade_r, ENGINE))
    elif kind == "2-blade":  # one blade through the hub
        parts.append(box(front, [width / 2, blade_r, depth / 2], rotation_z(phase), ENGINE))
    else:  # three blades from the hub
        for k in range(3):
            r = rotation_z(phase + 2 * math.pi * k / 3)
            parts.append(box(front + r @ [0, blade_r / 2, 0], [width / 2, blade_r / 2, depth / 2], r, ENGINE))
    return blade_r, kind


def _landing_gear(rng, fuselage: _Fuselage, lowest: float, parts: list) -> None:
    """A fixed tricycle gear labelled body, as the real meshes label it: a nose wheel under the front of the
    straight section and two main wheels under the wing root, each wheel (a disc across x) on a strut from inside
    the fuselage. The wheels reach down to ``lowest`` at least (y; below a propeller's tips)."""
    U = rng.uniform
    rf = fuselage.radius
    wheel_r, width = U(0.25, 0.4) * rf, U(0.3, 0.5) * rf
    hub_y = min(-rf - U(0.4, 1.0) * rf, lowest + wheel_r)
    spread = U(1.0, 1.8) * rf
    for x, z in ((0.0, fuselage.front - U(0.0, 0.05)), (-spread, fuselage.main_z), (spread, fuselage.main_z)):
        hub = np.array([x, hub_y, z])
        parts.append(bar([0.5 * x, -0.5 * rf, z], hub, 0.5 * wheel_r, BODY, round_section=True))
        parts.append(Cylinder.between(hub - [width / 2, 0, 0], hub + [width / 2, 0, 0], wheel_r, BODY))
