"""Point-to-cuboid distances: the paper's normal-aware sampled distance, Eq. (5), and its baselines.

:func:`point_to_cuboid_distance` is d(p_n, C_m) of Eq. (5) (Sec. 3.4.1). The baselines of Sec. 4.3
are :func:`nearest_surface_distance` (projection to the closest surface, P2C-Dis) and
:func:`chamfer_distance_to_cuboids` (Chamfer-Dis); :func:`chamfer_distance` between two point sets is
also the evaluation metric. All results are SQUARED Euclidean distances. Points and normals are
(B, N, 3), cuboids as in :mod:`cuboidlib.geometry`; a batch size of 1 on either side is broadcast.
"""

from __future__ import annotations

import torch

from ._checks import as_float_tensor, check_finite, check_shape, check_unit_vectors
from .geometry import (
    TensorLike,
    _as_exists_mask,
    _directions_to_local,
    _to_local,
    _validate_points_and_cuboids,
    sample_cuboid_surfaces,
)
from .neighbors import nearest_index, nearest_indices
from .rotations import quaternion_to_rotation_matrix

__all__ = [
    "point_to_cuboid_distance",
    "nearest_surface_distance",
    "nearest_neighbors",
    "chamfer_distance",
    "chamfer_distance_to_cuboids",
]


def point_to_cuboid_distance(
    points: TensorLike,
    normals: TensorLike,
    centers: TensorLike,
    quaternions: TensorLike,
    half_sizes: TensorLike,
    sigma_s: float = 0.05,
    offsets: TensorLike | None = None,
    generator: torch.Generator | None = None,
    validate: bool = True,
) -> torch.Tensor:
    """The paper's point-to-cuboid distance d(p_n, C_m), Eq. (5) (Sec. 3.4.1), for all pairs.

    The face whose outward normal is closest to the point's normal is chosen (no gradient through
    the choice); a point p^s = p + e n, e ~ N(0, sigma_s^2), is sampled along the normal; d is the
    squared distance from the ORIGINAL point p to the point of that face nearest to p^s. d = 0 only
    on a face whose outward normal is n; on a face tilted by theta, E[d] = sigma_s^2 sin^2 theta.

    Args:
        points: (B, N, 3).
        normals: (B, N, 3) unit normals of the points.
        centers: (B, M, 3) cuboid centres t.
        quaternions: (B, M, 4) unit quaternions r, (w, x, y, z).
        half_sizes: (B, M, 3) positive half extents s.
        sigma_s: standard deviation of e; 0 (with no offsets) is the unsampled variant.
        offsets: optional (B, N) values of e, one per point shared by all cuboids (then sigma_s is
            unused); ``sigma_s * torch.randn(B, N, generator=g)`` reproduces ``generator=g``.
        generator: source of e when ``offsets`` is None.
        validate: check shapes, finiteness, unit normals and quaternions and positive sizes; False
            expects tensors of one float dtype on one device.

    Returns:
        (B, N, M) squared distances, d[b, n, m] = d(p_n, C_m); differentiable with respect to
        points, normals and the cuboid parameters.
    """
    if validate:
        v = _validate_points_and_cuboids(
            {"points": points, "normals": normals},
            {"centers": centers, "quaternions": quaternions, "half_sizes": half_sizes},
            "point_to_cuboid_distance",
        )
        points, normals = v["points"], v["normals"]
        centers, quaternions, half_sizes = v["centers"], v["quaternions"], v["half_sizes"]
        check_unit_vectors(normals, "normals")
        if not (isinstance(sigma_s, (int, float)) and sigma_s >= 0 and sigma_s != float("inf")):
            raise ValueError(f"sigma_s must be a finite non-negative number, got {sigma_s!r}")
    e = _normal_offsets(points, sigma_s, offsets, generator, validate)  # (B, N) or None

    R = quaternion_to_rotation_matrix(quaternions, validate=False)
    p = _to_local(points, centers, R)  # (B, N, M, 3) points in every cuboid's frame
    n = _directions_to_local(normals, R)  # (B, N, M, 3) normals in every cuboid's frame
    s = half_sizes[:, None]  # (B, 1, M, 3)

    # 1. Face selection: most similar outward normal = axis a of largest |n_a|, side sign(n_a).
    with torch.no_grad():
        face_axis = _largest_axis_one_hot(n)  # (B, N, M, 3), 1 on axis a, 0 elsewhere
        face_side = n.sign()  # read on axis a only, where |n_a| >= 1/sqrt(3) > 0

    # 2. Sample along the normal: p^s = p + e n.
    p_s = p if e is None else p + e[:, :, None, None] * n

    # 3. Closest point of the selected face rectangle: p^s clamped to the box on the two in-plane
    #    axes, and the face plane sign(n_a) s_a on axis a. The clamp to [-s, s] is written with two
    #    ReLUs: the same values and gradients, and a backward pass about twice as fast on a CPU as
    #    torch.clamp with tensor bounds.
    q = p_s - torch.relu(p_s - s) + torch.relu(-s - p_s)
    q = q + face_axis * (face_side * s - q)

    # 4. Squared distance to the original point.
    return (q - p).square().sum(dim=-1)


def _largest_axis_one_hot(v: torch.Tensor) -> torch.Tensor:
    """One-hot (..., 3) float mask of the axis with the largest |v_i| (ties go to the lower axis).

    Same result as ``one_hot(v.abs().argmax(-1), 3)``, written with comparisons because an argmax
    over a length-3 axis is several times slower on CPU.
    """
    ax, ay, az = v.abs().unbind(-1)
    pick_x = (ax >= ay) & (ax >= az)
    pick_y = ~pick_x & (ay >= az)
    pick_z = ~(pick_x | pick_y)
    return torch.stack((pick_x, pick_y, pick_z), dim=-1).to(v.dtype)


def _normal_offsets(
    points: torch.Tensor,
    sigma_s: float,
    offsets: TensorLike | None,
    generator: torch.Generator | None,
    validate: bool,
) -> torch.Tensor | None:
    """The offsets e (B, N) along the normals, or None for the unsampled variant."""
    if offsets is not None:
        e = as_float_tensor(offsets, "offsets").to(points)
        if validate:
            if tuple(e.shape) != tuple(points.shape[:2]):
                raise ValueError(
                    f"offsets must have shape (B, N) = {tuple(points.shape[:2])} like the points, "
                    f"got {tuple(e.shape)}"
                )
            check_finite(e, "offsets")
        return e
    if sigma_s == 0:
        return None
    noise = torch.randn(points.shape[:2], generator=generator, dtype=points.dtype, device=points.device)
    return sigma_s * noise


def nearest_surface_distance(
    points: TensorLike,
    centers: TensorLike,
    quaternions: TensorLike,
    half_sizes: TensorLike,
    validate: bool = True,
) -> torch.Tensor:
    """Squared distance from every point to every cuboid's SURFACE, ignoring normals (P2C-Dis, Sec. 4.3).

    Inside a cuboid the distance is to its nearest face, not 0: the solid's interior is not its surface.

    Args:
        points: (B, N, 3).
        centers: (B, M, 3); quaternions: (B, M, 4) unit (w, x, y, z); half_sizes: (B, M, 3) positive.
        validate: check the inputs; False expects tensors of one float dtype on one device.

    Returns:
        (B, N, M) squared distances, differentiable away from the kinks where the nearest face changes.
    """
    if validate:
        v = _validate_points_and_cuboids(
            {"points": points},
            {"centers": centers, "quaternions": quaternions, "half_sizes": half_sizes},
            "nearest_surface_distance",
        )
        points, centers, quaternions, half_sizes = v["points"], v["centers"], v["quaternions"], v["half_sizes"]
    R = quaternion_to_rotation_matrix(quaternions, validate=False)
    a = _to_local(points, centers, R).abs()  # (B, N, M, 3), by symmetry only |l| matters
    s = half_sizes[:, None]  # (B, 1, M, 3)
    outside = (a - s).clamp_min(0).square().sum(dim=-1)
    depth = (s - a).amin(dim=-1)  # > 0 exactly when the point is inside: distance to the nearest face
    return torch.where(depth > 0, depth.square(), outside)


def _auto_chunk(batch: int, n_reference: int, chunk_size: int | None) -> int:
    """Rows per chunk so that one chunk's distance matrix holds about 2^24 numbers."""
    if chunk_size is not None:
        if not isinstance(chunk_size, int) or chunk_size < 1:
            raise ValueError(f"chunk_size must be a positive integer or None, got {chunk_size!r}")
        return chunk_size
    return max(1, (1 << 24) // max(1, batch * n_reference))


def _check_point_sets(
    a: TensorLike, b: TensorLike, names: tuple[str, str], what: str
) -> tuple[torch.Tensor, torch.Tensor]:
    """Two (B, Na, 3), (B, Nb, 3) finite non-empty sets, batch sizes equal or 1 (then expanded)."""
    x, y = as_float_tensor(a, names[0]), as_float_tensor(b, names[1])
    for t, name in ((x, names[0]), (y, names[1])):
        check_shape(t, ("B", "N", 3), name)
        if t.shape[1] == 0:
            raise ValueError(f"{name} is empty (N = 0); at least one point per shape is needed")
        check_finite(t, name)
    if x.device != y.device:
        raise ValueError(f"{what}: {names[0]} is on {x.device} but {names[1]} is on {y.device}")
    if x.shape[0] != y.shape[0] and 1 not in (x.shape[0], y.shape[0]):
        raise ValueError(
            f"{what}: batch sizes {x.shape[0]} ({names[0]}) and {y.shape[0]} ({names[1]}) must be equal "
            "or one of them 1"
        )
    batch = max(x.shape[0], y.shape[0])
    dtype = torch.promote_types(x.dtype, y.dtype)
    return x.to(dtype).expand(batch, -1, -1), y.to(dtype).expand(batch, -1, -1)


def _gather_sq_dist(x: torch.Tensor, y: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """|x_i - y_index[i]|^2 for x (B, Nx, 3), y (B, Ny, 3), index (B, Nx) -> (B, Nx).

    Raises ValueError when a squared distance overflows the dtype (finite input, infinite result).
    """
    partner = torch.gather(y, 1, index[..., None].expand(-1, -1, 3))
    d2 = (x - partner).square().sum(dim=-1)
    if not torch.isfinite(d2).all():
        raise ValueError(
            f"squared distances overflow {str(d2.dtype).replace('torch.', '')} (coordinates up to "
            f"{float(x.detach().abs().max()):.3g}); normalise the points or pass float64"
        )
    return d2


def nearest_neighbors(
    query: TensorLike,
    reference: TensorLike,
    chunk_size: int | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Squared distance to and index of the nearest reference point, for every query point.

    Args:
        query: (B, Nq, 3), Nq >= 1.
        reference: (B, Nr, 3), Nr >= 1; a batch size of 1 on either side is broadcast.
        chunk_size: query points searched at once; None: about 2^24 distances per chunk.

    Returns:
        ``(sq_dist, index)``, each (B, Nq); index is int64. The distances are recomputed from the
        chosen pairs, so they are differentiable with respect to both sets.
    """
    q, r = _check_point_sets(query, reference, ("query", "reference"), "nearest_neighbors")
    index = nearest_index(q, r, _auto_chunk(q.shape[0], r.shape[1], chunk_size))
    return _gather_sq_dist(q, r, index), index


def chamfer_distance(
    a: TensorLike,
    b: TensorLike,
    chunk_size: int | None = None,
    return_directions: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Bidirectional Chamfer distance between point sets, one value per shape.

    The convention, stated wherever cuboidlib reports it: squared L2, mean per direction, sum of the
    two directions, no scaling::

        CD(a, b) = mean_i min_j |a_i - b_j|^2 + mean_j min_i |b_j - a_i|^2

    Args:
        a: (B, Na, 3), Na >= 1.
        b: (B, Nb, 3), Nb >= 1; a batch size of 1 on either side is broadcast.
        chunk_size: points of a searched at once; None: about 2^24 distances per chunk.
        return_directions: also return the two directions.

    Returns:
        (B,), or ``(total, a_to_b, b_to_a)``, each (B,); differentiable with respect to both sets.
    """
    x, y = _check_point_sets(a, b, ("a", "b"), "chamfer_distance")
    x_to_y, y_to_x = nearest_indices(x, y, _auto_chunk(x.shape[0], y.shape[1], chunk_size))
    forward = _gather_sq_dist(x, y, x_to_y).mean(dim=1)
    backward = _gather_sq_dist(y, x, y_to_x).mean(dim=1)
    total = forward + backward
    return (total, forward, backward) if return_directions else total


def chamfer_distance_to_cuboids(
    points: TensorLike,
    centers: TensorLike,
    quaternions: TensorLike,
    half_sizes: TensorLike,
    n_samples: int | None = None,
    exists: TensorLike | None = None,
    generator: torch.Generator | None = None,
    chunk_size: int | None = None,
    return_directions: bool = False,
    validate: bool = True,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Chamfer distance between a point cloud and samples of the cuboids' surfaces (Chamfer-Dis, Sec. 4.3).

    The samples come from :func:`cuboidlib.geometry.sample_cuboid_surfaces` (reparameterised, so
    differentiable) and are compared by :func:`chamfer_distance`.

    Args:
        points: (B, N, 3).
        centers: (B, M, 3); quaternions: (B, M, 4) unit (w, x, y, z); half_sizes: (B, M, 3) positive.
        n_samples: points sampled on the surfaces per shape; None: N.
        exists: optional (B, M) bool mask; only existing cuboids are sampled.
        generator: source of the samples.
        chunk_size: as in :func:`chamfer_distance`.
        return_directions: also return the two directions.
        validate: check the inputs; False expects tensors of one float dtype on one device.

    Returns:
        (B,), or ``(total, points_to_cuboids, cuboids_to_points)``, each (B,).
    """
    if validate:
        v = _validate_points_and_cuboids(
            {"points": points},
            {"centers": centers, "quaternions": quaternions, "half_sizes": half_sizes},
            "chamfer_distance_to_cuboids",
        )
        points, centers, quaternions, half_sizes = v["points"], v["centers"], v["quaternions"], v["half_sizes"]
        if exists is not None:
            exists = _as_exists_mask(exists, tuple(centers.shape[:2]), centers.device)
    n = points.shape[1] if n_samples is None else n_samples
    samples = sample_cuboid_surfaces(
        centers, quaternions, half_sizes, n, exists=exists, generator=generator, validate=False
    )
    return chamfer_distance(points, samples.points, chunk_size=chunk_size, return_directions=return_directions)
