"""Applications of a trained network (Sec. 4.4): generation (Fig. 12), interpolation (Fig. 13), structural
clustering (Fig. 14), abstraction of point clouds, and loading the committed networks by name.

One file, because every application runs the same encode / decode in evaluation mode.

All use the network's ``encode`` / ``decode`` in evaluation mode (running BatchNorm statistics, no
gradients), in the normalised coordinates it was trained in. A cuboid exists when its probability exceeds
``threshold`` (0.5, as :mod:`cuboidlib.evaluation`), and every shape keeps at least its most probable one.
Pitfall: a network trained with centroid centres (``LossConfig(centers_from_allocation=True)``, the committed
ones) never trains its translation head by gradient; ``cuboidlib train --release`` fits it afterwards
(:func:`cuboidlib.release.fit_translation_head`), which generation and interpolation need.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, NamedTuple

import numpy as np
import torch

from ._checks import MAX_SHAPES, as_float_tensor, check_finite, check_shape, check_size
from .checkpoint import load_model
from .geometry import Cuboids
from .losses import allocation_weighted_centers
from .results import AbstractionBatch
from .model import CuboidAbstractionNet

__all__ = [
    "existence_mask",
    "decode_latents",
    "generate_shapes",
    "encode_shapes",
    "latent_statistics",
    "latent_distance",
    "check_latent_statistics",
    "abstract_shapes",
    "cuboid_step_changes",
    "Interpolation",
    "interpolate_codes",
    "interpolate_latents",
    "cluster_by_existence",
    "ExistenceGroup",
    "existence_groups",
    "purity",
    "adjusted_rand_index",
    "CHECKPOINT_DIR_ENV",
    "checkpoint_dir",
    "committed_checkpoints",
    "resolve_checkpoint",
    "load_trained_model",
]

#: Environment variable that overrides the folder of committed checkpoints.
CHECKPOINT_DIR_ENV = "CUBOIDLIB_CHECKPOINTS"


# ----------------------------------------------------------------------------------------------
# Decoding
# ----------------------------------------------------------------------------------------------


def existence_mask(exist_probs: torch.Tensor, threshold: float = 0.5) -> torch.Tensor:
    """Existing cuboids from existence probabilities: p > threshold, at least one per shape.

    The rule :func:`cuboidlib.evaluation.predict_cuboids` scores networks with.

    Args:
        exist_probs: (B, M) probabilities in [0, 1].
        threshold: in [0, 1).

    Returns:
        (B, M) bool; a shape with no probability above ``threshold`` keeps only its most probable cuboid.
    """
    probs = as_float_tensor(exist_probs, "exist_probs")
    check_shape(probs, ("B", "M"), "exist_probs")
    if not 0 <= threshold < 1:
        raise ValueError(f"threshold must lie in [0, 1), got {threshold!r}")
    return _existence_mask(probs, threshold)


def _existence_mask(probs: torch.Tensor, threshold: float) -> torch.Tensor:
    exists = probs > threshold  # (B, M)
    empty = ~exists.any(dim=1)
    exists[empty, probs[empty].argmax(dim=1)] = True
    return exists


@contextmanager
def _evaluating(model: CuboidAbstractionNet) -> Iterator[None]:
    """Evaluation mode without gradients; the model's previous mode is restored afterwards."""
    if not isinstance(model, CuboidAbstractionNet):
        raise TypeError(f"model must be a CuboidAbstractionNet, got {type(model).__name__}")
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            yield
    finally:
        model.train(was_training)


def decode_latents(model: CuboidAbstractionNet, z, threshold: float = 0.5) -> AbstractionBatch:
    """Decode latent codes into cuboids with existence (Sec. 3.2); the same z gives the same cuboids.

    Args:
        model: the network.
        z: (B, latent_dim) latent codes.
        threshold: existence threshold of :func:`existence_mask`.

    Returns:
        An :class:`AbstractionBatch` of B shapes (labels and W are None).
    """
    with _evaluating(model):
        pred = model.decode(z)
        z = as_float_tensor(z, "z").to(pred.centers)
        probs = pred.exist_probs
        exists = existence_mask(probs, threshold)
        cuboids = Cuboids(pred.centers, pred.quaternions, pred.half_sizes, exists)
    return AbstractionBatch(cuboids, exist_probs=probs, z=z)


def generate_shapes(
    model: CuboidAbstractionNet,
    n_shapes: int,
    generator: torch.Generator | None = None,
    threshold: float = 0.5,
) -> AbstractionBatch:
    """Shape generation (Sec. 4.4, Fig. 12): decode ``n_shapes`` codes z ~ N(0, I).

    Args:
        model: the network.
        n_shapes: B, the number of shapes.
        generator: a CPU generator the codes are drawn from (seed it to repeat a draw); None: torch's global one.
        threshold: existence threshold of :func:`existence_mask`.

    Returns:
        An :class:`AbstractionBatch` of B shapes.
    """
    if isinstance(n_shapes, bool) or not isinstance(n_shapes, int) or n_shapes < 1:
        raise ValueError(f"n_shapes must be a positive integer, got {n_shapes!r}")
    check_size(n_shapes, "n_shapes", MAX_SHAPES)
    z = torch.randn(n_shapes, model.config.latent_dim, generator=generator)
    return decode_latents(model, z, threshold)


def _as_batch(points, name: str) -> torch.Tensor:
    p = as_float_tensor(np.asarray(points) if not isinstance(points, torch.Tensor) else points, name)
    if p.dim() == 2:
        p = p[None]
    check_shape(p, ("B", "N", 3), f"{name} (or (N, 3) for one shape)")
    if p.shape[1] == 0:
        raise ValueError(f"{name} is empty (N = 0); the network needs points")
    check_finite(p, name)
    # The network only knows shapes normalised as in training (box centre 0, diagonal 1): refuse others
    lo, hi = p.amin(dim=1), p.amax(dim=1)
    diagonal, centre = (hi - lo).norm(dim=-1), ((hi + lo) / 2).norm(dim=-1)
    bad = (diagonal < 0.25) | (diagonal > 4.0) | (centre > 0.5)
    if bad.any():
        b = int(torch.nonzero(bad)[0])
        raise ValueError(
            f"{name}: shape {b} is not normalised like the training shapes (bounding-box diagonal "
            f"{float(diagonal[b]):.3g}, centre {float(centre[b]):.3g} from the origin; expected about 1 and 0); "
            "normalise it first with cuboidlib.normalization.normalize (load_point_cloud does it)"
        )
    return p


def encode_shapes(model: CuboidAbstractionNet, points, normals=None) -> torch.Tensor:
    """Latent means mu of point clouds (Sec. 3.1).

    Args:
        model: the network.
        points: (B, N, 3) or (N, 3), normalised like the training shapes (:mod:`cuboidlib.normalization`).
        normals: the same shape as points, for a network that reads them (``ModelConfig.input_normals`` not "none").

    Returns:
        (B, latent_dim) mu (B = 1 for one cloud).
    """
    with _evaluating(model):
        mu, _ = model.encode(_as_batch(points, "points"), _normals_like(normals, points))
    return mu


def latent_statistics(model: CuboidAbstractionNet, points, normals=None, batch_size: int = 64) -> dict[str, torch.Tensor]:
    """Where a network puts the shapes it knows: the mean and spread of its latent means mu over a set of shapes.

    A Gaussian fitted to the codes of the training split, stored in a released checkpoint, so that
    :func:`latent_distance` can tell a shape unlike the training shapes (a network used off its category).

    Args:
        model: the network.
        points: (S, N, 3) normalised shapes, S > latent_dim (the training split).
        normals: (S, N, 3), for a network that reads them.
        batch_size: shapes per forward pass.

    Returns:
        {"mean": (D,) float64, "whitening": (D, D) float64 W with W^T W = (C + eps I)^-1, where C is the
        codes' covariance and eps 1e-3 of its mean variance, "shapes": () int64 S}.
    """
    p = _as_batch(points, "points")
    if p.shape[0] <= model.config.latent_dim:
        raise ValueError(f"latent_statistics needs more shapes than the {model.config.latent_dim} latent dimensions, "
                         f"got {p.shape[0]}")
    n = _normals_like(normals, points)
    mu = torch.cat([encode_shapes(model, p[s:s + batch_size], None if n is None else n[s:s + batch_size])
                    for s in range(0, p.shape[0], batch_size)]).double().cpu()
    covariance = torch.cov(mu.T)
    covariance += 1e-3 * covariance.diagonal().mean() * torch.eye(mu.shape[1], dtype=torch.float64)
    lower = torch.linalg.cholesky(covariance)  # C = L L^T, so (x - m)^T C^-1 (x - m) = |L^-1 (x - m)|^2
    whitening = torch.linalg.solve_triangular(lower, torch.eye(mu.shape[1], dtype=torch.float64), upper=False)
    return {"mean": mu.mean(dim=0), "whitening": whitening, "shapes": torch.tensor(mu.shape[0])}


def latent_distance(mu, statistics: dict[str, torch.Tensor]) -> torch.Tensor:
    """The Mahalanobis distance of latent codes from the codes of a network's training shapes.

    About sqrt(D) for a shape like the training shapes (D = latent_dim, 64 for the course's networks); much
    more for a shape of another kind (measured in ``benchmarks/bench_warning.py``).

    Args:
        mu: (B, D) or (D,) latent means (:func:`encode_shapes`).
        statistics: :func:`latent_statistics` of the training shapes.

    Returns:
        (B,) float64 |W (mu - mean)|.
    """
    check_latent_statistics(statistics)
    mean, whitening = statistics["mean"], statistics["whitening"]
    mu = as_float_tensor(mu, "mu", dtype=torch.float64)
    mu = mu.unsqueeze(0) if mu.dim() == 1 else mu
    check_shape(mu, ("B", mean.shape[0]), "mu")
    return ((mu.cpu() - mean) @ whitening.T).norm(dim=-1)


def check_latent_statistics(statistics, latent_dim: int | None = None, where: str = "statistics") -> None:
    """Refuse latent statistics that :func:`latent_distance` cannot use (a damaged or hand-edited checkpoint).

    Args:
        statistics: what :func:`latent_statistics` returns: "mean" (D,) and "whitening" (D, D), finite.
        latent_dim: D, the network's latent size, or None to take the mean's.
        where: names them in the message (e.g. "chair.pt: latent_statistics").

    Raises:
        ValueError: naming the missing or malformed entry and what was expected.
    """
    if not isinstance(statistics, dict):
        raise ValueError(f"{where} must be a dict with 'mean' and 'whitening' (cuboidlib.applications."
                         f"latent_statistics), got {type(statistics).__name__}")
    missing = [key for key in ("mean", "whitening") if key not in statistics]
    if missing:
        raise ValueError(f"{where} lack {missing} (they hold {sorted(statistics)}); expected 'mean' (D,) and "
                         "'whitening' (D, D) as cuboidlib.applications.latent_statistics writes them "
                         "(cuboidlib.release.add_latent_statistics adds them again to a checkpoint)")
    mean, whitening = statistics["mean"], statistics["whitening"]
    if not all(isinstance(t, torch.Tensor) and not t.is_meta for t in (mean, whitening)):
        raise ValueError(f"{where}: 'mean' and 'whitening' must be tensors with values")
    d = latent_dim if latent_dim is not None else (mean.shape[0] if mean.dim() == 1 else -1)
    if mean.shape != (d,) or whitening.shape != (d, d):
        raise ValueError(f"{where}: 'mean' has shape {tuple(mean.shape)} and 'whitening' {tuple(whitening.shape)}; "
                         f"expected ({d},) and ({d}, {d}) for the latent size {d}")
    if not (torch.isfinite(mean).all() and torch.isfinite(whitening).all()):
        raise ValueError(f"{where}: 'mean' or 'whitening' holds NaN or infinite values")


def _normals_like(normals, points):
    """normals as a (B, N, 3) batch like ``points`` ((N, 3) -> (1, N, 3)), or None."""
    if normals is None:
        return None
    n = normals if isinstance(normals, torch.Tensor) else torch.as_tensor(np.asarray(normals))
    return n.unsqueeze(0) if n.dim() == 2 else n


def abstract_shapes(
    model: CuboidAbstractionNet,
    points,
    threshold: float = 0.5,
    centers_from_allocation: bool = False,
    batch_size: int = 32,
    normals=None,
) -> AbstractionBatch:
    """Cuboid abstraction and segmentation of point clouds by the network (z = mu, Sec. 3).

    Args:
        model: the network.
        points: (B, N, 3) or (N, 3), normalised like the training shapes.
        threshold: existence threshold of :func:`existence_mask`.
        centers_from_allocation: place every cuboid at the allocation-weighted centroid of its points
            (:func:`cuboidlib.losses.allocation_weighted_centers`), for networks trained that way.
        batch_size: shapes per forward pass (the result does not depend on it).
        normals: the same shape as points, for a network that reads them (``ModelConfig.input_normals`` not "none").

    Returns:
        An :class:`AbstractionBatch` with labels (B, N), the argmax of W (B, N, M) over the existing cuboids.
    """
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    if not 0 <= threshold < 1:
        raise ValueError(f"threshold must lie in [0, 1), got {threshold!r}")
    p = _as_batch(points, "points").to(next(model.parameters()))
    n = _normals_like(normals, points)
    n = None if n is None else n.to(p)
    parts = [_abstract_batch(model, p[s:s + batch_size], threshold, centers_from_allocation,
                             None if n is None else n[s:s + batch_size])
             for s in range(0, p.shape[0], batch_size)]
    return parts[0] if len(parts) == 1 else AbstractionBatch.concatenate(parts)


def _abstract_batch(model, p: torch.Tensor, threshold: float, centers_from_allocation: bool,
                    n: torch.Tensor | None) -> AbstractionBatch:
    """:func:`abstract_shapes` of one batch of checked inputs."""
    with _evaluating(model):
        out = model(p, n, sample_latent=False)
        probs = out.exist_probs
        exists = _existence_mask(probs, threshold)
        centers = allocation_weighted_centers(out.W, p) if centers_from_allocation else out.centers
        cuboids = Cuboids(centers, out.quaternions, out.half_sizes, exists)
        labels = out.W.masked_fill(~exists[:, None, :], -1.0).argmax(dim=-1)  # (B, N)
    return AbstractionBatch(cuboids, labels, out.W, probs, out.z)


# ----------------------------------------------------------------------------------------------
# Interpolation
# ----------------------------------------------------------------------------------------------


def cuboid_step_changes(cuboids: Cuboids) -> tuple[torch.Tensor, torch.Tensor]:
    """How much the cuboids change between neighbouring shapes of a sequence.

    A cuboid's change is the largest distance one of its 8 corners moves: the displacement is affine over
    the unit cube, so no point moves farther. It combines centre, rotation and size in the shape's units.

    Args:
        cuboids: (K, M) cuboids, K >= 2 shapes in sequence.

    Returns:
        ``(step_change, existence_changes)``, (K - 1,) each: the largest change over the cuboids that exist
        in both neighbours (0 if none does), and the number (long) of cuboids that appear or disappear.
    """
    if not isinstance(cuboids, Cuboids):
        raise TypeError(f"cuboids must be a Cuboids sequence (K shapes), got {type(cuboids).__name__}")
    if cuboids.batch_size < 2:
        raise ValueError(f"a sequence of at least 2 shapes is needed, got {cuboids.batch_size}")
    corners = cuboids.corners()  # (K, M, 8, 3)
    moves = (corners[1:] - corners[:-1]).norm(dim=-1).amax(dim=-1)  # (K - 1, M)
    exists = cuboids.existing()
    both = exists[1:] & exists[:-1]
    step_change = torch.where(both, moves, torch.zeros_like(moves)).amax(dim=-1)
    return step_change, (exists[1:] != exists[:-1]).sum(dim=-1)


@dataclass
class Interpolation:
    """A decoded interpolation path of K steps (Sec. 4.4, Fig. 13).

    Attributes:
        t: (K,) interpolation weights from 0 to 1.
        shapes: K decoded shapes, ``shapes.z[k] = (1 - t_k) z_a + t_k z_b``.
        step_change, existence_changes: (K - 1,) each, from :func:`cuboid_step_changes`.
    """

    t: torch.Tensor
    shapes: AbstractionBatch
    step_change: torch.Tensor
    existence_changes: torch.Tensor

    @property
    def max_step_change(self) -> float:
        """The largest distance any point of an existing cuboid moves between neighbouring steps."""
        return float(self.step_change.max())

    @property
    def evenness(self) -> float:
        """Largest step change over the mean: 1 when every step moves the cuboids equally far, large when the
        path jumps somewhere (inf if no cuboid moves at all)."""
        mean = float(self.step_change.mean())
        return self.max_step_change / mean if mean > 0 else float("inf")


def interpolate_codes(
    model: CuboidAbstractionNet, z_a, z_b, steps: int = 8, threshold: float = 0.5
) -> Interpolation:
    """Decode the straight line z_k = (1 - t_k) z_a + t_k z_b, t_k = k / (steps - 1), between two codes.

    Each step is decoded as a batch of one, so the first and last steps are bitwise the decodings of
    z_a and z_b.

    Args:
        model: the network.
        z_a, z_b: (latent_dim,) or (1, latent_dim) latent codes.
        steps: K >= 2, the number of steps, ends included.
        threshold: existence threshold of :func:`existence_mask`.

    Returns:
        The :class:`Interpolation` of K steps.
    """
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 2:
        raise ValueError(f"steps must be an integer >= 2, got {steps!r}")
    check_size(steps, "steps", MAX_SHAPES, "shapes")
    codes = []
    for name, z in (("z_a", z_a), ("z_b", z_b)):
        z = as_float_tensor(z, name)
        if z.dim() == 2 and z.shape[0] == 1:
            z = z[0]
        check_shape(z, (model.config.latent_dim,), name)
        check_finite(z, name)
        codes.append(z)
    z_a, z_b = codes
    t = torch.linspace(0.0, 1.0, steps, dtype=z_a.dtype)
    t[0], t[-1] = 0.0, 1.0
    shapes = AbstractionBatch.concatenate([decode_latents(model, ((1 - tk) * z_a + tk * z_b)[None], threshold) for tk in t])
    step_change, flips = cuboid_step_changes(shapes.cuboids)
    return Interpolation(t, shapes, step_change, flips)


def interpolate_latents(
    model: CuboidAbstractionNet, points_a, points_b, steps: int = 8, threshold: float = 0.5,
    normals_a=None, normals_b=None,
) -> Interpolation:
    """Shape interpolation (Sec. 4.4, Fig. 13): encode two point clouds, decode the line between their means.

    Args:
        model: the network.
        points_a, points_b: (N, 3) each (N may differ), normalised like the training shapes.
        steps, threshold: as for :func:`interpolate_codes`.
        normals_a, normals_b: their (N, 3) normals, for a network that reads them
            (``ModelConfig.input_normals`` not "none").

    Returns:
        The :class:`Interpolation` from mu_a to mu_b.
    """
    mu_a = encode_shapes(model, _single(points_a, "points_a"), normals_a)
    mu_b = encode_shapes(model, _single(points_b, "points_b"), normals_b)
    return interpolate_codes(model, mu_a[0], mu_b[0], steps, threshold)


def _single(points, name: str) -> torch.Tensor:
    p = _as_batch(points, name)
    if p.shape[0] != 1:
        raise ValueError(f"{name} must be ONE point cloud (N, 3), got a batch of {p.shape[0]}")
    return p


# ----------------------------------------------------------------------------------------------
# Structural clustering
# ----------------------------------------------------------------------------------------------


def _as_labels(x, name: str) -> torch.Tensor:
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
    if t.dim() != 1 or t.numel() == 0:
        raise ValueError(f"{name} must be a non-empty 1-D sequence of labels, got shape {tuple(t.shape)}")
    if t.dtype.is_floating_point or t.dtype.is_complex or t.dtype == torch.bool:
        raise ValueError(f"{name} must hold integer labels, got dtype {t.dtype}")
    return t.long().cpu()


def cluster_by_existence(exists) -> torch.Tensor:
    """Structural clustering (Sec. 4.4, Fig. 14): shapes with identical existence vectors form a group.

    Args:
        exists: (S, M) bool (or 0/1 integers), the existing cuboids of S shapes decoded by one network
            (cuboid m is the same part in every shape).

    Returns:
        (S,) long group ids: 0 is the largest group, then by decreasing size; groups of equal size are
        numbered in the order their first shape appears.
    """
    e = exists if isinstance(exists, torch.Tensor) else torch.as_tensor(np.asarray(exists))
    if e.dtype.is_floating_point:
        raise ValueError("exists must be a boolean (S, M) mask; threshold probabilities first (p > 0.5)")
    if e.dim() != 2 or e.shape[0] == 0:
        raise ValueError(f"exists must have shape (S, M) with S >= 1, got {tuple(e.shape)}")
    if e.dtype != torch.bool:
        if ((e != 0) & (e != 1)).any():
            raise ValueError("exists must hold booleans or 0/1 integers")
        e = e != 0
    # inverse (S,): the group of every shape; counts (G,): the size of every group
    _, inverse, counts = torch.unique(e.cpu().to(torch.uint8), dim=0, return_inverse=True, return_counts=True)
    s = e.shape[0]
    first = torch.full((len(counts),), s, dtype=torch.long).scatter_reduce(
        0, inverse, torch.arange(s), reduce="amin"
    )
    order = torch.argsort(-counts * (s + 1) + first)  # larger groups first, then first appearance
    rank = torch.empty_like(order)
    rank[order] = torch.arange(len(order))
    return rank[inverse]


class ExistenceGroup(NamedTuple):
    """One structural group.

    Attributes:
        cluster: its id; size: its number of shapes.
        cuboids: the cuboid indices that exist in all its shapes (like Fig. 14's "[5,7,10,12,14]").
        members: the indices of its shapes.
    """

    cluster: int
    size: int
    cuboids: list[int]
    members: list[int]


def existence_groups(exists, clusters=None) -> list[ExistenceGroup]:
    """Summaries of the groups of :func:`cluster_by_existence`, ordered by group id.

    Args:
        exists: (S, M) bool.
        clusters: (S,) group ids; None: ``cluster_by_existence(exists)``.

    Returns:
        One :class:`ExistenceGroup` per group.
    """
    e = exists if isinstance(exists, torch.Tensor) else torch.as_tensor(np.asarray(exists))
    ids = cluster_by_existence(e) if clusters is None else _as_labels(clusters, "clusters")
    e = e.cpu() != 0
    if e.dim() != 2 or ids.shape[0] != e.shape[0]:
        raise ValueError(f"clusters has {ids.shape[0]} entries for exists of shape {tuple(e.shape)}")
    groups = []
    for g in torch.unique(ids).tolist():
        members = torch.nonzero(ids == g)[:, 0]
        shared = e[members].all(dim=0)
        groups.append(ExistenceGroup(int(g), len(members), torch.nonzero(shared)[:, 0].tolist(), members.tolist()))
    return groups


def _contingency(a, b) -> torch.Tensor:
    """Contingency table n_ij = |{s : a_s = i-th value of a, b_s = j-th value of b}| (float64)."""
    a, b = _as_labels(a, "clusters"), _as_labels(b, "truth")
    if a.shape != b.shape:
        raise ValueError(f"clusters ({a.shape[0]} shapes) and truth ({b.shape[0]} shapes) must have the same length")
    _, ia = torch.unique(a, return_inverse=True)
    _, ib = torch.unique(b, return_inverse=True)
    rows, cols = int(ia.max()) + 1, int(ib.max()) + 1
    table = torch.zeros(rows * cols, dtype=torch.float64)
    table.index_add_(0, ia * cols + ib, torch.ones(len(a), dtype=torch.float64))
    return table.view(rows, cols)


def purity(clusters, truth) -> float:
    """Purity of a grouping, (1 / S) sum_k max_j |C_k and T_j| for groups C_k and true types T_j.

    1 when every group holds one type only, also when every shape is its own group: read it with the ARI.

    Args:
        clusters, truth: (S,) integer labels of any values.

    Returns:
        The purity in (0, 1].
    """
    table = _contingency(clusters, truth)
    return float(table.amax(dim=1).sum() / table.sum())


def adjusted_rand_index(clusters, truth) -> float:
    """Adjusted Rand index (Hubert and Arabie, 1985) between a grouping and the true types.

    With the contingency table n_ij, row sums a_i, column sums b_j and C(x) = x (x - 1) / 2:
    index = sum_ij C(n_ij), expected = sum_i C(a_i) sum_j C(b_j) / C(S),
    maximum = (sum_i C(a_i) + sum_j C(b_j)) / 2, ARI = (index - expected) / (maximum - expected).

    Args:
        clusters, truth: (S,) integer labels of any values.

    Returns:
        1 for identical partitions (up to renaming, also when maximum = expected), about 0 for a random
        grouping, negative when worse than chance.
    """
    table = _contingency(clusters, truth)
    pairs = lambda x: (x * (x - 1) / 2).sum()  # noqa: E731
    n = table.sum()
    index = pairs(table)
    sum_a, sum_b = pairs(table.sum(dim=1)), pairs(table.sum(dim=0))
    total = n * (n - 1) / 2
    expected = sum_a * sum_b / total if total > 0 else torch.tensor(0.0, dtype=torch.float64)
    maximum = (sum_a + sum_b) / 2
    if maximum == expected:
        return 1.0
    return float((index - expected) / (maximum - expected))


# ----------------------------------------------------------------------------------------------
# Trained checkpoints by name
# ----------------------------------------------------------------------------------------------


def checkpoint_dir() -> Path:
    """The folder of committed checkpoints.

    Returns:
        ``$CUBOIDLIB_CHECKPOINTS`` if set, else ``data_samples/checkpoints`` of the source tree cuboidlib
        runs from, else (an installed wheel) the copy inside the package, ``cuboidlib/networks``.
    """
    env = os.environ.get(CHECKPOINT_DIR_ENV)
    if env:
        return Path(env)
    source_tree = Path(__file__).resolve().parent.parent / "data_samples" / "checkpoints"
    return source_tree if source_tree.is_dir() else Path(__file__).resolve().parent / "networks"


def committed_checkpoints() -> dict[str, Path]:
    """Committed checkpoints by name.

    Returns:
        ``{"chair": .../chair.pt, ...}`` for the ``.pt`` files of :func:`checkpoint_dir` (empty if none).
    """
    folder = checkpoint_dir()
    if not folder.is_dir():
        return {}
    return {p.stem: p for p in sorted(folder.glob("*.pt")) if p.is_file()}


def resolve_checkpoint(name_or_path: str | os.PathLike) -> Path:
    """The checkpoint file meant by a path or a committed network's name.

    Args:
        name_or_path: in this order, an existing file (itself); a training run folder (its ``best.pt``,
            else its ``last.pt``); a bare name of a committed checkpoint, e.g. ``"chair"`` for
            ``checkpoint_dir() / "chair.pt"`` (even when a folder of that name without a run exists here).

    Returns:
        The checkpoint file.

    Raises:
        FileNotFoundError: naming what was looked for and the committed names available.
    """
    path = Path(name_or_path)
    if path.is_file():
        return path
    if path.is_dir():
        for name in ("best.pt", "last.pt"):
            if (path / name).is_file():
                return path / name
    available = committed_checkpoints()
    text = str(name_or_path)
    if path.name == text and not path.suffix and text in available:
        return available[text]
    if path.is_dir():
        raise FileNotFoundError(f"{path}: a folder without best.pt or last.pt (not a training run folder)")
    names = ", ".join(available) if available else f"none yet in {checkpoint_dir()}"
    raise FileNotFoundError(
        f"{text}: no such checkpoint file, run folder or committed checkpoint name (committed: {names})"
    )


def load_trained_model(
    name_or_path: str | os.PathLike, device: str | torch.device = "cpu"
) -> tuple[CuboidAbstractionNet, dict, Path]:
    """Load a network by checkpoint path, run folder or committed name.

    Args:
        name_or_path: as for :func:`resolve_checkpoint`.
        device: where the network is built.

    Returns:
        ``(model in evaluation mode, checkpoint dict, resolved path)``, as :func:`cuboidlib.checkpoint.load_model`.
    """
    path = resolve_checkpoint(name_or_path)
    model, state = load_model(path, device=device)
    return model, state, path
