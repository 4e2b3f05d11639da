"""Procedural, part-labelled shape collections that stand in for the paper's data (Sec. 4).

The paper uses ShapeNet chairs, tables and airplanes and a set of four-legged animals, scored against
part labels (Sec. 4.2). Nothing can be downloaded here, so :func:`make_collection` builds look-alikes:
each shape is a union of analytic solids (:mod:`cuboidlib.solids`) sampled area-uniformly on its outer
surface, with an outward normal and a part label (``PART_NAMES``) per point. Each shape also records
its optional parts (``structure``) and a coarse group for clustering (``structure_id``, an index into
``STRUCTURES``). Shapes are normalised as in :mod:`cuboidlib.normalization`. Shape i of a collection
comes from a generator seeded with (seed, category, i), so a prefix of a larger collection equals the
smaller one; collections are cached as npz, keyed by their arguments and :data:`GENERATOR_VERSION`.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import trimesh

from ._checks import MAX_COLLECTION_POINTS, MAX_SHAPE_POINTS, MAX_SHAPES, check_size
from .normalization import normalize
from .solids import (
    Capsule,
    Cylinder,
    Ellipsoid,
    Hexahedron,
    RoundedBox,
    Solid,
    bar,
    box,
    frame_from_axis,
    rotation_x,
    rotation_z,
    sample_union_surface,
)

__all__ = [
    "CATEGORIES",
    "PART_NAMES",
    "STRUCTURES",
    "GENERATOR_VERSION",
    "PART_COLORS",
    "Shape",
    "ShapeCollection",
    "build_parts",
    "make_shape",
    "make_collection",
    "default_cache_dir",
    "plot_shapes",
]

CATEGORIES: tuple[str, ...] = ("chair", "table", "airplane", "animal")

# Part labels index these tuples. As in the paper (Sec. 4.2, after BSP-Net) every table support is
# "leg"; an animal's neck is labelled "head".
PART_NAMES: dict[str, tuple[str, ...]] = {
    "chair": ("back", "seat", "leg", "arm"),
    "table": ("top", "leg"),
    "airplane": ("body", "wing", "tail", "engine"),
    "animal": ("body", "head", "leg", "tail"),
}

# Coarse groups for clustering: chair legs type x armrests, table support x top shape (and trestle),
# airplane engine count x T-tail, animal body plan. Every group gets at least ~7 % of a collection.
STRUCTURES: dict[str, tuple[str, ...]] = {
    "chair": ("legs4", "legs4+arms", "pedestal", "pedestal+arms", "sled", "sled+arms"),
    "table": ("legs4-rect", "legs4-round", "pedestal-rect", "pedestal-round", "trestle"),
    "airplane": ("engines0", "engines0+t-tail", "engines2", "engines2+t-tail", "engines4", "engines4+t-tail"),
    "animal": ("standard", "long-neck", "low-long", "stocky"),
}

#: Bumped whenever generated shapes change, so stale cache files are never reused.
GENERATOR_VERSION = 1

#: RGB colours of part labels 0, 1, 2, 3 in figures (and in exported sample meshes).
PART_COLORS: tuple[tuple[float, float, float], ...] = (
    (0.122, 0.467, 0.706),
    (1.000, 0.498, 0.055),
    (0.173, 0.627, 0.173),
    (0.839, 0.153, 0.157),
)

_DEG = math.pi / 180


def _pick(rng: np.random.Generator, options: Sequence[str], probs: Sequence[float]) -> str:
    return options[int(np.searchsorted(np.cumsum(probs), rng.random() * sum(probs), side="right"))]


def _frame_block(origin, axes, x, a, b, label: int) -> Hexahedron:
    """A hexahedron spanning ranges ``x``, ``a``, ``b`` along the three ``axes`` from ``origin``."""
    ex, eu, ev = (np.asarray(v, dtype=float) for v in axes)
    corners = [
        origin + x[i & 1] * ex + a[(i >> 1) & 1] * eu + b[(i >> 2) & 1] * ev for i in range(8)
    ]
    return Hexahedron(np.array(corners), label)


def _wing(root_le_z: float, chord: float, taper: float, span: float, sweep: float, thickness: float) -> np.ndarray:
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


# --------------------------------------------------------------------------------------- chair
# Seat box or rounded box; back solid or slatted (horizontal slats or vertical spindles), maybe tilted
# backwards; four legs (square or round, maybe splayed, maybe with stretchers), a pedestal on a star
# of 4 or 5 spokes (maybe with casters) or two sled runners; optional armrests with their supports.


def _chair(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    BACK, SEAT, LEG, ARM = range(4)
    U = rng.uniform
    legs_type = _pick(rng, ("legs4", "pedestal", "sled"), (0.5, 0.25, 0.25))
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
    tau = U(6, 20) * _DEG if tilted else 0.0
    Hb, Wb, Tb = U(0.30, 0.60), W * U(0.8, 1.0), U(0.025, 0.07)
    P = np.array([0.0, H, -D / 2 + U(0.0, 0.02)])
    axes = ([1.0, 0, 0], [0, math.cos(tau), -math.sin(tau)], [0, math.sin(tau), math.cos(tau)])
    below, top = 0.6 * T / math.cos(tau), Hb / math.cos(tau)
    if not slatted:
        parts.append(_frame_block(P, axes, (-Wb / 2, Wb / 2), (-below, top), (0, Tb), BACK))
    else:
        ws, hr = U(0.03, 0.05), U(0.04, 0.10)
        for s in (-1, 1):
            parts.append(_frame_block(P, axes, sorted((s * Wb / 2, s * (Wb / 2 - ws))), (-below, top), (0, Tb), BACK))
        inner = (-Wb / 2 + ws / 2, Wb / 2 - ws / 2)
        parts.append(_frame_block(P, axes, inner, (top - hr, top), (0, Tb), BACK))
        if rng.random() < 0.5:  # horizontal slats
            k, hs = int(rng.integers(2, 5)), U(0.03, 0.06)
            for y in np.linspace(0.15 * top, top - hr - 0.05 - hs, k):
                parts.append(_frame_block(P, axes, inner, (y, y + hs), (0.2 * Tb, 0.8 * Tb), BACK))
        else:  # vertical spindles from the seat into the top rail
            k, wsp = int(rng.integers(3, 7)), U(0.02, 0.035)
            for x in np.linspace(-Wb / 2 + ws, Wb / 2 - ws, k + 2)[1:-1]:
                parts.append(_frame_block(P, axes, (x - wsp / 2, x + wsp / 2), (-below, top - hr / 2),
                                          (0.2 * Tb, 0.8 * Tb), BACK))


def _chair_legs(rng, W, D, top_y, stretchers, parts, LEG) -> None:
    """Four legs (maybe splayed) and maybe stretchers between them (a ring or an H)."""
    U = rng.uniform
    lw, round_legs = U(0.025, 0.05), rng.random() < 0.4
    inset = lw / 2 + U(0.005, 0.05)
    splay = U(2, 8) * _DEG if rng.random() < 0.35 else 0.0
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


# --------------------------------------------------------------------------------------- table
# Rectangular (box or rounded) or round top; four legs, a pedestal (disc or cross-foot base) or
# trestle ends (post + foot + cleat); optional shelf, stretchers, apron boards or trestle stretcher.


def _table(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    TOP, LEG = range(2)
    U = rng.uniform
    round_top = rng.random() < 0.4
    support = _pick(rng, ("legs4", "pedestal"), (0.4, 0.6)) if round_top else _pick(
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
    splay = U(2, 7) * _DEG if rng.random() < 0.25 else 0.0
    out = top_y * math.tan(splay)
    if top.round:
        rl = top.W / 2 * U(0.45, 0.7)
        phase = 45 * _DEG
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
    extra = _pick(rng, ("none", "shelf", "stretchers"), (0.4, 0.3, 0.3))
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
        phase = 0.0 if top.round else 45 * _DEG * rng.integers(0, 2)
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


# ------------------------------------------------------------------------------------ airplane
# Fuselage capsule, or cylinder with an ellipsoidal nose and a tail cone; tapered swept wings (low,
# mid or high, with dihedral); stabiliser and fin (conventional or T-tail); 0, 2 or 4 engines
# (nacelle + pylon) under the wings, or 2 on the rear fuselage (always with a T-tail).


def _airplane_tail(rng, fin_te: float, rf: float, t_tail: bool, parts: list, TAIL: int) -> None:
    """The tail: a fin (span along +y, root inside the fuselage, trailing edge at z = fin_te) and a
    horizontal stabiliser, on top of the fin (T-tail) or at the fuselage."""
    U = rng.uniform
    cf, hf, fin_taper = U(0.10, 0.20), U(0.10, 0.22), U(0.4, 0.8)
    fin_sweep, tf = U(20, 50) * _DEG, 0.1 * cf
    fin = _wing(fin_te + cf, cf, fin_taper, hf, fin_sweep, tf)[:, [1, 0, 2]]  # swap x <-> y
    parts.append(Hexahedron(fin, TAIL))
    cs, bs = U(0.08, 0.15), U(0.12, 0.25)
    if t_tail:
        tip_le = fin_te + cf - hf * math.tan(fin_sweep)
        tip_te = tip_le - fin_taper * cf
        margin = U(0.02, 0.05)
        ts = max(0.1 * cs, 0.012)
        parts.append(box([0, hf, (tip_le + tip_te) / 2], [bs, ts / 2, (tip_le - tip_te) / 2 + margin], label=TAIL))
    else:
        st_taper, st_sweep = U(0.4, 0.8), U(10, 40) * _DEG
        st_le = fin_te + cs + U(0.0, 0.04)
        y_s = U(-0.3, 0.3) * rf
        halfs = _wing(st_le, cs, st_taper, bs, st_sweep, 0.1 * cs) @ rotation_z(U(0, 8) * _DEG).T + [0, y_s, 0]
        parts.append(Hexahedron(halfs, TAIL))
        parts.append(Hexahedron(halfs * [-1, 1, 1], TAIL))


def _airplane(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
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
    sweep, dihedral = U(0, 38) * _DEG, U(-4, 7) * _DEG
    t_r = U(0.08, 0.13) * c_r
    wing_pos = _pick(rng, ("low", "mid", "high"), (0.4, 0.3, 0.3))
    y_room = 0.85 * rf - t_r / 2
    y_w = {"low": -1.0, "mid": 0.0, "high": 1.0}[wing_pos] * y_room * U(0.6, 1.0)
    z_le = float(np.clip(U(-0.05, 0.12) + c_r / 2, z0 + c_r + 0.01, z1 - 0.01))
    half = _wing(z_le, c_r, taper, b, sweep, t_r) @ rotation_z(dihedral).T + [0, y_w, 0]
    parts.append(Hexahedron(half, WING))
    parts.append(Hexahedron(half * [-1, 1, 1], WING))

    n_eng = int(_pick(rng, ("0", "2", "4"), (0.3, 0.45, 0.25)))
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


def _animal(rng: np.random.Generator) -> tuple[list[Solid], str, str]:
    BODY, HEAD, LEG, TAIL = range(4)
    U = rng.uniform
    plan = _pick(rng, tuple(_ANIMAL_PLANS), (1, 1, 1, 1))
    ry_r, rx_r, hip_r, lr_r, nl_r, na_r, nr_r, head_r = _ANIMAL_PLANS[plan]
    long_tail = rng.random() < {"low-long": 0.8, "stocky": 0.2}.get(plan, 0.5)
    ears = rng.random() < 0.5
    rz, ry, rx = 0.5, U(*ry_r), U(*rx_r)
    hip_y = U(*hip_r)
    hb = hip_y + 0.4 * ry
    pitch = U(-5, 5) * _DEG
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
    ang = U(*na_r) * _DEG
    base = np.array([0.0, hb + 0.45 * ry, 0.75 * rz])
    end = base + U(*nl_r) * np.array([0.0, math.sin(ang), math.cos(ang)])
    parts.append(Capsule(base, end, U(*nr_r), HEAD))
    hr = np.array([U(*r) for r in head_r])
    head_rot = rotation_x(U(0, 25) * _DEG)
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
        b1 = U(10, 50) * _DEG
        t1 = t0 + U(0.2, 0.35) * np.array([0, -math.sin(b1), -math.cos(b1)])
        b2 = b1 + U(10, 40) * _DEG
        t2 = t1 + U(0.15, 0.3) * np.array([0, -math.sin(b2), -math.cos(b2)])
        t1[1], t2[1] = max(t1[1], tr + 0.2 * hip_y), max(t2[1], 0.8 * tr + 0.15 * hip_y)  # clear of the floor
        parts.append(Capsule(t0, t1, tr, TAIL))
        parts.append(Capsule(t1, t2, 0.8 * tr, TAIL))
    else:
        b1 = -U(10, 40) * _DEG
        parts.append(Capsule(t0, t0 + U(0.06, 0.15) * np.array([0, -math.sin(b1), -math.cos(b1)]),
                             U(0.025, 0.045), TAIL))

    structure = plan + ("+long-tail" if long_tail else "+short-tail") + ("+ears" if ears else "")
    return parts, structure, plan


_GENERATORS: dict[str, Callable[[np.random.Generator], tuple[list[Solid], str, str]]] = {
    "chair": _chair,
    "table": _table,
    "airplane": _airplane,
    "animal": _animal,
}


# ------------------------------------------------------------------------------- public API


def _check_category(category: str) -> str:
    if category not in PART_NAMES:
        raise ValueError(f"category must be one of {CATEGORIES}, got {category!r}")
    return category


def _shape_rng(category: str, index: int, seed: int) -> np.random.Generator:
    if seed < 0 or index < 0:
        raise ValueError(f"seed and index must be non-negative integers, got seed={seed}, index={index}")
    return np.random.default_rng([int(seed), CATEGORIES.index(category), int(index)])


def build_parts(category: str, index: int, seed: int = 0) -> tuple[list[Solid], str, int]:
    """The parts of shape ``index`` of a collection, before sampling and normalisation.

    Args:
        category: one of :data:`CATEGORIES`.
        index: the shape's index in the collection, >= 0.
        seed: the collection's seed, >= 0.

    Returns:
        ``(solids, structure, structure_id)``: the solids in generator units (metres), each labelled
        with an index into ``PART_NAMES[category]``; the structure string, e.g.
        ``"legs4+stretchers+arms+slatted-back+tilted"``; the coarse group, an index into
        ``STRUCTURES[category]``.
    """
    _check_category(category)
    solids, structure, coarse = _GENERATORS[category](_shape_rng(category, index, seed))
    return solids, structure, STRUCTURES[category].index(coarse)


@dataclass
class Shape:
    """One procedural shape, normalised (see :mod:`cuboidlib.normalization`).

    Attributes:
        category: one of :data:`CATEGORIES`.
        points: (N, 3) float32 surface points.
        normals: (N, 3) float32 outward unit normals.
        labels: (N,) int64 part labels, indices into ``PART_NAMES[category]``.
        structure: string of the optional parts, e.g. ``"pedestal+arms+solid-back"``.
        structure_id: coarse structure, an index into ``STRUCTURES[category]``.
        parts: the analytic solids in normalised coordinates (their union is the shape).
        instances: (N,) int64 the part instance of each point: the index into ``parts`` of the solid it was
            sampled on (a leg, one slat of a back). ``labels == [parts[i].label for i in instances]``.
    """

    category: str
    points: np.ndarray
    normals: np.ndarray
    labels: np.ndarray
    structure: str
    structure_id: int
    parts: list[Solid] = field(repr=False)
    instances: np.ndarray | None = None

    @property
    def part_names(self) -> tuple[str, ...]:
        """The names of the part labels, ``PART_NAMES[category]``."""
        return PART_NAMES[self.category]

    def mesh(self) -> trimesh.Trimesh:
        """The parts' meshes concatenated (not boolean-merged), vertices coloured by part label.

        Returns:
            A ``trimesh.Trimesh`` whose face attribute ``label`` holds each face's part label. (Vertex
            colours, because trimesh exports them without scipy.)
        """
        meshes = [p.mesh() for p in self.parts]
        mesh = trimesh.util.concatenate(meshes)
        vertex_labels = np.concatenate([np.full(len(m.vertices), p.label) for p, m in zip(self.parts, meshes)])
        rgb = np.round(np.array(PART_COLORS)[vertex_labels] * 255).astype(np.uint8)
        mesh.visual.vertex_colors = np.concatenate([rgb, np.full((len(rgb), 1), 255, np.uint8)], axis=1)
        face_labels = np.concatenate([np.full(len(m.faces), p.label) for p, m in zip(self.parts, meshes)])
        mesh.face_attributes["label"] = face_labels.astype(np.int32)
        return mesh


def _sample_shape(category: str, index: int, seed: int, n_points: int):
    solids, structure, sid = build_parts(category, index, seed)
    rng = np.random.default_rng([int(seed), CATEGORIES.index(category), int(index), 1])  # sampling stream
    p, nn, idx = sample_union_surface(solids, n_points, rng)
    labels = np.array([s.label for s in solids])[idx]
    p, center, scale = normalize(p)
    return solids, structure, sid, p, nn, labels, idx, center, scale


def make_shape(category: str, index: int = 0, n_points: int = 2048, seed: int = 0) -> Shape:
    """Generate shape ``index`` of the collection ``(category, seed)``, with its analytic parts.

    Args:
        category: one of :data:`CATEGORIES`.
        index: the shape's index in the collection.
        n_points: N, points sampled on its surface.
        seed: the collection's seed.

    Returns:
        A :class:`Shape` equal to entry ``index`` of ``make_collection(category, n, n_points, seed)``
        for any ``n > index``, plus its parts (for meshes and exact inside/outside tests).
    """
    _check_category(category)
    n_points = check_size(n_points, "n_points", MAX_SHAPE_POINTS)
    solids, structure, sid, p, nn, labels, instances, center, scale = _sample_shape(category, index, seed, n_points)
    return Shape(
        category=category,
        points=p.astype(np.float32),
        normals=nn.astype(np.float32),
        labels=labels.astype(np.int64),
        structure=structure,
        structure_id=sid,
        parts=[s.mapped(center, scale) for s in solids],
        instances=np.asarray(instances, dtype=np.int64),
    )


@dataclass
class ShapeCollection:
    """A collection of procedural shapes of one category, as stacked arrays.

    Attributes:
        category: one of :data:`CATEGORIES`.
        points: (S, N, 3) float32, each shape normalised.
        normals: (S, N, 3) float32 outward unit normals.
        labels: (S, N) int64 part labels (indices into ``PART_NAMES[category]``).
        structures: (S,) structure strings.
        structure_ids: (S,) int64 coarse structures (indices into ``STRUCTURES[category]``).
        seed: the collection's seed.
        instances: (S, N) int64 part instances (each point's solid, as in :attr:`Shape.instances`), or None
            for a collection file written without them.
    """

    category: str
    points: np.ndarray
    normals: np.ndarray
    labels: np.ndarray
    structures: np.ndarray
    structure_ids: np.ndarray
    seed: int = 0
    instances: np.ndarray | None = None

    @property
    def part_names(self) -> tuple[str, ...]:
        """The names of the part labels, ``PART_NAMES[category]``."""
        return PART_NAMES[self.category]

    @property
    def structure_names(self) -> tuple[str, ...]:
        """The names of the coarse structure groups, ``STRUCTURES[category]``."""
        return STRUCTURES[self.category]

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def save(self, path: str | os.PathLike) -> Path:
        """Write the collection to an ``.npz`` file (no pickled objects), atomically.

        Args:
            path: the file to write; missing folders are created.

        Returns:
            The path written.
        """
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        extra = {} if self.instances is None else {"instances": self.instances}
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".npz", delete=False) as f:
            np.savez(f, category=np.array(self.category), points=self.points, normals=self.normals,
                     labels=self.labels, structures=np.asarray(self.structures, dtype=str),
                     structure_ids=self.structure_ids, seed=np.array(self.seed),
                     generator_version=np.array(GENERATOR_VERSION), **extra)
        os.replace(f.name, path)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "ShapeCollection":
        """Read a collection written by :meth:`save`.

        Args:
            path: an ``.npz`` file.

        Returns:
            The :class:`ShapeCollection`.

        Raises:
            FileNotFoundError: when ``path`` is not a file.
            ValueError: when the file is unreadable or does not hold a valid collection.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such collection file")
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except Exception as exc:  # noqa: BLE001 - re-raised with the file name
            raise ValueError(f"{path}: not a readable collection file ({exc})") from exc
        missing = {"category", "points", "normals", "labels", "structures", "structure_ids"} - set(data)
        if missing:
            raise ValueError(f"{path}: not a shape collection (missing arrays {sorted(missing)})")
        category = str(data["category"])
        if category not in CATEGORIES:
            raise ValueError(f"{path}: unknown category {category!r}; expected one of {CATEGORIES}")
        points, normals, labels = data["points"], data["normals"], data["labels"]
        if points.ndim != 3 or points.shape[-1] != 3 or normals.shape != points.shape:
            raise ValueError(f"{path}: points {points.shape} and normals {normals.shape} must both be (S, N, 3)")
        if labels.shape != points.shape[:2] or data["structures"].shape != points.shape[:1] or \
                data["structure_ids"].shape != points.shape[:1]:
            raise ValueError(f"{path}: labels, structures and structure ids do not match points {points.shape}")
        if points.dtype.kind != "f" or normals.dtype.kind != "f" or labels.dtype.kind not in "iu":
            raise ValueError(f"{path}: points and normals must be floats and labels integers")
        if not (np.isfinite(points).all() and np.isfinite(normals).all()):
            raise ValueError(f"{path}: holds NaN or infinite coordinates")
        if labels.size and (labels.min() < 0 or labels.max() >= len(PART_NAMES[category])):
            raise ValueError(f"{path}: part labels outside 0 .. {len(PART_NAMES[category]) - 1}")
        instances = data.get("instances")
        if instances is not None:
            if instances.shape != labels.shape or instances.dtype.kind not in "iu" or \
                    (instances.size and instances.min() < 0):
                raise ValueError(f"{path}: instances must be non-negative integers shaped like the labels "
                                 f"{labels.shape}, got {instances.dtype} {instances.shape}")
            instances = instances.astype(np.int64)
        return cls(category=category, points=points, normals=normals, labels=labels.astype(np.int64),
                   structures=data["structures"], structure_ids=data["structure_ids"].astype(np.int64),
                   seed=int(data.get("seed", 0)), instances=instances)


def default_cache_dir() -> Path:
    """``$CUBOIDLIB_CACHE`` if set, else ``~/.cache/cuboidlib``."""
    env = os.environ.get("CUBOIDLIB_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "cuboidlib"


def make_collection(
    category: str,
    n_shapes: int,
    n_points: int = 2048,
    seed: int = 0,
    cache_dir: str | os.PathLike | None = None,
    use_cache: bool = True,
    progress: bool = False,
) -> ShapeCollection:
    """Generate (or load from the cache) ``n_shapes`` shapes of ``category`` with ``n_points`` each.

    Args:
        category: "chair", "table", "airplane" or "animal".
        n_shapes: S, the number of shapes.
        n_points: N, points per shape.
        seed: the collection's seed (shape i's generator is seeded with ``(seed, category, i)``).
        cache_dir: cache folder; None: :func:`default_cache_dir`. The file name encodes
            ``(category, n_shapes, n_points, seed, GENERATOR_VERSION)``.
        use_cache: read and write the cache; False always generates and writes nothing.
        progress: show a tqdm progress bar while generating.

    Returns:
        A :class:`ShapeCollection`: points (S, N, 3) and normals (S, N, 3) float32, labels and instances
        (S, N) int64.
    """
    _check_category(category)
    n_shapes = check_size(n_shapes, "n_shapes", MAX_SHAPES, "shapes")
    n_points = check_size(n_points, "n_points", MAX_SHAPE_POINTS)
    check_size(n_shapes * n_points, f"n_shapes x n_points ({n_shapes:,} x {n_points:,})", MAX_COLLECTION_POINTS)
    cache_file = None
    if use_cache:
        cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        cache_file = cache_dir / f"{category}_S{n_shapes}_N{n_points}_seed{seed}_v{GENERATOR_VERSION}.npz"
        if cache_file.is_file():
            try:
                cached = ShapeCollection.load(cache_file)
                if (cached.category, cached.points.shape, cached.seed) == (category, (n_shapes, n_points, 3), seed) \
                        and cached.instances is not None:
                    return cached
            except ValueError:
                pass  # unreadable, invalid, mismatched or instance-less cache entry: regenerate and overwrite it
    points = np.empty((n_shapes, n_points, 3), np.float32)
    normals = np.empty((n_shapes, n_points, 3), np.float32)
    labels = np.empty((n_shapes, n_points), np.int64)
    instances = np.empty((n_shapes, n_points), np.int64)
    structures, ids = [], np.empty(n_shapes, np.int64)
    indices = range(n_shapes)
    if progress:
        from tqdm.auto import tqdm

        indices = tqdm(indices, desc=f"{category} shapes")
    for i in indices:
        _, structure, sid, p, nn, lab, inst, _, _ = _sample_shape(category, i, seed, n_points)
        points[i], normals[i], labels[i], instances[i] = p, nn, lab, inst
        structures.append(structure)
        ids[i] = sid
    coll = ShapeCollection(category, points, normals, labels, np.array(structures, dtype=str), ids, seed, instances)
    if cache_file is not None:
        coll.save(cache_file)
    return coll


def plot_shapes(shapes: Sequence, titles: Sequence[str] | None = None, ncols: int = 3, point_size: float = 2.0,
                figsize_per_plot: float = 2.6):
    """Matplotlib figure of part-labelled point clouds: one 3D scatter per shape, +y up, front (+z) to the viewer.

    Args:
        shapes: :class:`Shape` objects or ``(points (N, 3), labels (N,), category)`` tuples.
        titles: optional title per shape.
        ncols: subplots per row.
        point_size: marker size.
        figsize_per_plot: inches per subplot side.

    Returns:
        The ``matplotlib.figure.Figure``, a legend naming the parts at each run of one category.
    """
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    items = [(s.points, s.labels, s.category) if isinstance(s, Shape) else s for s in shapes]
    nrows = max(1, math.ceil(len(items) / ncols))
    fig = plt.figure(figsize=(figsize_per_plot * ncols, figsize_per_plot * nrows))
    previous = None
    for k, (pts, lab, cat) in enumerate(items):
        ax = fig.add_subplot(nrows, ncols, k + 1, projection="3d", proj_type="ortho")
        pts, lab = np.asarray(pts), np.asarray(lab)
        ax.scatter(pts[:, 0], -pts[:, 2], pts[:, 1], c=np.array(PART_COLORS)[lab], s=point_size, linewidths=0)
        half = float(np.abs(pts).max())
        for setter in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
            setter(-half, half)
        ax.set_box_aspect((1, 1, 1), zoom=1.25)
        ax.view_init(elev=20, azim=-60)
        ax.set_axis_off()
        if titles is not None:
            ax.set_title(titles[k], fontsize=7)
        if cat != previous:  # one legend per run of shapes of the same category
            handles = [Line2D([], [], marker="o", ls="", color=PART_COLORS[i], label=name)
                       for i, name in enumerate(PART_NAMES[cat])]
            ax.legend(handles=handles, loc="upper left", fontsize=6, frameon=False, handletextpad=0.1,
                      borderaxespad=0.0)
        previous = cat
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.0, top=0.95, wspace=0.0, hspace=0.1)
    return fig
