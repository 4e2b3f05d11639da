"""A non-learned baseline: k-means on position and normal, then one principal-axis box per cluster.

What one would try first without the paper. It knows no structure shared across a category, so its
cuboid indices carry no part correspondence; the course scores it with the network's metrics
(:mod:`cuboidlib.metrics`) at the same number of primitives. :func:`kmeans` also starts the per-shape fit.
"""

from __future__ import annotations

import torch

from ._checks import as_float_tensor, check_finite, check_shape
from .geometry import Cuboids
from .results import AbstractionBatch
from .rotations import rotation_matrix_to_quaternion

__all__ = ["kmeans", "oriented_bounding_box", "fit_cluster_boxes"]


def kmeans(features, k: int, iterations: int = 50,
           generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Lloyd's k-means with k-means++ seeding, for one point set or a batch of them.

    A cluster that loses all its points keeps its centroid; the iterations stop once no label changes.

    Args:
        features: (N, D), or (B, N, D) for B independent sets; N >= k.
        k: the number of clusters.
        iterations: at most this many Lloyd iterations.
        generator: the only source of randomness, the seeds (None: torch's global one).

    Returns:
        (labels, centroids): (N,) int64 and (k, D), or (B, N) and (B, k, D).

    Example::

        >>> labels, centroids = kmeans(torch.rand(100, 3), 4, generator=torch.Generator().manual_seed(0))
        >>> labels.shape, centroids.shape
        (torch.Size([100]), torch.Size([4, 3]))
    """
    x = as_float_tensor(features, "features")
    single = x.dim() == 2
    if single:
        x = x[None]
    check_shape(x, ("B", "N", "D"), "features")
    check_finite(x, "features")
    b, n, _ = x.shape
    if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= n:
        raise ValueError(f"k must be an integer between 1 and the number of points {n}, got {k!r}")
    batch = torch.arange(b, device=x.device)
    first = torch.randint(n, (b,), generator=generator).to(x.device)
    centroids = [x[batch, first]]
    nearest = (x - centroids[0][:, None]).square().sum(-1)  # (B, N) squared distance to the nearest seed
    for _ in range(1, k):  # k-means++: next seed with probability proportional to the squared distance
        weights = torch.where(nearest.sum(-1, keepdim=True) > 0, nearest, torch.ones_like(nearest))
        pick = torch.multinomial(weights.cpu(), 1, generator=generator)[:, 0].to(x.device)
        centroids.append(x[batch, pick])
        nearest = torch.minimum(nearest, (x - centroids[-1][:, None]).square().sum(-1))
    c = torch.stack(centroids, dim=1)  # (B, k, D)
    labels = torch.cdist(x, c).argmin(dim=-1)  # (B, N)
    for _ in range(iterations):
        one_hot = torch.nn.functional.one_hot(labels, k).to(x.dtype)  # (B, N, k)
        counts = one_hot.sum(dim=1)[..., None]  # (B, k, 1)
        c = torch.where(counts > 0, torch.einsum("bnk,bnd->bkd", one_hot, x) / counts.clamp_min(1), c)
        new_labels = torch.cdist(x, c).argmin(dim=-1)
        if torch.equal(new_labels, labels):
            break
        labels = new_labels
    return (labels[0], c[0]) if single else (labels, c)


def oriented_bounding_box(points, min_half_size: float = 1e-3) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Principal-axis bounding box of a point set.

    The axes are the covariance's eigenvectors (a right-handed frame; the identity below 3 points), the
    extent the points' range along each axis.

    Args:
        points: (n, 3), n >= 1.
        min_half_size: lower bound of the half sizes, so that a flat or one-point cluster is a valid cuboid.

    Returns:
        (center (3,), quaternion (4,) (w, x, y, z), half_sizes (3,)).
    """
    p = as_float_tensor(points, "points")
    check_shape(p, ("n", 3), "points")
    if p.shape[0] == 0:
        raise ValueError("points is empty; a bounding box needs at least one point")
    mean = p.mean(dim=0)
    centred = p - mean
    if p.shape[0] >= 3:
        _, axes = torch.linalg.eigh(centred.T @ centred)
        axes = axes.flip(-1)  # largest spread first
    else:
        axes = torch.eye(3, dtype=p.dtype)
    if torch.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    local = centred @ axes
    lo, hi = local.amin(dim=0), local.amax(dim=0)
    center = mean + axes @ ((lo + hi) / 2)
    half = ((hi - lo) / 2).clamp_min(min_half_size)
    return center, rotation_matrix_to_quaternion(axes, validate=False), half


def fit_cluster_boxes(points, normals, num_boxes: int, normal_weight: float = 0.2, iterations: int = 50,
                      seed: int = 0) -> AbstractionBatch:
    """The k-means + oriented-box baseline for one shape: :func:`kmeans`, then :func:`oriented_bounding_box`.

    Args:
        points, normals: (N, 3).
        num_boxes: K, the clusters and cuboid slots.
        normal_weight: k-means runs on [p, normal_weight * n]; on a shape of diagonal 1 the default lets
            the normals split a cluster only where the orientation changes sharply.
        iterations: at most this many k-means iterations.
        seed: seed of k-means.

    Returns:
        An :class:`~cuboidlib.results.AbstractionBatch` of one shape: K slots, those of non-empty clusters
        existing, and labels (1, N), each point's cluster.
    """
    p = as_float_tensor(points, "points")
    n = as_float_tensor(normals, "normals").to(p)
    check_shape(p, ("N", 3), "points")
    if n.shape != p.shape:
        raise ValueError(f"normals must have the shape of points {tuple(p.shape)}, got {tuple(n.shape)}")
    check_finite(p, "points")
    check_finite(n, "normals")
    if len(p) == 0 or float((p.amax(0) - p.amin(0)).max()) == 0.0:
        raise ValueError(f"points: {len(p)} point(s), all identical or none; boxes need a shape with extent")
    g = torch.Generator().manual_seed(seed)
    labels, _ = kmeans(torch.cat([p, normal_weight * n], dim=1), num_boxes, iterations, generator=g)
    used = torch.unique(labels)
    centers = torch.zeros(num_boxes, 3, dtype=p.dtype)
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=p.dtype).repeat(num_boxes, 1)
    halves = torch.full((num_boxes, 3), 1e-3, dtype=p.dtype)
    exists = torch.zeros(num_boxes, dtype=torch.bool)
    for c in used.tolist():
        centers[c], quats[c], halves[c] = oriented_bounding_box(p[labels == c])
        exists[c] = True
    return AbstractionBatch(Cuboids(centers[None], quats[None], halves[None], exists[None]), labels[None])
