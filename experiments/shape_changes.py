"""The changes of ``transfer_causes.py``: each perturbs one procedural shape in one way a real mesh differs.

A change takes a :class:`cuboidlib.shapes.Shape` and a random generator and returns a :class:`Changed`: the input
the network sees (points, normals, labels, the solid of each point) and the unperturbed outer surface in the same
frame, against which the Chamfer distance is measured.

The changes (``transfer_causes.py`` normalises every input again, box diagonal 1, as ``cuboidlib.abstract``
would):

* sampling: ``resampled`` (a fresh area-uniform sample of the outer surface: the control, what sampling alone
  changes); ``every_face`` (area-uniform on the whole surface of every solid, the faces inside the union
  included, as a sampler of a real mesh built of overlapping closed parts does); ``every_face_real_share`` (the
  same with the points inside other solids thinned to the share estimated for the category's real meshes, see
  below); ``mesh_pipeline`` (the real
  meshes' pipeline of ``benchmarks/bench_real_meshes.py`` on the solids' concatenated triangle meshes: 2048
  area-uniform samples on every triangle with flat face normals, oriented by
  :func:`cuboidlib.normals.orient_normals`, the first 1024 kept); ``normals_reoriented`` (the outer-surface
  points with their normals' signs chosen by ``orient_normals`` from random signs, the orientation step alone);
* density: ``density_ramp4`` (density rising 4x along a random direction); ``density_triangles`` (each solid
  sampled in proportion to the triangles of its mesh instead of its area);
* noise: ``noise_0.005``, ``noise_0.01`` (Gaussian jitter of that standard deviation per coordinate, in box
  diagonals; normals kept);
* pose and scale: ``stretch_<axis><factor>`` (one axis scaled by 0.8 or 1.25, normals transformed with it);
  ``pitch_<deg>`` / ``roll_<deg>`` (turned about x / z by 5 or 10 degrees, the sign random per shape);
* part proportions and variants where the real meshes' part statistics leave the procedural range (below):
  airplanes ``nose_propeller`` (the engines replaced by a two-bladed propeller and spinner on the nose, labelled
  engine, as the real single-engine aircraft have), ``landing_gear`` (a fixed tricycle gear, struts and wheels
  labelled body, as seven of the real airplanes have), ``fuselage_x1.4`` (the fuselage 1.4 times thicker, its
  length kept), ``wing_span1.3`` (the wings 1.3 times longer), ``tail_x1.4``
  (fin and stabiliser 1.4 times larger); animals ``thigh_labels`` (the labels only: body points over the hips
  and shoulders, up to 60 % of the body's height, labelled leg, as the real meshes' skins label them; the
  network's input is unchanged), ``tail_long`` (the tail lengthened about its root to at least 0.3 body lengths,
  as long as the real tails' lower half), ``tail_raised`` / ``tail_hanging`` (the same, and turned about its root
  to 60 degrees above / 75 degrees below the horizontal), ``head_x1.4`` (head, snout and ears 1.4 times larger).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from cuboidlib.normals import orient_normals
from cuboidlib.shapes import Shape
from cuboidlib.solids import (Capsule, Cylinder, Ellipsoid, Hexahedron, bar, box, rotation_x, rotation_z,
                              sample_union_surface)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks" / "real_meshes"))
from load import sample_triangles  # noqa: E402  (benchmarks/ is not a package)

CATEGORIES = ("chair", "table", "airplane", "animal")
_DEG = math.pi / 180


@dataclass
class Changed:
    """One perturbed shape before normalisation: the input the network sees and the unperturbed surface."""

    points: np.ndarray  # (N, 3) input points
    normals: np.ndarray  # (N, 3) input normals
    labels: np.ndarray  # (N,) part labels of the input points
    instances: np.ndarray  # (N,) the solid each input point lies on
    reference: np.ndarray  # (R, 3) the unperturbed outer surface in the same frame (for the CD)
    inside: np.ndarray | None = None  # (N,) bool: the point lies inside another solid (None: none does)


@dataclass(frozen=True)
class Change:
    name: str
    group: str
    apply: Callable[[Shape, np.random.Generator], Changed]
    normals_only: bool = False  # only the normals change: nothing to run for a network that reads none
    labels_only: bool = False  # only the labels change: the network's input is the unperturbed one
    categories: tuple[str, ...] = CATEGORIES
    takes_interior_share: bool = False  # apply(shape, rng, share): the real meshes' estimated interior share


def _labels_of(solids, index: np.ndarray) -> np.ndarray:
    return np.array([s.label for s in solids], np.int64)[index]


def _outer(solids, n: int, rng: np.random.Generator) -> Changed:
    p, nn, idx = sample_union_surface(solids, n, rng)
    return Changed(p, nn, _labels_of(solids, idx), idx, p)


def sample_every_face(solids, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` points area-uniform on the whole surface of every solid, the parts inside other solids included (what
    a sampler of a mesh built of overlapping closed parts returns): points, each solid's outward normals, solid
    indices."""
    areas = np.array([s.area() for s in solids])
    counts = rng.multinomial(n, areas / areas.sum())
    got = [(s.sample(int(k), rng), i) for i, (s, k) in enumerate(zip(solids, counts)) if k]
    p = np.concatenate([g[0][0] for g in got])
    nn = np.concatenate([g[0][1] for g in got])
    idx = np.concatenate([np.full(len(g[0][0]), g[1]) for g in got])
    order = rng.permutation(n)
    return p[order], nn[order], idx[order]


def buried(solids, points: np.ndarray, index: np.ndarray, tol: float = 1e-4) -> np.ndarray:
    """(N,) bool: the point lies deeper than ``tol`` inside a solid other than its own (``index``)."""
    out = np.zeros(len(points), bool)
    for i, s in enumerate(solids):
        out |= (s.sdf(points) < -tol) & (index != i)
    return out


def _every_face(shape: Shape, rng) -> Changed:
    p, nn, idx = sample_every_face(shape.parts, len(shape.points), rng)
    return Changed(p, nn, _labels_of(shape.parts, idx), idx, shape.points, buried(shape.parts, p, idx))


def _every_face_at_share(shape: Shape, rng, share: float) -> Changed:
    """Every-face sampling with the points inside other solids thinned to ``share`` of the input (at most the
    share that every-face sampling gives)."""
    n = len(shape.points)
    p, nn, idx = sample_every_face(shape.parts, 4 * n, rng)
    inside = buried(shape.parts, p, idx)
    k = min(int(round(share * n)), int(inside.sum()), int(round(inside.mean() * n)))
    pick = np.concatenate([rng.permutation(np.nonzero(inside)[0])[:k], rng.permutation(np.nonzero(~inside)[0])[:n - k]])
    pick = rng.permutation(pick)
    return Changed(p[pick], nn[pick], _labels_of(shape.parts, idx[pick]), idx[pick], shape.points, inside[pick])


def _mesh_pipeline(shape: Shape, rng) -> Changed:
    meshes = [s.mesh() for s in shape.parts]
    verts, faces, owner, offset = [], [], [], 0
    for i, m in enumerate(meshes):
        verts.append(np.asarray(m.vertices, float))
        faces.append(np.asarray(m.faces) + offset)
        owner.append(np.full(len(m.faces), i))
        offset += len(m.vertices)
    n = len(shape.points)
    p, nn, face = sample_triangles(np.concatenate(verts), np.concatenate(faces), 2 * n, int(rng.integers(2**31)))
    nn = orient_normals(p, nn)
    idx = np.concatenate(owner)[face]
    return Changed(p[:n], nn[:n], _labels_of(shape.parts, idx[:n]), idx[:n], shape.points,
                   buried(shape.parts, p[:n], idx[:n]))


def _reoriented(shape: Shape, rng) -> Changed:
    signs = np.where(rng.random(len(shape.points)) < 0.5, -1.0, 1.0)[:, None]
    nn = orient_normals(shape.points.astype(np.float64), shape.normals * signs)
    return Changed(shape.points, nn, shape.labels, shape.instances, shape.points)


def _resampled(shape: Shape, rng) -> Changed:
    out = _outer(shape.parts, len(shape.points), rng)
    out.reference = shape.points
    return out


def _thinned(solids, n: int, rng, weight: Callable[[np.ndarray], np.ndarray]) -> Changed:
    """``n`` outer-surface points kept with probability ``weight(p) / max weight`` from a larger sample."""
    p, nn, idx = sample_union_surface(solids, 8 * n, rng)
    w = weight(p)
    keep = np.nonzero(rng.random(len(p)) * w.max() < w)[0]
    keep = rng.permutation(keep)[:n]
    return Changed(p[keep], nn[keep], _labels_of(solids, idx[keep]), idx[keep], p[:n])


def _ramp(shape: Shape, rng) -> Changed:
    direction = rng.standard_normal(3)
    direction /= np.linalg.norm(direction)

    def weight(p):
        t = p @ direction
        return 1.0 + 3.0 * (t - t.min()) / max(t.max() - t.min(), 1e-12)
    return _thinned(shape.parts, len(shape.points), rng, weight)


def _by_triangles(shape: Shape, rng) -> Changed:
    """The outer surface sampled with each solid's share proportional to the triangles of its mesh, not its area
    (uniform within a solid); a candidate inside another solid is rejected as in ``sample_union_surface``."""
    solids, n = shape.parts, len(shape.points)
    weights = np.array([len(s.mesh().faces) for s in solids], float)
    kept: list[tuple] = []
    have = 0
    while have < n:
        counts = rng.multinomial(4 * n, weights / weights.sum())
        for i, (s, k) in enumerate(zip(solids, counts)):
            if not k:
                continue
            p, nn = s.sample(int(k), rng)
            buried = np.zeros(len(p), bool)
            for j, other in enumerate(solids):
                if j != i:
                    buried |= other.sdf(p) < (1e-9 if j < i else -1e-9)
            kept.append((p[~buried], nn[~buried], np.full(int((~buried).sum()), i)))
            have += int((~buried).sum())
    p, nn, idx = (np.concatenate([k[j] for k in kept]) for j in range(3))
    keep = rng.permutation(len(p))[:n]
    return Changed(p[keep], nn[keep], _labels_of(solids, idx[keep]), idx[keep], shape.points)


def _noise(sigma: float):
    def apply(shape: Shape, rng) -> Changed:
        p = shape.points + sigma * rng.standard_normal(shape.points.shape)
        return Changed(p, shape.normals, shape.labels, shape.instances, shape.points)
    return apply


def _linear(matrix_of: Callable[[np.random.Generator], np.ndarray]):
    """A linear map of points and reference; normals by its inverse transpose."""
    def apply(shape: Shape, rng) -> Changed:
        a = matrix_of(rng)
        nn = shape.normals @ np.linalg.inv(a)  # (A^-T n) as rows
        nn /= np.linalg.norm(nn, axis=1, keepdims=True)
        return Changed(shape.points @ a.T, nn, shape.labels, shape.instances, shape.points @ a.T)
    return apply


def _stretch(axis: int, factor: float):
    a = np.eye(3)
    a[axis, axis] = factor
    return _linear(lambda rng: a)


def _tilt(rotation, degrees: float):
    return _linear(lambda rng: rotation((1 if rng.random() < 0.5 else -1) * degrees * _DEG))


# ------------------------------------------------------------------------- part proportions and variants


def _edited(shape: Shape, solids: list, rng) -> Changed:
    """The outer surface of edited solids: input and reference alike (the edited shape is the unperturbed one)."""
    return _outer(solids, len(shape.points), rng)


def _scaled_hex(solid: Hexahedron, pivot, factors) -> Hexahedron:
    return Hexahedron(pivot + (solid.corners - pivot) * np.asarray(factors, float), solid.label)


def _fuselage(shape: Shape):
    """(axis point, nose tip z, radius) of an airplane's fuselage: its first solid (capsule or cylinder)."""
    main = shape.parts[0]
    if isinstance(main, Capsule):
        axis, radius = main.a, main.radius
        tip = max(main.a[2], main.b[2]) + radius
    else:
        axis, radius = main.c, main.radius
        tip = max(s.c[2] + s.radii[2] for s in shape.parts if isinstance(s, Ellipsoid) and s.label == 0)
    return np.asarray(axis, float), float(tip), float(radius)


def _nose_propeller(shape: Shape, rng) -> Changed:
    body, wing, tail, engine = range(4)
    axis, tip, rf = _fuselage(shape)
    solids = [s for s in shape.parts if s.label != engine]
    hub = np.array([axis[0], axis[1], tip])
    solids.append(Ellipsoid(hub, np.eye(3), [0.45 * rf, 0.45 * rf, 0.5 * rf], engine))
    blade_r, phase = rng.uniform(1.6, 2.4) * rf, rng.uniform(0, math.pi)
    for k in range(2):  # two blades crossing at the hub: one two-bladed propeller of four blade halves
        r = rotation_z(phase + k * math.pi / 2)
        solids.append(box(hub + [0, 0, 0.25 * rf], [0.12 * rf, blade_r, 0.04 * rf], r, engine))
    return _edited(shape, solids, rng)


def _landing_gear(shape: Shape, rng) -> Changed:
    """A fixed tricycle gear, labelled body as the real meshes label it: a nose wheel and two main wheels (discs
    across x) on vertical struts below the fuselage, the main wheels under the wing root's middle."""
    axis, tip, rf = _fuselage(shape)
    wing = [s for s in shape.parts if s.label == 1]
    root = np.concatenate([w.corners[np.abs(w.corners[:, 0] - axis[0]) <= np.abs(w.corners[:, 0] - axis[0]).min()
                                     + 1e-9] for w in wing])
    z_main, bottom = float(root[:, 2].mean()), axis[1] - 0.8 * rf
    wheel_r, strut = rng.uniform(0.45, 0.7) * rf, rng.uniform(1.0, 1.6) * rf
    solids = list(shape.parts)
    for x, z in ((axis[0], tip - 3.0 * rf), (axis[0] - 1.5 * rf, z_main), (axis[0] + 1.5 * rf, z_main)):
        hub = np.array([x, axis[1] - rf - strut, z])
        solids.append(bar([x, bottom, z], hub, 0.2 * rf, 0))
        solids.append(Cylinder.between(hub - [0.25 * rf, 0, 0], hub + [0.25 * rf, 0, 0], wheel_r, 0))
    return _edited(shape, solids, rng)


def _fuselage_scaled(factor: float):
    """The fuselage (its capsule, or its cylinder and nose and tail ellipsoids) ``factor`` times thicker about its
    axis, its length kept: the real meshes' fuselages are thicker for their length (a third of them above the
    procedural range)."""
    def thicker(s):
        if s.label != 0:
            return s
        if isinstance(s, Capsule):  # the segment shortened by the rounded ends' growth: the same overall length
            inward = (factor - 1) * s.radius * (s.b - s.a) / np.linalg.norm(s.b - s.a)
            return Capsule(s.a + inward, s.b - inward, s.radius * factor, 0)
        if isinstance(s, Cylinder):
            return Cylinder(s.c, s.R, s.radius * factor, s.half_height, 0)
        return Ellipsoid(s.c, s.R, s.radii * [factor, factor, 1.0], 0)  # axis-aligned (shapes._airplane)

    def apply(shape: Shape, rng) -> Changed:
        return _edited(shape, [thicker(s) for s in shape.parts], rng)
    return apply


def _wing_span(factor: float):
    def apply(shape: Shape, rng) -> Changed:
        axis, _, _ = _fuselage(shape)
        solids = [_scaled_hex(s, axis, [factor, 1, 1]) if s.label == 1 else s for s in shape.parts]
        return _edited(shape, solids, rng)
    return apply


def _tail_scaled(factor: float):
    def apply(shape: Shape, rng) -> Changed:
        fin = next(s for s in shape.parts if s.label == 2)  # the fin comes first (shapes._airplane_tail)
        pivot = fin.corners[fin.corners[:, 1] <= np.median(fin.corners[:, 1])].mean(axis=0)  # its root's centre
        solids = [_scaled_hex(s, pivot, [factor] * 3) if s.label == 2 else s for s in shape.parts]
        return _edited(shape, solids, rng)
    return apply


def _thigh_labels(shape: Shape, rng) -> Changed:
    """Body points over each upper leg (horizontally within 2.5 leg radii of its hip), up to 60 % of the body's
    height, labelled leg, as the real meshes' skins label the thighs and shoulders; points unchanged."""
    body, head, leg, tail = range(4)
    uppers = [s for s in shape.parts if s.label == leg][0::2]  # (upper, lower) capsule per leg
    p, labels = shape.points, shape.labels.copy()
    on_body = labels == body
    lo, hi = p[on_body, 1].min(), p[on_body, 1].max()
    below = p[:, 1] < lo + 0.6 * (hi - lo)
    for capsule in uppers:
        hip = capsule.a if capsule.a[1] > capsule.b[1] else capsule.b
        near = np.hypot(p[:, 0] - hip[0], p[:, 2] - hip[2]) < 2.5 * capsule.radius
        labels[on_body & below & near] = leg
    return Changed(p, shape.normals, labels, shape.instances, p)


def turned_tail(parts: list, angle_deg: float | None, ground: float, min_length: float = 0.3) -> list:
    """An animal's solids with its tail (its capsules) turned rigidly about its root so that the root-to-tip
    direction lies ``angle_deg`` above the horizontal (None: not turned), and lengthened about its root to at least
    ``min_length`` body lengths (the real tails' median is 0.41, the procedural 0.22); a tail that would reach below
    ``ground`` is shortened about its root to end there."""
    tails = [s for s in parts if s.label == 3]
    body = parts[0]  # the body ellipsoid, its length along z (shapes._animal)
    root, end = tails[0].a, tails[-1].b
    v = end - root
    turn = np.eye(3)
    if angle_deg is not None:
        now = math.atan2(v[1], -v[2])  # the tail points backwards (-z): its angle above the horizontal
        turn = rotation_x(angle_deg * _DEG - now)  # rotation_x(+) turns -z towards +y: raises the tail
    k = max(1.0, min_length * 2 * body.radii[2] / np.linalg.norm(v))
    moved = [Capsule(root + k * (s.a - root) @ turn.T, root + k * (s.b - root) @ turn.T, s.radius, s.label)
             for s in tails]
    room = [(root[1] - c.radius - ground) / (root[1] - e[1]) for c in moved for e in (c.a, c.b) if e[1] < root[1]]
    f = max(min([1.0] + room), 0.1)
    if f < 1:  # every capsule's lowest point at or above the ground
        moved = [Capsule(root + (c.a - root) * f, root + (c.b - root) * f, c.radius, c.label) for c in moved]
    return [s for s in parts if s.label != 3] + moved


def _tail_turned(angle_deg: float | None):
    def apply(shape: Shape, rng) -> Changed:
        return _edited(shape, turned_tail(shape.parts, angle_deg, float(shape.points[:, 1].min())), rng)
    return apply


def _head_scaled(factor: float):
    def apply(shape: Shape, rng) -> Changed:
        neck = next(s for s in shape.parts if s.label == 1 and isinstance(s, Capsule))
        pivot = neck.b
        solids = [Ellipsoid(pivot + (s.c - pivot) * factor, s.R, s.radii * factor, s.label)
                  if s.label == 1 and isinstance(s, Ellipsoid) else s for s in shape.parts]
        return _edited(shape, solids, rng)
    return apply


CHANGES: tuple[Change, ...] = (
    Change("clean", "reference", lambda shape, rng: Changed(shape.points, shape.normals, shape.labels,
                                                             shape.instances, shape.points)),
    Change("resampled", "sampling", _resampled),
    Change("every_face", "sampling", _every_face),
    Change("every_face_real_share", "sampling", _every_face_at_share, takes_interior_share=True),
    Change("mesh_pipeline", "sampling", _mesh_pipeline),
    Change("normals_reoriented", "sampling", _reoriented, normals_only=True),
    Change("density_ramp4", "density", _ramp),
    Change("density_triangles", "density", _by_triangles),
    Change("noise_0.005", "noise", _noise(0.005)),
    Change("noise_0.01", "noise", _noise(0.01)),
    *(Change(f"stretch_{'xyz'[axis]}{factor:g}", "pose and scale", _stretch(axis, factor))
      for axis in range(3) for factor in (0.8, 1.25)),
    *(Change(f"{name}_{deg}", "pose and scale", _tilt(rot, deg))
      for name, rot in (("pitch", rotation_x), ("roll", rotation_z)) for deg in (5, 10)),
    Change("nose_propeller", "proportions and variants", _nose_propeller, categories=("airplane",)),
    Change("landing_gear", "proportions and variants", _landing_gear, categories=("airplane",)),
    Change("fuselage_x1.4", "proportions and variants", _fuselage_scaled(1.4), categories=("airplane",)),
    Change("wing_span1.3", "proportions and variants", _wing_span(1.3), categories=("airplane",)),
    Change("tail_x1.4", "proportions and variants", _tail_scaled(1.4), categories=("airplane",)),
    Change("thigh_labels", "proportions and variants", _thigh_labels, labels_only=True, categories=("animal",)),
    Change("tail_long", "proportions and variants", _tail_turned(None), categories=("animal",)),
    Change("tail_raised", "proportions and variants", _tail_turned(60), categories=("animal",)),
    Change("tail_hanging", "proportions and variants", _tail_turned(-75), categories=("animal",)),
    Change("head_x1.4", "proportions and variants", _head_scaled(1.4), categories=("animal",)),
)
