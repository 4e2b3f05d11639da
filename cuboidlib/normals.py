"""Normal estimation for point clouds that come without normals.

The paper's losses need a normal per point (the distance loss samples along it, Sec. 3.3.1) and its
data come with normals; files a user brings often do not. :func:`estimate_normals` gives each point
a unit normal in two steps:

1. **PCA** (:func:`pca_normals`): the normal is the eigenvector of the smallest eigenvalue of the
   (Gaussian-weighted) covariance of the point's ``k`` nearest neighbours (itself included). This
   fixes the normal's line but not its sign.
2. **Outward orientation** (:func:`orient_normals`), visibility based: from each point cast a fan
   of 5 rays on each side of its tangent plane (along ``+n`` and tilted from it by 60 degrees
   towards 4 tangent directions; the same about ``-n``) and find how far each ray runs before it
   passes within ``ray_radius`` of another point (points near the point's own tangent plane never
   block). Inside a closed surface the rays soon hit the opposite wall of the part; outside they
   escape or travel to another part. The side whose rays run farther in total (each capped at the
   bounding-box diagonal) is outward; on a tie the normal is turned away from the centroid. A
   final vote over each point's tangent-plane neighbours flips isolated normals that disagree
   with their surface patch.

The outcome is judged with :func:`normal_errors` against known normals (``benchmarks/
bench_shapes.py`` measures it on the procedural shapes). Points are (N, 3) numpy arrays or torch
tensors (the result has the input's kind); the k-nearest-neighbour search is the exact, block-wise one
of :mod:`cuboidlib.neighbors`, so memory is bounded and time O(N^2): fine for the few thousand points
of a training shape; :func:`estimate_normals` refuses more than ``MAX_POINTS`` points (subsample first).
"""

from __future__ import annotations

import numpy as np
import torch

from ._checks import as_float_tensor, check_finite, check_shape
from .neighbors import knn_indices

# Largest cloud estimate_normals accepts: its cost grows as N^2 (about 40 s for 20 000 points on one
# laptop core); a larger cloud should be subsampled first (load_point_cloud(..., n_points=...)).
MAX_POINTS = 20_000

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
    """Unoriented unit normals (N, 3): smallest-eigenvalue eigenvector of each kNN covariance.

    Neighbour ``j`` of point ``i`` has the Gaussian weight ``exp(-|p_j - p_i|^2 / (2 sigma_i^2))``
    with ``sigma_i`` the distance to its ``sigma_neighbour``-th nearest neighbour (0: equal weights).
    The weights keep the far wall of a thin plate, which enters a sparse neighbourhood, from
    tilting the normal.
    """
    p, is_numpy = _as_points(points)
    if not 0 <= sigma_neighbour < k:
        raise ValueError(f"sigma_neighbour must be in [0, k), got {sigma_neighbour} with k={k}")
    idx = _knn(p, k)
    nb = p[idx].double()  # (N, k, 3)
    d2 = ((nb - nb[:, :1]) ** 2).sum(dim=-1)
    if sigma_neighbour > 0:
        w = torch.exp(-d2 / (2 * d2[:, sigma_neighbour:sigma_neighbour + 1].clamp_min(1e-24)))
    else:
        w = torch.ones_like(d2)
    mean = (w[..., None] * nb).sum(dim=1, keepdim=True) / w.sum(dim=1)[:, None, None]
    c = nb - mean
    cov = (w[..., None] * c).transpose(1, 2) @ c
    _, vecs = torch.linalg.eigh(cov)
    return _out(vecs[..., 0].to(p.dtype), is_numpy)


def orient_normals(points, normals, ray_radius: float | None = None, max_occluders: int = 4096,
                   chunk_size: int = 64, vote_neighbours: int = 10, tilt: float = 60.0, far: float = 1.0,
                   seed: int = 0):
    """Flip normals (N, 3) to point outward, by ray visibility (see the module docstring).

    Args:
        points: (N, 3) points; normals: (N, 3) unit normals of any sign.
        ray_radius: a point blocks a ray when it lies within this distance of it; default 1.2 x the
            median distance from a point to its 3rd nearest neighbour.
        max_occluders: rays are tested against at most this many points (a seeded random subset
            of larger clouds), bounding time and memory.
        chunk_size: rays per block (memory ~ chunk_size * max_occluders).
        vote_neighbours: neighbours in the final tangent-plane vote (0 disables the vote).
        tilt: angle in degrees between the normal and the 4 tilted rays of each fan.
        far: rays are capped at ``far`` x the bounding-box diagonal (a ray that escapes counts
            this much).
        seed: seed of the occluder subset.

    Returns:
        The normals with their signs chosen, same kind (numpy/torch) as ``normals``.
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
        hit = (d2[:, None, :] - t * t < rho2) & (t > 0)
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
    """Unit normals (N, 3) for points (N, 3): PCA over ``k`` neighbours, oriented outward.

    With ``orient=False`` the signs are those of the eigen-solver (arbitrary).
    """
    p, is_numpy = _as_points(points)
    if p.shape[0] < 3:
        raise ValueError(f"points must hold at least 3 points to estimate normals, got {p.shape[0]}")
    if p.shape[0] > MAX_POINTS:
        raise ValueError(
            f"points holds {p.shape[0]} points; normal estimation takes time N^2 and accepts at most "
            f"{MAX_POINTS}: subsample first (for files: load_point_cloud(path, n_points=4096)) or provide normals"
        )
    if float((p.amax(dim=0) - p.amin(dim=0)).max()) == 0.0:
        raise ValueError("points are all identical; no normals can be estimated")
    p = (p.double() - p.double().mean(dim=0)).to(p.dtype)  # normals do not move; precision far from 0 does
    normals = pca_normals(p, min(k, p.shape[0]), sigma_neighbour=min(4, p.shape[0] - 1))
    if orient:
        normals = orient_normals(p, normals)
    return _out(normals, is_numpy)


def normal_errors(estimated, truth) -> tuple:
    """Per-point errors of estimated normals (N, 3) against true unit normals (N, 3).

    Returns ``(angle_deg, flipped)``: the unoriented angle in degrees between the two lines
    (0..90, judges PCA) and a boolean "points the wrong way" (``dot < 0``, judges orientation).
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
