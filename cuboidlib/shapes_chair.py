"""The procedural chairs of :mod:`cuboidlib.shapes`: back, seat, legs (four, a pedestal or sled runners), arms.
"""

from __future__ import annotations

import math

import numpy as np

from .shapes_common import DEG, frame_block, pick
from .solids import Capsule, Cylinder, RoundedBox, Solid, bar, box

__all__ = ["chair"]


# --------------------------------------------------------------------------------------- chair
# Seat box or rounded box; back solid or slatted (horizontal slats or vertical spindles), maybe tilted
# backwards; four legs (square or round, maybe splayed, maybe with stretchers), a pedestal on a star
# of 4 or 5 spokes (maybe with casters) or two sled runners; optional armrests with their supports.


def chair(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    BACK, SEAT, LEG, ARM = range(4)
    U = rng.uniform
    legs_type = pick(rng, ("legs4", "pedestal", "sled"), (0.5, 0.25, 0.25))
    arms = rng.random() < 0.4
    slatted = rng.random() < 0.4
    tilted = rng.random() < 0.5
    stretchers = legs_type == "legs4" and rng.random() < 0.4
    parts: list[Solid] = []

    W, D, T, H = U(0.40, 0.62), U(0.38, 0.60), U(0.03, 0.10), U(0.38, 0.52)
    seat_c = np.array([0.0, H - T / 2, 0.0])
    if rng.random() < 0.4:
        r = U(0.4, 0.95) * T / 2
        parts.append(RoundedBox(seat_c, np.eye(3), [W / 2 - r, T / 2 - r, D / 2 - r], r, SEAT))
    else:
        parts.append(box(seat_c, [W / 2, T / 2, D / 2], label=SEAT))

    _chair_back(rng, W, D, T, H, tilted, slatted, parts, BACK)
    top_y = H - T / 2
    if legs_type == "legs4":
        _chair_legs(rng, W, D, top_y, stretchers, parts, LEG)
    elif legs_type == "pedestal":
        _chair_pedestal(rng, top_y, parts, LEG)
    else:
        _chair_sled(rng, W, D, top_y, parts, LEG)
    if arms:
        _chair_arms(rng, W, D, H, top_y, parts, ARM)
    structure = legs_type + ("+stretchers" if stretchers else "") + ("+arms" if arms else "")
    structure += "+slatted-back" if slatted else "+solid-back"
    structure += "+tilted" if tilted else ""
    return parts, structure, legs_type + ("+arms" if arms else "")


def _chair_back(rng, W, D, T, H, tilted, slatted, parts, BACK) -> None:
    """The back: a frame pivoting about the seat's rear top edge, leaning backwards by tau; solid or slatted."""
    U = rng.uniform
    tau = U(6, 20) * DEG if tilted else 0.0
    Hb, Wb, Tb = U(0.30, 0.60), W * U(0.8, 1.0), U(0.025, 0.07)
    P = np.array([0.0, H, -D / 2 + U(0.0, 0.02)])
    axes = ([1.0, 0, 0], [0, math.cos(tau), -math.sin(tau)], [0, math.sin(tau), math.cos(tau)])
    below, top = 0.6 * T / math.cos(tau), Hb / math.cos(tau)
    if not slatted:
        parts.append(frame_block(P, axes, (-Wb / 2, Wb / 2), (-below, top), (0, Tb), BACK))
    else:
        ws, hr = U(0.03, 0.05), U(0.04, 0.10)
        for s in (-1, 1):
            parts.append(frame_block(P, axes, sorted((s * Wb / 2, s * (Wb / 2 - ws))), (-below, top), (0, Tb), BACK))
        inner = (-Wb / 2 + ws / 2, Wb / 2 - ws / 2)
        parts.append(frame_block(P, axes, inner, (top - hr, top), (0, Tb), BACK))
        if rng.random() < 0.5:  # horizontal slats
            k, hs = int(rng.integers(2, 5)), U(0.03, 0.06)
            for y in np.linspace(0.15 * top, top - hr - 0.05 - hs, k):
                parts.append(frame_block(P, axes, inner, (y, y + hs), (0.2 * Tb, 0.8 * Tb), BACK))
        else:  # vertical spindles from the seat into the top rail
            k, wsp = int(rng.integers(3, 7)), U(0.02, 0.035)
            for x in np.linspace(-Wb / 2 + ws, Wb / 2 - ws, k + 2)[1:-1]:
                parts.append(frame_block(P, axes, (x - wsp / 2, x + wsp / 2), (-below, top - hr / 2),
                                          (0.2 * Tb, 0.8 * Tb), BACK))


def _chair_legs(rng, W, D, top_y, stretchers, parts, LEG) -> None:
    """Four legs (maybe splayed) and maybe stretchers between them (a ring or an H)."""
    U = rng.uniform
    lw, round_legs = U(0.025, 0.05), rng.random() < 0.4
    inset = lw / 2 + U(0.005, 0.05)
    splay = U(2, 8) * DEG if rng.random() < 0.35 else 0.0
    out = top_y * math.tan(splay)
    tops, feet = [], []
    for sx, sz in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        a = np.array([sx * (W / 2 - inset), top_y, sz * (D / 2 - inset)])
        b = a + np.array([sx * out, -top_y, sz * out])
        tops.append(a)
        feet.append(b)
        parts.append(bar(a, b, lw, LEG, round_legs))
    if stretchers:
        hs, sw = U(0.08, 0.25), lw * U(0.5, 0.8)
        at = [f + (t - f) * hs / top_y for t, f in zip(tops, feet)]  # leg axes at height hs
        if rng.random() < 0.5:
            pairs = [(0, 1), (1, 2), (2, 3), (3, 0)]
            for i, j in pairs:
                parts.append(bar(at[i], at[j], sw, LEG, round_legs))
        else:  # H pattern: two side bars and a cross bar between their midpoints
            parts.append(bar(at[0], at[3], sw, LEG, round_legs))
            parts.append(bar(at[1], at[2], sw, LEG, round_legs))
            parts.append(bar((at[0] + at[3]) / 2, (at[1] + at[2]) / 2, sw, LEG, round_legs))


def _chair_pedestal(rng, top_y, parts, LEG) -> None:
    """An office-chair column on a star of 4 or 5 spokes, maybe with casters."""
    U = rng.uniform
    casters = rng.random() < 0.6
    rc, rw = U(0.02, 0.04), U(0.02, 0.03)
    base_y = U(0.06, 0.10) if casters else U(0.03, 0.05)
    spoke_w, n_spokes, Ls = U(0.025, 0.045), 5 if rng.random() < 0.8 else 4, U(0.22, 0.32)
    hub_r = max(rc * 1.6, spoke_w)
    parts.append(Cylinder.between([0, base_y - spoke_w, 0], [0, base_y + 0.04, 0], hub_r, LEG))
    parts.append(Cylinder.between([0, base_y, 0], [0, top_y, 0], rc, LEG))
    tip_y = 1.6 * rw if casters else spoke_w / 2
    phase = U(0, 2 * math.pi)
    for k in range(n_spokes):
        ang = phase + 2 * math.pi * k / n_spokes
        tip = np.array([Ls * math.sin(ang), tip_y, Ls * math.cos(ang)])
        parts.append(bar([0, base_y, 0], tip, spoke_w, LEG))
        if casters:
            parts.append(Capsule([tip[0], rw, tip[2]], [tip[0], rw, tip[2]], rw, LEG))


def _chair_sled(rng, W, D, top_y, parts, LEG) -> None:
    """Sled runners: a U-shaped tube on each side."""
    U = rng.uniform
    rt = U(0.008, 0.016)
    xs = W / 2 - rt - U(0.0, 0.04)
    zf, zb = D / 2 + U(-0.03, 0.06), -D / 2 - U(-0.03, 0.05)
    for s in (-1, 1):
        f, b = np.array([s * xs, rt, zf]), np.array([s * xs, rt, zb])
        parts.append(Capsule(b, f, rt, LEG))
        parts.append(Capsule(f, [s * xs, top_y, D / 2 - 0.05], rt, LEG))
        parts.append(Capsule(b, [s * xs, top_y, -D / 2 + 0.05], rt, LEG))


def _chair_arms(rng, W, D, H, top_y, parts, ARM) -> None:
    """Two arm rests, each on two supports."""
    U = rng.uniform
    ha, aw, at_ = U(0.15, 0.25), U(0.04, 0.07), U(0.02, 0.04)
    z_rear, z_front = -D / 2 + 0.01, D / 2 - U(0.0, 0.06)
    sup_w, round_sup = U(0.025, 0.04), rng.random() < 0.3
    for s in (-1, 1):
        xa = s * (W / 2 - aw / 2 - U(0.0, 0.02))
        parts.append(box([xa, H + ha, (z_rear + z_front) / 2], [aw / 2, at_ / 2, (z_front - z_rear) / 2], label=ARM))
        for z in (z_front - 0.03, z_rear + 0.03):
            parts.append(bar([xa, top_y, z], [xa, H + ha, z], min(sup_w, aw * 0.9), ARM, round_sup))
