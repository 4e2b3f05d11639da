"""The procedural tables of :mod:`cuboidlib.shapes`: a top on four legs, a pedestal or trestle ends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .shapes_common import DEG, pick
from .solids import Cylinder, RoundedBox, Solid, bar, box, frame_from_axis

__all__ = ["table"]


# --------------------------------------------------------------------------------------- table
# Rectangular (box or rounded) or round top; four legs, a pedestal (disc or cross-foot base) or
# trestle ends (post + foot + cleat); optional shelf, stretchers, apron boards or trestle stretcher.


def table(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    TOP, LEG = range(2)
    U = rng.uniform
    round_top = rng.random() < 0.4
    support = pick(rng, ("legs4", "pedestal"), (0.4, 0.6)) if round_top else pick(
        rng, ("legs4", "pedestal", "trestle"), (0.5, 0.2, 0.3))
    H, T = U(0.42, 0.78), U(0.025, 0.07)
    parts: list[Solid] = []
    extras: list[str] = []
    up = frame_from_axis([0.0, 1.0, 0.0])

    if round_top:
        R = U(0.35, 0.65)
        parts.append(Cylinder([0, H - T / 2, 0], up, R, T / 2, TOP))
        W = D = 2 * R
        reach = R  # distance from the centre to the edge, for supports
    else:
        W = U(0.8, 1.2) if support == "pedestal" else U(0.8, 1.8)
        D = U(0.5, min(1.0, W))
        if rng.random() < 0.3:
            r = U(0.4, 0.95) * T / 2
            parts.append(RoundedBox([0, H - T / 2, 0], np.eye(3), [W / 2 - r, T / 2 - r, D / 2 - r], r, TOP))
        else:
            parts.append(box([0, H - T / 2, 0], [W / 2, T / 2, D / 2], label=TOP))
        reach = min(W, D) / 2
    top = _TableTop(H, T, W, D, reach, round_top, up)
    if support == "legs4":
        _table_legs(rng, top, parts, extras, LEG)
    elif support == "pedestal":
        _table_pedestal(rng, top, parts, extras, LEG)
    else:
        _table_trestle(rng, top, parts, extras, LEG)
    coarse = "trestle" if support == "trestle" else f"{support}-{'round' if round_top else 'rect'}"
    structure = coarse + "".join("+" + e for e in extras)
    return parts, structure, coarse


@dataclass(frozen=True)
class _TableTop:
    """The sizes of a table top that its supports are built from (a round top has W = D = 2R)."""

    H: float  # height of the top surface
    T: float  # thickness
    W: float  # width (x)
    D: float  # depth (z)
    reach: float  # distance from the centre to the nearest edge
    round: bool
    up: np.ndarray  # frame with +y as the axis, for vertical cylinders

    @property
    def y(self) -> float:  # height of the top's mid-plane
        return self.H - self.T / 2


def _table_legs(rng, top: _TableTop, parts: list, extras: list, LEG: int) -> None:
    """Four legs (maybe splayed), then a shelf or stretchers, and on rectangular tops maybe an apron."""
    U, top_y = rng.uniform, top.y
    lw, round_legs = U(0.03, 0.08), rng.random() < 0.4
    splay = U(2, 7) * DEG if rng.random() < 0.25 else 0.0
    out = top_y * math.tan(splay)
    if top.round:
        rl = top.W / 2 * U(0.45, 0.7)
        phase = 45 * DEG
        corners = [(rl * math.cos(phase + k * math.pi / 2), rl * math.sin(phase + k * math.pi / 2)) for k in range(4)]
    else:
        inset = lw / 2 + U(0.01, 0.12)
        corners = [(sx * (top.W / 2 - inset), sz * (top.D / 2 - inset))
                   for sx, sz in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    tops, feet = [], []
    for cx, cz in corners:
        a = np.array([cx, top_y, cz])
        d = np.array([cx, 0.0, cz]) / math.hypot(cx, cz)
        b = np.array([cx, 0.0, cz]) + out * d
        tops.append(a)
        feet.append(b)
        parts.append(bar(a, b, lw, LEG, round_legs))
    extra = pick(rng, ("none", "shelf", "stretchers"), (0.4, 0.3, 0.3))
    hs = U(0.1, 0.3) * top.H
    at = [f + (t - f) * hs / top_y for t, f in zip(tops, feet)]
    if extra == "shelf":
        extras.append("shelf")
        ts = U(0.015, 0.03)
        if top.round:
            rs = float(np.linalg.norm(at[0][[0, 2]]))
            parts.append(Cylinder([0, hs, 0], top.up, rs, ts / 2, LEG))
        else:
            hx, hz = abs(at[0][0]), abs(at[0][2])
            parts.append(box([0, hs, 0], [hx, ts / 2, hz], label=LEG))
    elif extra == "stretchers":
        extras.append("stretchers")
        sw = lw * U(0.4, 0.7)
        if rng.random() < 0.5:
            for i in range(4):
                parts.append(bar(at[i], at[(i + 1) % 4], sw, LEG, round_legs))
        else:  # crossing diagonals
            parts.append(bar(at[0], at[2], sw, LEG, round_legs))
            parts.append(bar(at[1], at[3], sw, LEG, round_legs))
    if not top.round and rng.random() < 0.4:
        extras.append("apron")
        ah, th = U(0.05, 0.12), min(U(0.015, 0.03), lw * 0.8)
        yc, hh = top_y - (ah + top.T / 2) / 2, (ah + top.T / 2) / 2
        for i in range(4):
            a, b = tops[i], tops[(i + 1) % 4]
            mid = (a + b) / 2
            length = float(np.linalg.norm((b - a)[[0, 2]]))
            along = abs(b[0] - a[0]) > abs(b[2] - a[2])
            half = [length / 2, hh, th / 2] if along else [th / 2, hh, length / 2]
            parts.append(box([mid[0], yc, mid[2]], half, label=LEG))


def _table_pedestal(rng, top: _TableTop, parts: list, extras: list, LEG: int) -> None:
    """A central column on a disc base or on a four-footed cross base."""
    U = rng.uniform
    rc = U(0.04, 0.10)
    bt = U(0.02, 0.05)
    parts.append(Cylinder.between([0, bt / 2, 0], [0, top.y, 0], rc, LEG))
    base_r = max(top.reach * U(0.45, 0.75), rc * 2.2)
    if rng.random() < 0.5:
        extras.append("disc-base")
        parts.append(Cylinder([0, bt / 2, 0], top.up, base_r, bt / 2, LEG))
    else:
        extras.append("cross-base")
        fh, fw = U(0.03, 0.06), U(0.04, min(0.08, 1.6 * rc))
        phase = 0.0 if top.round else 45 * DEG * rng.integers(0, 2)
        for k in range(4):
            ang = phase + k * math.pi / 2
            tip = np.array([base_r * math.cos(ang), fh / 2, base_r * math.sin(ang)])
            parts.append(bar([0, fh / 2, 0], tip, fw, LEG))
        parts.append(Cylinder.between([0, 0, 0], [0, fh * 1.2, 0], rc * 1.3, LEG))


def _table_trestle(rng, top: _TableTop, parts: list, extras: list, LEG: int) -> None:
    """Trestle ends: post + foot (+ cleat under the top), optional stretcher between the posts."""
    U, top_y, H, T = rng.uniform, top.y, top.H, top.T
    inset, pw, pd = U(0.05, 0.2), U(0.04, 0.10), U(0.06, 0.25)
    fh, pf, fl = U(0.04, 0.08), pw * U(1.1, 1.6), top.D * U(0.6, 0.95)
    cleat = rng.random() < 0.6
    xe = top.W / 2 - inset
    for s in (-1, 1):
        parts.append(box([s * xe, (fh / 2 + top_y) / 2, 0], [pw / 2, (top_y - fh / 2) / 2, pd / 2], label=LEG))
        parts.append(box([s * xe, fh / 2, 0], [pf / 2, fh / 2, fl / 2], label=LEG))
        if cleat:
            ch = U(0.03, 0.05)
            parts.append(box([s * xe, H - T - ch / 2 + T / 4, 0], [pf / 2, ch / 2 + T / 4, fl * 0.45], label=LEG))
    if cleat:
        extras.append("cleats")
    if rng.random() < 0.6:
        extras.append("stretcher")
        sh, ss = U(0.15, 0.5) * H, U(0.03, min(0.06, pd * 0.9))
        parts.append(box([0, sh, 0], [xe, ss / 2, ss / 2], label=LEG))
