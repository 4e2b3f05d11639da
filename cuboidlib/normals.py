"""Normals for point clouds that come without them (the distance of Eq. (5), Sec. 3.4.1, needs one per point).

:func:`estimate_normals` runs :func:`pca_normals` (each point's line: the smallest-eigenvalue
eigenvector of its weighted kNN covariance) and then :func:`orient_normals` (each line's sign: the
side of the tangent plane whose fan of rays runs farther before meeting another point is outward).
:func:`normal_errors` scores normals against known ones (``benchmarks/bench_shapes.py``). Points are
(N, 3) arrays or tensors, the result is of the input's kind; the exact kNN search of
:mod:`cuboidlib.neighbors` costs O(N^2) time, hence the limit ``MAX_POINTS``.
"""

from __future__ import annotations

import numpy as np
import torch

from ._checks import MAX_SHAPE_POINTS, as_float_tensor, check_finite, check_shape
from .neighbors import knn_indices

# Largest cloud estimate_normals accepts: its cost grows as N^2 (about 40 s for 20 000 points on one
# laptop core); a larger cloud should be subsampled first (load_point_cloud(..., n_points=...)). The limit on
# points per shape, cuboidlib._checks.MAX_SHAPE_POINTS.
MAX_POINTS = MAX_SHAPE_POINTS

__all__ = ["MAX_POINTS", "pca_normals", "orient_normals", "estimate_normals", "normal_errors"]


def _as_points(points, name: str = "points") -> tuple[torch.Tensor, bool]:
    is_numpy = not isinstance(points, torch.Tensor)
    t = as_float_tensor(np.asarray(points) if is_numpy else points, name).detach()
    check_shape(t, ("N", 3), name)
    if t.shape[0] == 0:
        raise ValueError(f"{name} is empty (0 points)")
    check_finite(t, name)
    return t, is_numpy


def _knn(p: torch.Tensor, k: int) -> torch.Tensor:
    """(N, k) indices of each point's k nearest points, itself first, then by increasing distance."""
    return knn_indices(p[None], k, sorted=True)[0]


def _out(t: torch.Tensor, is_numpy: bool):
    return t.cpu().numpy() if is_numpy else t


def pca_normals(points, k: int = 16, sigma_neighbour: int = 4):
    """Unoriented unit normals: the smallest-eigenvalue eigenvector of each point's kNN covariance.

    Args:
        points: (N, 3) array or tensor.
        k: neighbours per point, the point itself included.
        sigma_neighbour: neighbour j of point i has the weight ``exp(-|p_j - p_i|^2 / (2 sigma_i^2))``,
            sigma_i the distance to the ``sigma_neighbour``-th nearest neighbour; 0 gives equal weights.
            The weights keep the far wall of a thin plate from tilting the normal.

    Returns:
        (N, 3) unit normals of arbitrary sign, of the kind and dtype of ``points``.
    """
    p, is_numpy = _as_points(points)
    if not 0 <= sigma_neighbour < k:
        raise ValueError(f"sigma_neighbour must be in [0, k), got {sigma_neighbour} with k={k}")
    idx = _knn(p, k)
    nb = p[idx].double()  # (N, k, 3)
    d2 = ((nb - nb[:, :1]) ** 2).sum(dim=-1)  # (N, k) squared distances to the point itself
    if sigma_neighbour > 0:
        w = torch.exp(-d2 / (2 * d2[:, sigma_neighbour:sigma_neighbour + 1].clamp_min(1e-24)))
    else:
        w = torch.ones_like(d2)
    mean = (w[..., None] * nb).sum(dim=1, keepdim=True) / w.sum(dim=1)[:, None, None]
    c = nb - mean
    cov = (w[..., None] * c).transpose(1, 2) @ c  # (N, 3, 3) weighted covariances
    _, vecs = torch.linalg.eigh(cov)  # (N, 3, 3), columns by increasing eigenvalue
    return _out(vecs[..., 0].to(p.dtype), is_numpy)


def orient_normals(points, normals, ray_radius: float | None = None, max_occluders: int = 4096,
                   chunk_size: int = 64, vote_neighbours: int = 10, tilt: float = 60.0, far: float = 1.0,
                   seed: int = 0):
    """Flip normals to point outward, by ray visibility.

    From each point a fan of 5 rays leaves each side of its tangent plane (the normal and 4 rays
    tilted from it by ``tilt``); the side whose rays run farther in total before passing near
    another point is outward (ties: away from the centroid). A vote of tangent-plane neighbours then
    flips isolated normals that disagree with their surface patch.

    Args:
        points: (N, 3) array or tensor.
        normals: (N, 3) unit normals of any sign.
        ray_radius: a point within this distance of a ray blocks it; None: 1.2 x the median distance
            from a point to its 3rd nearest neighbour.
        max_occluders: rays are tested against at most this many points (a seeded random subset).
        chunk_size: points whose rays are traced at once (memory ~ chunk_size * max_occluders).
        vote_neighbours: neighbours in the final vote (0 skips the vote).
        tilt: angle in degrees between the normal and the 4 tilted rays.
        far: rays are capped at ``far`` x the bounding-box diagonal (what an escaping ray counts).
        seed: seed of the occluder subset.

    Returns:
        (N, 3) normals with their signs chosen, of the kind of ``normals``.
    """
    p, _ = _as_points(points)
    n, is_numpy = _as_points(normals, "normals")
    if n.shape != p.shape:
        raise ValueError(f"normals must have the shape of points {tuple(p.shape)}, got {tuple(n.shape)}")
    n = n.to(p.dtype)
    N = p.shape[0]
    if N > max_occluders:
        g = torch.Generator().manual_seed(seed)
        q = p[torch.randperm(N, generator=g)[:max_occluders].to(p.device)]
    else:
        q = p
    if ray_radius is None:
        kq = min(4, q.shape[0])
        nn3 = q[_knn(q, kq)[:, -1]]
        ray_radius = 1.2 * float(torch.linalg.vector_norm(nn3 - q, dim=1).median())
    rho2, dead2, cap = ray_radius**2, (0.1 * ray_radius) ** 2, far * float((q.amax(0) - q.amin(0)).norm())
    # Ray fans: the normal and 4 directions tilted from it by `tilt`, on each side.
    helper = torch.where(n[:, :1].abs() < 0.9, torch.tensor([1.0, 0.0, 0.0], dtype=p.dtype, device=p.device),
                         torch.tensor([0.0, 1.0, 0.0], dtype=p.dtype, device=p.device))
    u = torch.linalg.cross(helper, n)
    u = u / torch.linalg.vector_norm(u, dim=1, keepdim=True)
    v = torch.linalg.cross(n, u)
    ct, st = float(np.cos(np.deg2rad(tilt))), float(np.sin(np.deg2rad(tilt)))
    fan = [n] + [ct * n + st * w for w in (u, -u, v, -v)]
    dirs = torch.stack(fan + [-f for f in fan], dim=1)  # (N, 10, 3): 5 outward candidates, 5 inward
    free = torch.empty((N, dirs.shape[1]), dtype=p.dtype, device=p.device)
    qq = (q * q).sum(dim=1)
    for s in range(0, N, chunk_size):
        pc, nc, dc = p[s:s + chunk_size], n[s:s + chunk_size], dirs[s:s + chunk_size]
        # Everything from matrix products, without a (chunk, M, 3) tensor of differences.
        d2 = qq[None, :] - 2 * pc @ q.T + (pc * pc).sum(dim=1, keepdim=True)  # |q - p|^2, (c, M)
        sn = nc @ q.T - (nc * pc).sum(dim=1, keepdim=True)  # offset from the tangent plane, (c, M)
        t = dc @ q.T - (dc * pc[:, None, :]).sum(dim=-1, keepdim=True)  # along each ray, (c, 10, M)
        hit = (d2[:, None, :] - t * t < rho2) & (t > 0)  # (c, 10, M): q within rho of the ray, ahead
        # A blocker must also lie well off the point's tangent plane (more than 30 degrees), on the
        # side of the ray, so that neighbours on the point's own surface never block its rays.
        off_plane = sn * sn > dead2 + (d2 - sn * sn) / 3
        hit[:, :5] &= (off_plane & (sn > 0))[:, None, :]
        hit[:, 5:] &= (off_plane & (sn < 0))[:, None, :]
        free[s:s + chunk_size] = torch.where(hit, t, cap).amin(dim=-1).clamp_max(cap)
    out_free, in_free = free[:, :5].sum(dim=1), free[:, 5:].sum(dim=1)
    away = ((p - p.mean(dim=0)) * n).sum(dim=1) >= 0
    keep = torch.where(out_free == in_free, away, out_free > in_free)
    n = torch.where(keep[:, None], n, -n)
    if vote_neighbours > 0 and N > 1:
        # Tangent-plane vote: neighbours lying near the point's tangent plane with nearly parallel
        # normals are on the same surface patch, so should share its orientation.
        idx = _knn(p, min(vote_neighbours + 1, N))[:, 1:]
        rel = p[idx] - p[:, None, :]
        off_plane = (rel * n[:, None, :]).sum(dim=-1).abs()
        agree = (n[idx] * n[:, None, :]).sum(dim=-1)
        same_patch = (off_plane < 0.25 * ray_radius) & (agree.abs() > 0.9)
        votes = torch.where(same_patch, torch.sign(agree), torch.zeros_like(agree)).sum(dim=1)
        n = torch.where((votes < -1)[:, None], -n, n)
    return _out(n, is_numpy)


def estimate_normals(points, k: int = 16, orient: bool = True):
    """Unit normals for a point cloud: :func:`pca_normals` over ``k`` neighbours, then :func:`orient_normals`.

    Args:
        points: (N, 3) array or tensor, 3 <= N <= ``MAX_POINTS``, not all identical.
        k: neighbours per point, the point itself included.
        orient: choose outward signs; False keeps the eigen-solver's arbitrary signs.

    Returns:
        (N, 3) unit normals, of the kind and dtype of ``points``.

    Raises:
        ValueError: for more than ``MAX_POINTS`` points (subsample first, or provide normals).
    """
    p, is_numpy = _as_points(points)
    if p.shape[0] < 3:
        raise ValueError(f"points must hold at least 3 points to estimate normals, got {p.shape[0]}")
    if p.shape[0] > MAX_POINTS:
        raise ValueError(
            f"points holds {p.shape[0]} points; normal estimation takes time N^2 and accepts at most "
            f"{MAX_POINTS} (cuboidlib._checks.{MAX_POINTS.name}): subsample first (for files: "
            "load_point_cloud(path, n_points=4096)) or provide normals"
        )
    if float((p.amax(dim=0) - p.amin(dim=0)).max()) == 0.0:
        raise ValueError("points are all identical; no normals can be estimated")
    p = (p.double() - p.double().mean(dim=0)).to(p.dtype)  # normals do not move; precision far from 0 does
    normals = pca_normals(p, min(k, p.shape[0]), sigma_neighbour=min(4, p.shape[0] - 1))
    if orient:
        normals = orient_normals(p, normals)
    return _out(normals, is_numpy)


def normal_errors(estimated, truth) -> tuple:
    """Per-point errors of estimated normals against true ones.

    Args:
        estimated: (N, 3) normals (normalised here).
        truth: (N, 3) true normals.

    Returns:
        ``(angle_deg, flipped)``, each (N,), of the kind of ``estimated``: the angle in degrees
        between the two lines, in [0, 90] (judges PCA), and bool ``dot < 0`` (judges orientation).
    """
    e, is_numpy = _as_points(estimated, "estimated")
    t, _ = _as_points(truth, "truth")
    if e.shape != t.shape:
        raise ValueError(f"estimated and truth must have the same shape, got {tuple(e.shape)} and {tuple(t.shape)}")
    e = e / torch.linalg.vector_norm(e, dim=1, keepdim=True)
    t = t.to(e.dtype) / torch.linalg.vector_norm(t, dim=1, keepdim=True)
    dot = (e * t).sum(dim=1)
    angle = torch.rad2deg(torch.arccos(dot.abs().clamp(max=1.0)))
    return _out(angle, is_numpy), _out(dot < 0, is_numpy)
