"""A non-learned baseline: cluster the points, then fit one oriented box per cluster.

It is what one would try first without the paper: k-means on position and normal splits a shape
into K groups, and each group gets its principal-axis bounding box. It has no notion of structure
shared across a category, so its cuboid indices carry no part correspondence; the course scores it
with the same metrics as the network (:mod:`cuboidlib.metrics`) at the same number of primitives.

Shapes: points and normals (N, 3) for one shape; results as :class:`cuboidlib.geometry.Cuboids`
with a batch of one.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ._checks import as_float_tensor, check_finite, check_shape
from .geometry import Cuboids, rotation_matrix_to_quaternion

__all__ = ["kmeans", "oriented_bounding_box", "ClusterBoxes", "fit_cluster_boxes"]


def kmeans(features, k: int, iterations: int = 50, generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Lloyd's k-means with k-means++ seeding.

    features: (N, D). Returns (labels (N,) long, centroids (k, D)). Deterministic given ``generator``.
    A cluster that loses all its points keeps its previous centroid.
    """
    x = as_float_tensor(features, "features")
    check_shape(x, ("N", "D"), "features")
    check_finite(x, "features")
    n = x.shape[0]
    if not (isinstance(k, int) and 1 <= k <= n):
        raise ValueError(f"k must be an integer between 1 and the number of points {n}, got {k!r}")
    first = int(torch.randint(n, (1,), generator=generator))
    centroids = [x[first]]
    nearest = (x - x[first]).square().sum(dim=1)
    for _ in range(1, k):  # k-means++: next seed with probability proportional to the squared distance
        weights = nearest if nearest.sum() > 0 else torch.ones_like(nearest)
        pick = int(torch.multinomial(weights, 1, generator=generator))
        centroids.append(x[pick])
        nearest = torch.minimum(nearest, (x - x[pick]).square().sum(dim=1))
    c = torch.stack(centroids)
    labels = torch.cdist(x, c).argmin(dim=1)
    for _ in range(iterations):
        sums = torch.zeros_like(c).index_add_(0, labels, x)
        counts = torch.bincount(labels, minlength=k).to(x.dtype)[:, None]
        c = torch.where(counts > 0, sums / counts.clamp_min(1), c)
        new_labels = torch.cdist(x, c).argmin(dim=1)
        if torch.equal(new_labels, labels):
            break
        labels = new_labels
    return labels, c


def oriented_bounding_box(points, min_half_size: float = 1e-3) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Principal-axis bounding box of a point set.

    points: (n, 3), n >= 1. The box axes are the eigenvectors of the covariance (a right-handed
    frame), its extent the range of the points along each axis. Returns (center (3,),
    quaternion (4,) (w, x, y, z), half_sizes (3,)), half sizes at least ``min_half_size`` so a flat
    or single-point cluster still gives a valid cuboid.
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


@dataclass
class ClusterBoxes:
    """Result of :func:`fit_cluster_boxes`: the boxes (batch of one) and each point's cluster index (N,)."""

    cuboids: Cuboids
    labels: torch.Tensor


def fit_cluster_boxes(points, normals, num_boxes: int, normal_weight: float = 0.2, iterations: int = 50,
                      seed: int = 0) -> ClusterBoxes:
    """The k-means + oriented-box baseline for one shape.

    points, normals: (N, 3). k-means runs on the features [p, normal_weight * n] (positions of a
    unit-diagonal shape span about 1, so the default lets normals split a cluster only where
    orientation changes sharply), then each cluster gets :func:`oriented_bounding_box`.
    Returns :class:`ClusterBoxes` with ``num_boxes`` existing cuboids (fewer if there are fewer
    distinct points).
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
    boxes = [oriented_bounding_box(p[labels == c]) for c in used.tolist()]
    centers, quats, halves = (torch.stack(parts)[None] for parts in zip(*boxes))
    relabel = torch.full((num_boxes,), -1, dtype=torch.long)
    relabel[used] = torch.arange(len(used))
    return ClusterBoxes(Cuboids(centers, quats, halves), relabel[labels])
