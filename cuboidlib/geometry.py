"""Cuboid geometry (Sec. 3): local frames, faces, corners, meshes and surface sampling.

One file, because every cuboid operation shares the frame, face and corner conventions below; the rotations
themselves (quaternions and matrices) are in :mod:`cuboidlib.rotations`.

A cuboid C_m is the paper's triple (t, r, s): ``centers`` t (B, M, 3), unit ``quaternions`` r (B, M, 4)
in (w, x, y, z) order, and ``half_sizes`` s (B, M, 3), so that it spans [-s_x, s_x] x [-s_y, s_y] x
[-s_z, s_z] in its own frame. A world point is p = R l + t, the columns of R = R(r) being the local axes.
Faces are numbered +x, -x, +y, -y, +z, -z (:data:`FACE_NORMALS`); corner k has the sign + on axis i when
bit i of k is set (:data:`CORNER_SIGNS`). Functions accept tensors or arrays and validate them;
``validate=False`` skips the checks in hot loops and then expects tensors of one float dtype on one device.
:class:`Cuboids` bundles a batch and calls into the functions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
import trimesh

from ._checks import (
    as_float_tensor,
    check_finite,
    check_positive,
    check_same_leading,
    check_shape,
    check_unit_vectors,
)
from .rotations import quaternion_to_rotation_matrix

#: Inputs accepted where a tensor is expected: tensors, numpy arrays (converted to tensors).
TensorLike = torch.Tensor | np.ndarray

__all__ = [
    "TensorLike",
    "FACE_NORMALS",
    "FACE_TANGENTS",
    "CORNER_SIGNS",
    "CUBOID_TRIANGLES",
    "validate_cuboids",
    "world_to_local",
    "local_to_world",
    "directions_to_local",
    "directions_to_world",
    "cuboid_face_normals",
    "cuboid_corners",
    "cuboid_face_areas",
    "cuboids_to_trimesh",
    "SurfaceSamples",
    "sample_cuboid_surfaces",
    "Cuboids",
]

#: Local outward normals of the six faces, shape (6, 3), in the order +x, -x, +y, -y, +z, -z.
#: Face f lies on the plane l[f // 2] = (+1 if f is even else -1) * s[f // 2] of the local frame.
FACE_NORMALS = torch.tensor(
    [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]
)

#: Two local unit tangents (u, v) spanning each face, shape (6, 2, 3), chosen so that u x v is the
#: face's outward normal. A point of face f in unit-cube coordinates is n_f + a u_f + b v_f with
#: a, b in [-1, 1]; multiplying by s gives the local point.
FACE_TANGENTS = torch.tensor(
    [
        [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],  # +x: u = +y, v = +z
        [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]],  # -x: u = +z, v = +y
        [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]],  # +y: u = +z, v = +x
        [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],  # -y: u = +x, v = +z
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],  # +z: u = +x, v = +y
        [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]],  # -z: u = +y, v = +x
    ]
)

#: Signs of the eight corners in the unit cube, shape (8, 3): corner k has sign +1 on axis i when bit
#: i of k is set and -1 otherwise. Corner k of a cuboid is t + R (CORNER_SIGNS[k] * s).
CORNER_SIGNS = torch.tensor([[1.0 if (k >> i) & 1 else -1.0 for i in range(3)] for k in range(8)])


def _corner_index(signs: torch.Tensor) -> int:
    """Index of the corner with the given (3,) sign vector (inverse of :data:`CORNER_SIGNS`)."""
    return int(sum(int(signs[i] > 0) << i for i in range(3)))


def _build_triangles() -> torch.Tensor:
    """Two triangles per face, wound counter-clockwise when seen from outside (outward normals)."""
    triangles = []
    for f in range(6):
        n, (u, v) = FACE_NORMALS[f], FACE_TANGENTS[f]
        # Going (-u,-v) -> (+u,-v) -> (+u,+v) -> (-u,+v) is counter-clockwise seen from outside,
        # because u x v = n points outwards.
        ring = [_corner_index(n + a * u + b * v) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        triangles += [[ring[0], ring[1], ring[2]], [ring[0], ring[2], ring[3]]]
    return torch.tensor(triangles, dtype=torch.long)


#: Triangles of a cuboid mesh, shape (12, 3), as indices into its 8 corners (:data:`CORNER_SIGNS`
#: order). Triangles 2f and 2f + 1 cover face f; all are wound so their normals point outwards.
CUBOID_TRIANGLES = _build_triangles()


# ----------------------------------------------------------------------------------------------
# Validation
# ----------------------------------------------------------------------------------------------


def _common_float(tensors: dict) -> dict:
    """Convert to float tensors of one promoted dtype on one device (error if devices differ)."""
    out = {name: as_float_tensor(t, name) for name, t in tensors.items()}
    devices = {str(t.device) for t in out.values()}
    if len(devices) > 1:
        listing = ", ".join(f"{name} on {t.device}" for name, t in out.items())
        raise ValueError(f"all inputs must be on one device, got {listing}; move them with .to(device)")
    dtype = out[next(iter(out))].dtype
    for t in out.values():
        dtype = torch.promote_types(dtype, t.dtype)
    return {name: t.to(dtype) for name, t in out.items()}


def _as_exists_mask(exists: TensorLike, shape: tuple, device: torch.device) -> torch.Tensor:
    """Check an existence mask: booleans (or 0/1 integers) of the given (B, M) shape."""
    e = exists if isinstance(exists, torch.Tensor) else torch.as_tensor(np.asarray(exists))
    if e.is_floating_point():
        raise TypeError(
            "exists must be a boolean mask of shape (B, M); threshold probabilities first, "
            "e.g. exists = existence_probability > 0.5"
        )
    if e.dtype != torch.bool:
        if ((e != 0) & (e != 1)).any():
            raise ValueError("exists must be a boolean mask (or 0/1 integers) of shape (B, M)")
        e = e != 0
    if tuple(e.shape) != tuple(shape):
        raise ValueError(f"exists must have shape (B, M) = {tuple(shape)} like the cuboids, got {tuple(e.shape)}")
    return e.to(device)


_CUBOID_SHAPES = {"centers": ("B", "M", 3), "quaternions": ("B", "M", 4), "half_sizes": ("B", "M", 3)}


def _validate_cuboid_parts(parts: dict, quaternion_tol: float = 1e-3) -> dict:
    """Validate any subset of the cuboid tensors (dict name -> tensor); see :func:`validate_cuboids`."""
    t = _common_float(parts)
    sizes: dict = {}
    check_same_leading({name: check_shape(x, _CUBOID_SHAPES[name], name) for name, x in t.items()}, sizes, "cuboids")
    if sizes["M"] == 0:
        raise ValueError("cuboids: M = 0; at least one cuboid per shape is needed")
    for name, value in t.items():
        check_finite(value, name)
    if "quaternions" in t:
        check_unit_vectors(t["quaternions"], "quaternions", tol=quaternion_tol)
    if "half_sizes" in t:
        check_positive(t["half_sizes"], "half_sizes")
    return t


def validate_cuboids(
    centers: TensorLike,
    quaternions: TensorLike,
    half_sizes: TensorLike,
    exists: TensorLike | None = None,
    quaternion_tol: float = 1e-3,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Check a batch of cuboids and return it as float tensors of one dtype and device.

    Args:
        centers: (B, M, 3), M >= 1.
        quaternions: (B, M, 4) unit quaternions (w, x, y, z).
        half_sizes: (B, M, 3), positive.
        exists: optional (B, M) mask, bool or 0/1 integers.
        quaternion_tol: allowed deviation of |q| from 1.

    Returns:
        ``(centers, quaternions, half_sizes, exists)``, promoted to a common float dtype; exists is
        a bool tensor or None.

    Raises:
        ValueError: naming the argument, for wrong or disagreeing shapes, NaN/inf, non-unit
            quaternions or non-positive half sizes.
        TypeError: for a float ``exists`` (threshold probabilities first).
    """
    t = _validate_cuboid_parts(
        {"centers": centers, "quaternions": quaternions, "half_sizes": half_sizes}, quaternion_tol
    )
    c = t["centers"]
    mask = None if exists is None else _as_exists_mask(exists, tuple(c.shape[:2]), c.device)
    return c, t["quaternions"], t["half_sizes"], mask


def _check_points(points: TensorLike, name: str = "points") -> torch.Tensor:
    """Check a (B, N, 3) point (or direction) cloud with N >= 1 and finite values."""
    p = as_float_tensor(points, name)
    check_shape(p, ("B", "N", 3), name)
    if p.shape[1] == 0:
        raise ValueError(f"{name} is empty (N = 0); at least one point per shape is needed")
    check_finite(p, name)
    return p


def _broadcast_batch(b_points: int, b_cuboids: int, what: str) -> int:
    """Batch size of points against cuboids: equal, or one of them is 1 and is broadcast."""
    if b_points != b_cuboids and 1 not in (b_points, b_cuboids):
        raise ValueError(
            f"{what}: the points have batch size {b_points} but the cuboids have {b_cuboids}; "
            "they must be equal or one of them must be 1 (broadcast)"
        )
    return max(b_points, b_cuboids)


def _validate_points_and_cuboids(points: dict, cuboids: dict, what: str) -> dict:
    """Validate point clouds and cuboid tensors (dicts name -> tensor) together.

    Every point cloud must be (B, N, 3) with the same shape; the cuboid tensors are checked as in
    :func:`validate_cuboids`; the two batch sizes must agree or one must be 1. Returns all tensors
    converted to one float dtype, keyed by name.
    """
    checked = {name: _check_points(p, name) for name, p in points.items()}
    cub = _validate_cuboid_parts(cuboids)
    out = _common_float({**checked, **cub})
    first_name = next(iter(points))
    first = out[first_name]
    for name in points:
        if out[name].shape != first.shape:
            raise ValueError(
                f"{what}: {name} has shape {tuple(out[name].shape)} but {first_name} has "
                f"{tuple(first.shape)}; they must match"
            )
    _broadcast_batch(first.shape[0], next(iter(cub.values())).shape[0], what)
    return out


# ----------------------------------------------------------------------------------------------
# Local frames
# ----------------------------------------------------------------------------------------------


def _to_local(points: torch.Tensor, centers: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """l = R^T (p - t) for every point and cuboid: (B, N, 3), (B, M, 3), (B, M, 3, 3) -> (B, N, M, 3).

    Computed with row vectors as p R - t R: one batched matrix product and a broadcast subtraction.
    """
    return torch.einsum("bnj,bmji->bnmi", points, R) - torch.einsum("bmj,bmji->bmi", centers, R)[:, None]


def _directions_to_local(directions: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """R^T d for every direction and cuboid: (B, N, 3), (B, M, 3, 3) -> (B, N, M, 3)."""
    return torch.einsum("bnj,bmji->bnmi", directions, R)


def world_to_local(
    points: TensorLike,
    centers: TensorLike,
    quaternions: TensorLike,
    validate: bool = True,
) -> torch.Tensor:
    """Coordinates of every point in every cuboid's local frame, l = R^T (p - t).

    Args:
        points: (B, N, 3).
        centers: (B, M, 3).
        quaternions: (B, M, 4) unit (w, x, y, z); a batch size of 1 on either side is broadcast.
        validate: check the inputs; False expects tensors of one float dtype on one device.

    Returns:
        (B, N, M, 3): entry [b, n, m] is point n of shape b in the frame of cuboid m.
    """
    if validate:
        v = _validate_points_and_cuboids(
            {"points": points}, {"centers": centers, "quaternions": quaternions}, "world_to_local"
        )
        points, centers, quaternions = v["points"], v["centers"], v["quaternions"]
    R = quaternion_to_rotation_matrix(quaternions, validate=False)
    return _to_local(points, centers, R)


def _check_local(local: torch.Tensor, cuboids: dict, name: str, what: str) -> None:
    """Check (B, N, M, 3) local coordinates against validated cuboid tensors."""
    sizes = check_shape(local, ("B", "N", "M", 3), name)
    check_finite(local, name)
    first = next(iter(cuboids.values()))
    if sizes["M"] != first.shape[1]:
        raise ValueError(f"{what}: {name} has M = {sizes['M']} cuboids but the cuboids have M = {first.shape[1]}")
    _broadcast_batch(sizes["B"], first.shape[0], what)


def local_to_world(
    local_points: TensorLike,
    centers: TensorLike,
    quaternions: TensorLike,
    validate: bool = True,
) -> torch.Tensor:
    """Inverse of :func:`world_to_local`: p = R l + t.

    Args:
        local_points: (B, N, M, 3), point n in the frame of cuboid m.
        centers: (B, M, 3).
        quaternions: (B, M, 4) unit (w, x, y, z).
        validate: check the inputs; False expects tensors of one float dtype on one device.

    Returns:
        (B, N, M, 3) world coordinates.
    """
    if validate:
        v = _common_float(
            {"local_points": local_points, **_validate_cuboid_parts({"centers": centers, "quaternions": quaternions})}
        )
        local_points, centers, quaternions = v["local_points"], v["centers"], v["quaternions"]
        _check_local(local_points, {"centers": centers}, "local_points", "local_to_world")
    R = quaternion_to_rotation_matrix(quaternions, validate=False)
    return torch.einsum("bmij,bnmj->bnmi", R, local_points) + centers[:, None]


def directions_to_local(directions: TensorLike, quaternions: TensorLike, validate: bool = True) -> torch.Tensor:
    """Directions (e.g. normals) in every cuboid's local frame, R^T d (no translation).

    Args:
        directions: (B, N, 3).
        quaternions: (B, M, 4) unit (w, x, y, z).
        validate: check the inputs; False expects tensors of one float dtype on one device.

    Returns:
        (B, N, M, 3) local directions.
    """
    if validate:
        v = _validate_points_and_cuboids(
            {"directions": directions}, {"quaternions": quaternions}, "directions_to_local"
        )
        directions, quaternions = v["directions"], v["quaternions"]
    return _directions_to_local(directions, quaternion_to_rotation_matrix(quaternions, validate=False))


def directions_to_world(
    local_directions: TensorLike,
    quaternions: TensorLike,
    validate: bool = True,
) -> torch.Tensor:
    """Inverse of :func:`directions_to_local`: R d.

    Args:
        local_directions: (B, N, M, 3), direction n in the frame of cuboid m.
        quaternions: (B, M, 4) unit (w, x, y, z).
        validate: check the inputs; False expects tensors of one float dtype on one device.

    Returns:
        (B, N, M, 3) world directions.
    """
    if validate:
        v = _common_float(
            {"local_directions": local_directions, **_validate_cuboid_parts({"quaternions": quaternions})}
        )
        local_directions, quaternions = v["local_directions"], v["quaternions"]
        _check_local(local_directions, {"quaternions": quaternions}, "local_directions", "directions_to_world")
    R = quaternion_to_rotation_matrix(quaternions, validate=False)
    return torch.einsum("bmij,bnmj->bnmi", R, local_directions)


# ----------------------------------------------------------------------------------------------
# Faces, corners, areas
# ----------------------------------------------------------------------------------------------


def cuboid_face_normals(quaternions: TensorLike, validate: bool = True) -> torch.Tensor:
    """World outward normals of the six faces of every cuboid: plus/minus the columns of R.

    Args:
        quaternions: (B, M, 4) unit (w, x, y, z).
        validate: require finite unit quaternions.

    Returns:
        (B, M, 6, 3) in the :data:`FACE_NORMALS` order (+x, -x, +y, -y, +z, -z).
    """
    R = quaternion_to_rotation_matrix(quaternions, validate=validate)
    return torch.einsum("...ij,fj->...fi", R, FACE_NORMALS.to(R))  # (B, M, 6, 3)


def cuboid_corners(
    centers: TensorLike,
    quaternions: TensorLike,
    half_sizes: TensorLike,
    validate: bool = True,
) -> torch.Tensor:
    """The eight corners of every cuboid, t + R (sigma_k * s).

    Args:
        centers: (B, M, 3); quaternions: (B, M, 4) unit (w, x, y, z); half_sizes: (B, M, 3) positive.
        validate: check the inputs (:func:`validate_cuboids`).

    Returns:
        (B, M, 8, 3) in the :data:`CORNER_SIGNS` order (corner k has +s_i on axis i when bit i of k is set).
    """
    if validate:
        centers, quaternions, half_sizes, _ = validate_cuboids(centers, quaternions, half_sizes)
    R = quaternion_to_rotation_matrix(quaternions, validate=False)
    local = CORNER_SIGNS.to(half_sizes) * half_sizes[..., None, :]  # (B, M, 8, 3)
    return torch.einsum("bmij,bmkj->bmki", R, local) + centers[..., None, :]  # (B, M, 8, 3)


def cuboid_face_areas(half_sizes: TensorLike) -> torch.Tensor:
    """Areas of the six faces, in the :data:`FACE_NORMALS` order.

    Args:
        half_sizes: (..., 3).

    Returns:
        (..., 6): the +x and -x faces have area (2 s_y)(2 s_z), and so on.
    """
    s = as_float_tensor(half_sizes, "half_sizes")
    if s.dim() < 1 or s.shape[-1] != 3:
        raise ValueError(f"half_sizes must have shape (..., 3), got shape {tuple(s.shape)}")
    sx, sy, sz = s.unbind(-1)
    yz, xz, xy = 4 * sy * sz, 4 * sx * sz, 4 * sx * sy
    return torch.stack((yz, yz, xz, xz, xy, xy), dim=-1)


# ----------------------------------------------------------------------------------------------
# Meshes
# ----------------------------------------------------------------------------------------------


def _rgba_uint8(colors, m: int) -> np.ndarray:
    """Colours (M, 3) or (M, 4), floats in [0, 1] or integers in [0, 255] -> (M, 4) uint8 RGBA."""
    c = np.asarray(colors.detach().cpu() if isinstance(colors, torch.Tensor) else colors)
    if c.ndim != 2 or c.shape[0] != m or c.shape[1] not in (3, 4):
        raise ValueError(f"colors must have shape (M, 3) or (M, 4) with M = {m}, got shape {c.shape}")
    if np.issubdtype(c.dtype, np.floating):
        if not np.isfinite(c).all() or c.min() < 0 or c.max() > 1:
            raise ValueError("float colors must lie in [0, 1] (use integers for the 0..255 range)")
        c = np.round(c * 255)
    elif not np.issubdtype(c.dtype, np.integer) or c.min() < 0 or c.max() > 255:
        raise ValueError("colors must be floats in [0, 1] or integers in [0, 255]")
    if c.shape[1] == 3:
        c = np.concatenate([c, np.full((m, 1), 255)], axis=1)
    return c.astype(np.uint8)


def cuboids_to_trimesh(
    centers: TensorLike,
    quaternions: TensorLike,
    half_sizes: TensorLike,
    exists: TensorLike | None = None,
    colors: TensorLike | None = None,
    split: bool = False,
) -> trimesh.Trimesh | list[trimesh.Trimesh]:
    """Triangle mesh of the cuboids of ONE shape (8 vertices and 12 outward triangles per cuboid).

    Args:
        centers: (M, 3), no batch axis; quaternions: (M, 4) unit (w, x, y, z); half_sizes: (M, 3).
        exists: optional (M,) bool mask; cuboids marked False are left out.
        colors: optional (M, 3) or (M, 4) per-cuboid face colours, floats in [0, 1] or integers in [0, 255].
        split: return one mesh per kept cuboid instead of one mesh of all.

    Returns:
        A ``trimesh.Trimesh`` (each cuboid a watertight component, float64 vertices, no gradient), or
        with ``split`` a list of them in cuboid order.
    """
    def single(x, name):
        x = as_float_tensor(x, name).detach()
        if x.dim() != 2:
            raise ValueError(f"{name} must describe ONE shape, shape (M, ...), got shape {tuple(x.shape)}")
        return x[None]

    c, q, s = single(centers, "centers"), single(quaternions, "quaternions"), single(half_sizes, "half_sizes")
    if exists is not None:
        exists = torch.as_tensor(np.asarray(exists.cpu() if isinstance(exists, torch.Tensor) else exists))[None]
    c, q, s, mask = validate_cuboids(c, q, s, exists)
    m = c.shape[1]
    corners = cuboid_corners(c, q, s, validate=False)[0].cpu().double().numpy()  # (M, 8, 3)
    rgba = None if colors is None else _rgba_uint8(colors, m)
    keep = range(m) if mask is None else [i for i in range(m) if bool(mask[0, i])]
    triangles = CUBOID_TRIANGLES.numpy()

    meshes = []
    for i in keep:  # building a few mesh objects, not a numerical loop
        face_colors = None if rgba is None else np.repeat(rgba[i : i + 1], len(triangles), axis=0)
        meshes.append(trimesh.Trimesh(vertices=corners[i], faces=triangles, face_colors=face_colors, process=False))
    if split:
        return meshes
    if not meshes:
        return trimesh.Trimesh(vertices=np.zeros((0, 3)), faces=np.zeros((0, 3), dtype=np.int64), process=False)
    vertices = np.concatenate([mesh.vertices for mesh in meshes])
    faces = np.concatenate([triangles + 8 * k for k in range(len(meshes))])
    face_colors = None if rgba is None else np.concatenate([mesh.visual.face_colors for mesh in meshes])
    return trimesh.Trimesh(vertices=vertices, faces=faces, face_colors=face_colors, process=False)


# ----------------------------------------------------------------------------------------------
# Surface sampling
# ----------------------------------------------------------------------------------------------


class SurfaceSamples(NamedTuple):
    """Points sampled on cuboid surfaces (unpacks as ``points, normals, cuboid_index``)."""

    points: torch.Tensor  #: (B, n, 3) world positions
    normals: torch.Tensor  #: (B, n, 3) world outward unit normals of the sampled faces
    cuboid_index: torch.Tensor  #: (B, n) long, index m of the cuboid each point lies on


def sample_cuboid_surfaces(
    centers: TensorLike,
    quaternions: TensorLike,
    half_sizes: TensorLike,
    n_points: int,
    exists: TensorLike | None = None,
    generator: torch.Generator | None = None,
    validate: bool = True,
) -> SurfaceSamples:
    """Area-uniform samples on all the cuboids' surfaces (overlaps included), with outward normals.

    A face is drawn with probability proportional to its area, then a uniform point (a, b) on it;
    the map from (a, b) to the point is differentiable (reparameterisation), the face choice is not.

    Args:
        centers: (B, M, 3); quaternions: (B, M, 4) unit (w, x, y, z); half_sizes: (B, M, 3) positive.
        n_points: n, samples per shape.
        exists: optional (B, M) bool mask; only existing cuboids are sampled (at least one per shape).
        generator: the only source of randomness.
        validate: check the inputs; False expects tensors of one float dtype on one device.

    Returns:
        :class:`SurfaceSamples`: points (B, n, 3), normals (B, n, 3), cuboid_index (B, n) int64.
    """
    if validate:
        centers, quaternions, half_sizes, exists = validate_cuboids(centers, quaternions, half_sizes, exists)
    if not isinstance(n_points, int) or n_points < 1:
        raise ValueError(f"n_points must be a positive integer, got {n_points!r}")
    b, m = centers.shape[:2]
    areas = cuboid_face_areas(half_sizes.detach())  # (B, M, 6)
    if exists is not None:
        areas = areas * exists[..., None].to(areas.dtype)
        empty = ~exists.any(dim=1)
        if empty.any():
            raise ValueError(
                f"exists marks no cuboid in shape {int(torch.nonzero(empty)[0])}; at least one cuboid "
                "per shape must exist to sample its surface"
            )
    flat_face = torch.multinomial(areas.reshape(b, m * 6), n_points, replacement=True, generator=generator)
    cuboid, face = flat_face // 6, flat_face % 6  # (B, n) each
    ab = torch.rand(b, n_points, 2, generator=generator, dtype=centers.dtype, device=centers.device) * 2 - 1

    normals_local = FACE_NORMALS.to(centers)[face]  # (B, n, 3)
    tangents = FACE_TANGENTS.to(centers)[face]  # (B, n, 2, 3)
    unit = normals_local + ab[..., 0:1] * tangents[..., 0, :] + ab[..., 1:2] * tangents[..., 1, :]  # (B, n, 3)

    def pick(x: torch.Tensor) -> torch.Tensor:  # (B, M, ...) -> (B, n, ...) for each sample's cuboid
        index = cuboid.reshape(b, n_points, *([1] * (x.dim() - 2))).expand(b, n_points, *x.shape[2:])
        return torch.gather(x, 1, index)

    R = pick(quaternion_to_rotation_matrix(quaternions, validate=False))  # (B, n, 3, 3)
    points = torch.einsum("bnij,bnj->bni", R, unit * pick(half_sizes)) + pick(centers)  # (B, n, 3)
    normals = torch.einsum("bnij,bnj->bni", R, normals_local)
    return SurfaceSamples(points, normals, cuboid)


# ----------------------------------------------------------------------------------------------
# Container
# ----------------------------------------------------------------------------------------------


@dataclass
class Cuboids:
    """A batch of cuboids; its methods are thin conveniences over this module's functions.

    Args:
        centers: (B, M, 3).
        quaternions: (B, M, 4) unit (w, x, y, z).
        half_sizes: (B, M, 3) positive.
        exists: optional (B, M) bool mask, the paper's indicator delta_m (Sec. 3); None: all exist.
        validate: check and convert the fields with :func:`validate_cuboids` at construction.
    """

    centers: torch.Tensor
    quaternions: torch.Tensor
    half_sizes: torch.Tensor
    exists: torch.Tensor | None = None
    validate: bool = True

    def __post_init__(self) -> None:
        if self.validate:
            self.centers, self.quaternions, self.half_sizes, self.exists = validate_cuboids(
                self.centers, self.quaternions, self.half_sizes, self.exists
            )

    @property
    def batch_size(self) -> int:
        """B, the number of shapes."""
        return self.centers.shape[0]

    @property
    def num_cuboids(self) -> int:
        """M, the number of cuboid slots per shape (existing or not)."""
        return self.centers.shape[1]

    def existing(self) -> torch.Tensor:
        """The (B, M) boolean existence mask (all True when ``exists`` is None)."""
        if self.exists is None:
            return torch.ones(self.centers.shape[:2], dtype=torch.bool, device=self.centers.device)
        return self.exists

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> Cuboids:
        """A copy on another device and/or float dtype, unvalidated.

        Args:
            device: target device; None keeps each tensor's.
            dtype: float dtype of the cuboid tensors; None keeps it (the mask stays bool).

        Returns:
            A new :class:`Cuboids`.
        """
        move = lambda x: x.to(device=device or x.device, dtype=dtype or x.dtype)  # noqa: E731
        exists = None if self.exists is None else self.exists.to(device or self.exists.device)
        return Cuboids(move(self.centers), move(self.quaternions), move(self.half_sizes), exists, validate=False)

    def detach(self) -> Cuboids:
        """A copy whose tensors are detached from the autograd graph."""
        exists = None if self.exists is None else self.exists.detach()
        return Cuboids(
            self.centers.detach(), self.quaternions.detach(), self.half_sizes.detach(), exists, validate=False
        )

    def rotation_matrices(self) -> torch.Tensor:
        """(B, M, 3, 3) rotation matrices (columns = local axes in world coordinates)."""
        return quaternion_to_rotation_matrix(self.quaternions, validate=False)

    def corners(self) -> torch.Tensor:
        """(B, M, 8, 3) corners, see :func:`cuboid_corners`."""
        return cuboid_corners(self.centers, self.quaternions, self.half_sizes, validate=False)

    def face_normals(self) -> torch.Tensor:
        """(B, M, 6, 3) world outward face normals, see :func:`cuboid_face_normals`."""
        return cuboid_face_normals(self.quaternions, validate=False)

    def sample_surface(self, n_points: int, generator: torch.Generator | None = None) -> SurfaceSamples:
        """Area-weighted samples on the existing cuboids, see :func:`sample_cuboid_surfaces`.

        Args:
            n_points: n, samples per shape.
            generator: the only source of randomness.

        Returns:
            :class:`SurfaceSamples`: points (B, n, 3), normals (B, n, 3), cuboid_index (B, n).
        """
        return sample_cuboid_surfaces(
            self.centers, self.quaternions, self.half_sizes, n_points, self.exists, generator, validate=False
        )

    def to_trimesh(
        self,
        index: int = 0,
        colors=None,
        split: bool = False,
    ) -> trimesh.Trimesh | list[trimesh.Trimesh]:
        """Mesh of the existing cuboids of one shape, see :func:`cuboids_to_trimesh`.

        Args:
            index: the shape, in [-B, B).
            colors: optional (M, 3) or (M, 4) per-cuboid colours.
            split: one mesh per cuboid.

        Returns:
            A ``trimesh.Trimesh``, or with ``split`` a list of them.
        """
        if not -self.batch_size <= index < self.batch_size:
            raise IndexError(f"index {index} is out of range for a batch of {self.batch_size} shapes")
        exists = None if self.exists is None else self.exists[index]
        return cuboids_to_trimesh(
            self.centers[index], self.quaternions[index], self.half_sizes[index], exists, colors, split
        )
