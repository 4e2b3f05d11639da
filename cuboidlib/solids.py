"""Analytic solids that the procedural shapes of :mod:`cuboidlib.shapes` are assembled from.

One file, because every solid answers the same five questions, and the shapes use them side by side.

Every :class:`Solid` reports its surface area, samples area-uniform surface points with outward
unit normals, evaluates a signed distance (negative inside), maps itself by the normalisation
``x -> (x - center) / scale`` of :mod:`cuboidlib.normalization`, and builds a ``trimesh.Trimesh``.
A solid carries the integer part ``label`` of its points. Points are float64 arrays (n, 3); a local
frame is a centre ``c`` (3,) and a rotation ``R`` (3, 3) whose columns are the local axes, so
``world = c + local @ R.T``. :func:`sample_union_surface` samples the outer surface of a union.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

__all__ = [
    "Solid",
    "Hexahedron",
    "RoundedBox",
    "Cylinder",
    "Capsule",
    "Ellipsoid",
    "box",
    "bar",
    "frame_from_axis",
    "rotation_x",
    "rotation_y",
    "rotation_z",
    "sample_union_surface",
    "union_sdf",
]


def rotation_x(angle: float) -> np.ndarray:
    """Rotation about +x (right-handed).

    Args:
        angle: in radians.

    Returns:
        (3, 3) float64 rotation matrix.
    """
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_y(angle: float) -> np.ndarray:
    """Rotation about +y (right-handed).

    Args:
        angle: in radians.

    Returns:
        (3, 3) float64 rotation matrix.
    """
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_z(angle: float) -> np.ndarray:
    """Rotation about +z (right-handed).

    Args:
        angle: in radians.

    Returns:
        (3, 3) float64 rotation matrix.
    """
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def frame_from_axis(axis: np.ndarray) -> np.ndarray:
    """A frame whose local z axis points along ``axis``.

    Args:
        axis: (3,) non-zero vector.

    Returns:
        (3, 3) rotation whose third column is the unit vector along ``axis``.
    """
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(helper, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    return np.stack([e1, e2, a], axis=1)


def _unit_sphere(n: int, rng: np.random.Generator) -> np.ndarray:
    u = rng.standard_normal((n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


_SPHERE_LATTICE = _fibonacci_sphere(8192)


class Solid:
    """Base class: a closed solid with a part ``label``; subclasses implement the methods below."""

    label: int

    def area(self) -> float:
        """Surface area (the ellipsoid's to about 1e-4 relative error)."""
        raise NotImplementedError

    def sample(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Area-uniform points on the surface.

        Args:
            n: number of points.
            rng: numpy random generator.

        Returns:
            ``(points, normals)``: (n, 3) surface points and their (n, 3) outward unit normals.
        """
        raise NotImplementedError

    def sdf(self, x: np.ndarray) -> np.ndarray:
        """Signed distance: < 0 inside, 0 on the surface, > 0 outside.

        Exact for cylinders, capsules, rounded boxes and inside a hexahedron; for the ellipsoid and
        outside a hexahedron (boxes included) only the sign and the zero set are exact.

        Args:
            x: (n, 3) points.

        Returns:
            (n,) signed distances.
        """
        raise NotImplementedError

    def mapped(self, center: np.ndarray, scale: float) -> "Solid":
        """The same solid after ``x -> (x - center) / scale``.

        Args:
            center: (3,) translation, as from :func:`cuboidlib.normalization.normalize`.
            scale: positive scale.

        Returns:
            A new solid of the same type and label.
        """
        raise NotImplementedError

    def mesh(self) -> trimesh.Trimesh:
        """A closed triangle mesh of the surface (tessellated for curved solids)."""
        raise NotImplementedError


class _Framed(Solid):
    """A solid described in a local frame (centre ``c``, rotation ``R``)."""

    def __init__(self, c, R, label: int):
        self.c = np.asarray(c, dtype=float)
        self.R = np.asarray(R, dtype=float)
        self.label = int(label)

    def _local(self, x: np.ndarray) -> np.ndarray:
        return (x - self.c) @ self.R

    def _world(self, p: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.c + p @ self.R.T, n @ self.R.T

    def _transform(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.c
        return T


# Box topology of a hexahedron: corner i has local signs (bit 0 -> x, bit 1 -> y, bit 2 -> z).
# Each quad face lists its corners counter-clockwise seen from outside a standard box.
_HEX_QUADS = np.array(
    [[0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 5, 4], [2, 6, 7, 3], [0, 2, 3, 1], [4, 5, 7, 6]]
)
_HEX_TRIS = np.concatenate([_HEX_QUADS[:, [0, 1, 2]], _HEX_QUADS[:, [0, 2, 3]]])


class Hexahedron(Solid):
    """A convex solid with a box's topology and planar faces: boxes, tilted boxes, swept wings, fins.

    Args:
        corners: (8, 3); corner i plays the box corner whose sign on axis j is bit j of i.
            Each face's four corners must be coplanar.
        label: part label.
    """

    def __init__(self, corners: np.ndarray, label: int):
        self.corners = np.asarray(corners, dtype=float).reshape(8, 3)
        self.label = int(label)
        tri = self.corners[_HEX_TRIS]  # (12, 3, 3)
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        centroid = self.corners.mean(axis=0)
        outward = np.einsum("ij,ij->i", cross, tri.mean(axis=1) - centroid) >= 0
        cross[~outward] *= -1
        self._faces = np.where(outward[:, None], _HEX_TRIS, _HEX_TRIS[:, [0, 2, 1]])
        twice_area = np.linalg.norm(cross, axis=1)
        self._tri = tri
        self._areas = 0.5 * twice_area
        self._normals = cross / np.maximum(twice_area, 1e-300)[:, None]
        self._offsets = np.einsum("ij,ij->i", self._normals, tri[:, 0])
        keep = self._areas > 0
        self._plane_n, self._plane_d = self._normals[keep], self._offsets[keep]

    def area(self) -> float:
        return float(self._areas.sum())

    def sample(self, n, rng):
        cdf = np.cumsum(self._areas)
        t = np.minimum(np.searchsorted(cdf, rng.random(n) * cdf[-1], side="right"), 11)
        r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
        tri = self._tri[t]
        p = (1 - r1)[:, None] * tri[:, 0] + (r1 * (1 - r2))[:, None] * tri[:, 1] + (r1 * r2)[:, None] * tri[:, 2]
        return p, self._normals[t]

    def sdf(self, x):
        return (x @ self._plane_n.T - self._plane_d).max(axis=1)

    def mapped(self, center, scale):
        return Hexahedron((self.corners - center) / scale, self.label)

    def mesh(self):
        return trimesh.Trimesh(vertices=self.corners.copy(), faces=self._faces.copy(), process=False)


def box(center, half_sizes, R=None, label: int = 0) -> Hexahedron:
    """An oriented box as a :class:`Hexahedron`.

    Args:
        center: (3,).
        half_sizes: (3,) half extents along the local axes.
        R: (3, 3) rotation whose columns are the local axes; None: the identity.
        label: part label.

    Returns:
        The box as a :class:`Hexahedron`.
    """
    R = np.eye(3) if R is None else np.asarray(R, dtype=float)
    signs = np.array([[(i >> k & 1) * 2 - 1 for k in range(3)] for i in range(8)], dtype=float)
    corners = np.asarray(center, dtype=float) + (signs * np.asarray(half_sizes, dtype=float)) @ R.T
    return Hexahedron(corners, label)


class RoundedBox(_Framed):
    """A box with all edges and corners rounded: the Minkowski sum of a box and a ball.

    Args:
        c: (3,) centre.
        R: (3, 3) rotation, columns the local axes.
        inner: (3,) half sizes of the inner box, >= 0; the outer half sizes are ``inner + radius``.
        radius: rounding radius.
        label: part label.
    """

    def __init__(self, c, R, inner, radius: float, label: int):
        super().__init__(c, R, label)
        self.inner = np.asarray(inner, dtype=float)
        self.radius = float(radius)
        e, r = self.inner, self.radius
        faces = [8 * e[(a + 1) % 3] * e[(a + 2) % 3] for a in range(3)]
        edges = [4 * math.pi * r * e[a] for a in range(3)]
        self._pieces = np.array(faces + edges + [4 * math.pi * r * r])

    def area(self):
        return float(self._pieces.sum())

    def sample(self, n, rng):
        e, r = self.inner, self.radius
        counts = rng.multinomial(n, self._pieces / self._pieces.sum())
        pts, nrm = [], []
        for a in range(3):  # flat faces perpendicular to axis a
            k = counts[a]
            p = (rng.random((k, 3)) * 2 - 1) * e
            s = np.where(rng.random(k) < 0.5, -1.0, 1.0)
            p[:, a] = s * (e[a] + r)
            nn = np.zeros((k, 3))
            nn[:, a] = s
            pts.append(p)
            nrm.append(nn)
        for a in range(3):  # quarter cylinders along axis a
            k = counts[3 + a]
            b, c = (a + 1) % 3, (a + 2) % 3
            theta = rng.random(k) * 2 * math.pi
            cb, cc = np.cos(theta), np.sin(theta)
            p = np.empty((k, 3))
            p[:, a] = (rng.random(k) * 2 - 1) * e[a]
            p[:, b] = np.sign(cb) * e[b] + r * cb
            p[:, c] = np.sign(cc) * e[c] + r * cc
            nn = np.zeros((k, 3))
            nn[:, b], nn[:, c] = cb, cc
            pts.append(p)
            nrm.append(nn)
        u = _unit_sphere(counts[6], rng)  # sphere octants at the 8 corners
        pts.append(np.sign(u) * e + r * u)
        nrm.append(u)
        return self._world(np.concatenate(pts), np.concatenate(nrm))

    def sdf(self, x):
        q = np.abs(self._local(x)) - self.inner
        return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0) - self.radius

    def mapped(self, center, scale):
        return RoundedBox((self.c - center) / scale, self.R, self.inner / scale, self.radius / scale, self.label)

    def mesh(self):
        sphere = trimesh.creation.icosphere(subdivisions=2)
        v = sphere.vertices
        v = np.sign(np.round(v, 9)) * self.inner + self.radius * v
        return trimesh.Trimesh(vertices=v, faces=sphere.faces, process=False).apply_transform(self._transform())


class Cylinder(_Framed):
    """A closed circular cylinder along its local z axis.

    Args:
        c: (3,) centre.
        R: (3, 3) rotation, columns the local axes.
        radius: radius.
        half_height: the caps lie at local z = +-half_height.
        label: part label.
    """

    def __init__(self, c, R, radius: float, half_height: float, label: int):
        super().__init__(c, R, label)
        self.radius, self.half_height = float(radius), float(half_height)

    @classmethod
    def between(cls, a, b, radius: float, label: int) -> "Cylinder":
        """The cylinder whose axis runs from ``a`` to ``b``.

        Args:
            a: (3,) centre of one cap.
            b: (3,) centre of the other cap.
            radius: radius.
            label: part label.

        Returns:
            A :class:`Cylinder`.
        """
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        return cls((a + b) / 2, frame_from_axis(b - a), radius, np.linalg.norm(b - a) / 2, label)

    def area(self):
        r, h = self.radius, self.half_height
        return 2 * math.pi * r * 2 * h + 2 * math.pi * r * r

    def sample(self, n, rng):
        r, h = self.radius, self.half_height
        side = 4 * math.pi * r * h
        on_side = rng.random(n) < side / self.area()
        theta = rng.random(n) * 2 * math.pi
        cos, sin = np.cos(theta), np.sin(theta)
        rad = np.where(on_side, r, r * np.sqrt(rng.random(n)))
        cap = np.where(rng.random(n) < 0.5, -1.0, 1.0)
        z = np.where(on_side, (rng.random(n) * 2 - 1) * h, cap * h)
        p = np.stack([rad * cos, rad * sin, z], axis=1)
        nn = np.where(on_side[:, None], np.stack([cos, sin, np.zeros(n)], axis=1),
                      np.stack([np.zeros(n), np.zeros(n), cap], axis=1))
        return self._world(p, nn)

    def sdf(self, x):
        p = self._local(x)
        d = np.stack([np.hypot(p[:, 0], p[:, 1]) - self.radius, np.abs(p[:, 2]) - self.half_height], axis=1)
        return np.minimum(d.max(axis=1), 0) + np.linalg.norm(np.maximum(d, 0), axis=1)

    def mapped(self, center, scale):
        return Cylinder((self.c - center) / scale, self.R, self.radius / scale, self.half_height / scale, self.label)

    def mesh(self):
        return trimesh.creation.cylinder(radius=self.radius, height=2 * self.half_height, sections=24,
                                         transform=self._transform())


class Capsule(Solid):
    """All points within ``radius`` of a segment.

    Args:
        a: (3,) one end of the segment.
        b: (3,) the other end (may equal ``a``: a ball).
        radius: radius.
        label: part label.
    """

    def __init__(self, a, b, radius: float, label: int):
        self.a, self.b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        self.radius = float(radius)
        self.label = int(label)
        self.length = float(np.linalg.norm(self.b - self.a))
        self.R = frame_from_axis(self.b - self.a) if self.length > 0 else np.eye(3)

    def area(self):
        return 2 * math.pi * self.radius * self.length + 4 * math.pi * self.radius**2

    def sample(self, n, rng):
        r, L = self.radius, self.length
        on_side = rng.random(n) < 2 * math.pi * r * L / self.area()
        theta = rng.random(n) * 2 * math.pi
        side_n = np.stack([np.cos(theta), np.sin(theta), np.zeros(n)], axis=1)
        u = _unit_sphere(n, rng)
        nn = np.where(on_side[:, None], side_n, u)
        z = np.where(on_side, rng.random(n) * L, np.where(u[:, 2] >= 0, L, 0.0))
        axis_pt = np.stack([np.zeros(n), np.zeros(n), z], axis=1)
        return self.a + (axis_pt + r * nn) @ self.R.T, nn @ self.R.T

    def sdf(self, x):
        ab = self.b - self.a
        t = np.clip((x - self.a) @ ab / max(ab @ ab, 1e-300), 0.0, 1.0)
        return np.linalg.norm(x - (self.a + t[:, None] * ab), axis=1) - self.radius

    def mapped(self, center, scale):
        return Capsule((self.a - center) / scale, (self.b - center) / scale, self.radius / scale, self.label)

    def mesh(self):
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = (self.a + self.b) / 2
        return trimesh.creation.capsule(height=self.length, radius=self.radius, count=[12, 12], transform=T)


class Ellipsoid(_Framed):
    """An ellipsoid with semi-axes ``radii`` along its local axes.

    Sampling maps uniform directions u to ``radii * u``, kept with probability proportional to the
    area stretch; the area is averaged on a fixed Fibonacci lattice. The signed distance
    ``(|x / radii| - 1) * min(radii)`` is exact only in sign and zero set.

    Args:
        c: (3,) centre.
        R: (3, 3) rotation, columns the local axes.
        radii: (3,) semi-axes.
        label: part label.
    """

    def __init__(self, c, R, radii, label: int):
        super().__init__(c, R, label)
        self.radii = np.asarray(radii, dtype=float)
        g = np.prod(self.radii) * np.linalg.norm(_SPHERE_LATTICE / self.radii, axis=1)
        self._area = float(4 * math.pi * g.mean())

    def area(self):
        return self._area

    def sample(self, n, rng):
        inv = 1.0 / self.radii
        gmax = inv.max()
        out = []
        have = 0
        while have < n:
            m = int((n - have) * gmax / inv.min() * 1.1) + 16
            u = _unit_sphere(m, rng)
            keep = u[rng.random(m) * gmax < np.linalg.norm(u * inv, axis=1)]
            out.append(keep)
            have += len(keep)
        u = np.concatenate(out)[:n]
        nn = u * inv
        nn /= np.linalg.norm(nn, axis=1, keepdims=True)
        return self._world(u * self.radii, nn)

    def sdf(self, x):
        return (np.linalg.norm(self._local(x) / self.radii, axis=1) - 1.0) * self.radii.min()

    def mapped(self, center, scale):
        return Ellipsoid((self.c - center) / scale, self.R, self.radii / scale, self.label)

    def mesh(self):
        sphere = trimesh.creation.icosphere(subdivisions=3)
        return trimesh.Trimesh(vertices=sphere.vertices * self.radii, faces=sphere.faces,
                               process=False).apply_transform(self._transform())


def bar(a, b, width: float, label: int, round_section: bool = False, up=(0.0, 1.0, 0.0)) -> Solid:
    """A straight bar from ``a`` to ``b``: a square-section box or a cylinder.

    Args:
        a: (3,) start of the bar's axis.
        b: (3,) end of the bar's axis.
        width: side of the square section, or the cylinder's diameter.
        label: part label.
        round_section: build a :class:`Cylinder` instead of a box.
        up: (3,) one side of the square section is perpendicular to both the bar and ``up`` (a
            horizontal bar then has horizontal and vertical faces).

    Returns:
        A :class:`Hexahedron` or, with ``round_section``, a :class:`Cylinder`.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if round_section:
        return Cylinder.between(a, b, width / 2, label)
    axis = (b - a) / np.linalg.norm(b - a)
    side = np.cross(np.asarray(up, dtype=float), axis)
    if np.linalg.norm(side) < 1e-9:
        side = np.array([1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    R = np.stack([side, np.cross(axis, side), axis], axis=1)
    return box((a + b) / 2, [width / 2, width / 2, np.linalg.norm(b - a) / 2], R, label)


def union_sdf(solids: list[Solid], x: np.ndarray) -> np.ndarray:
    """Signed distance to the union of solids: the minimum over them.

    Args:
        solids: the solids.
        x: (n, 3) points.

    Returns:
        (n,) signed distances.
    """
    return np.min([s.sdf(x) for s in solids], axis=0)


def sample_union_surface(
    solids: list[Solid], n: int, rng: np.random.Generator, tol: float = 1e-9
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample ``n`` points area-uniformly on the outer surface of the union of ``solids``.

    Area-weighted candidates from every solid are rejected where they lie inside another solid.
    Solids that touch must overlap (not merely share a face), or the contact face survives. Where
    two solids share a coplanar piece of outer surface, only the one listed first is sampled there.

    Args:
        solids: the solids of one shape.
        n: number of points.
        rng: numpy random generator.
        tol: a candidate is rejected when ``sdf < -tol`` for another solid (``sdf < tol`` for an
            earlier one).

    Returns:
        ``(points, normals, index)``: (n, 3) points, (n, 3) outward unit normals and (n,) solid
        indices (``solids[index[i]].label`` is point i's part label).
    """
    areas = np.array([s.area() for s in solids])
    probs = areas / areas.sum()
    kept_p, kept_n, kept_i = [], [], []
    have, m, rate = 0, int(n * 1.6) + 64, None
    while have < n:
        if rate is not None:
            m = int((n - have) / max(rate, 0.02) * 1.15) + 64
        counts = rng.multinomial(m, probs)
        pts, nrm, idx = [], [], []
        for i, (s, k) in enumerate(zip(solids, counts)):
            if k:
                p, nn = s.sample(int(k), rng)
                pts.append(p)
                nrm.append(nn)
                idx.append(np.full(int(k), i))
        p, nn, idx = np.concatenate(pts), np.concatenate(nrm), np.concatenate(idx)
        buried = np.zeros(len(p), dtype=bool)
        for i, s in enumerate(solids):
            buried |= (s.sdf(p) < np.where(idx > i, tol, -tol)) & (idx != i)
        keep = ~buried
        rate = max(keep.mean(), 1e-3)
        kept_p.append(p[keep])
        kept_n.append(nn[keep])
        kept_i.append(idx[keep])
        have += int(keep.sum())
    p, nn, idx = np.concatenate(kept_p), np.concatenate(kept_n), np.concatenate(kept_i)
    choice = rng.permutation(len(p))[:n]
    return p[choice], nn[choice], idx[choice]
