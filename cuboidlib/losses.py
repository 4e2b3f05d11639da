"""The training losses of the paper (Sec. 3.4).

The network is trained with L = L_recons + lambda_1 L_compact + lambda_2 L_exist + lambda_3 L_KL (Eq. 9).
Each loss term has its own section below, headed by the paper's subsection and equation number.

Shapes: the allocation W (the paper's W_{m,n}) is a tensor of shape (B, N, M) whose last axis sums to 1
(softmax over the M cuboids, Eq. 3). The portions w_m = (1/N) sum_n W_{m,n} have shape (B, M).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ._checks import as_float_tensor, check_finite, check_positive
from .config import ConfigDict
from .distance import chamfer_distance_to_cuboids, nearest_surface_distance, point_to_cuboid_distance

__all__ = [
    "allocation_portions",
    "reconstruction_loss",
    "nearest_cuboid_allocation",
    "allocation_weighted_centers",
    "compactness_loss",
    "l1_penalty",
    "l2_penalty",
    "existence_targets",
    "existence_loss",
    "kl_divergence",
    "slot_consistency_loss",
    "LossConfig",
    "LossTerms",
    "LOSS_TERMS",
    "total_loss",
]


# ---------------------------------------------------------------------------------------------------------
# Allocation portions w_m (Sec. 3.4.2), shared by the compactness loss (Eq. 6) and the existence targets (Eq. 7)
# ---------------------------------------------------------------------------------------------------------


def allocation_portions(W: torch.Tensor) -> torch.Tensor:
    """Portion of the points allocated to each cuboid, w_m = (1/N) sum_n W_{m,n} (Sec. 3.4.2).

    Args:
        W: (B, N, M) soft allocation, each row summing to 1 over the M cuboids.

    Returns:
        (B, M) portions w, summing to 1 over M.
    """
    W = as_float_tensor(W, "W")
    if W.dim() != 3:
        raise ValueError(f"W must have shape (B, N, M), got shape {tuple(W.shape)}")
    if W.shape[1] == 0:
        raise ValueError("W has no points (N = 0); at least one point is needed to compute portions")
    return W.mean(dim=1)


def _check_portions(w, name: str = "w") -> torch.Tensor:
    """Return ``w`` as a float tensor of shape (..., M), M >= 1, finite and non-negative."""
    w = as_float_tensor(w, name)
    if w.dim() < 1 or w.shape[-1] == 0:
        raise ValueError(f"{name} must have shape (..., M) with M >= 1 cuboids, got shape {tuple(w.shape)}")
    check_finite(w, name)
    check_positive(w, name, allow_zero=True)
    return w


# ---------------------------------------------------------------------------------------------------------
# Reconstruction loss: Sec. 3.4.1, Eq. (4)
#
# L_recons = (1/N) sum_n sum_m W_{m,n} d(p_n, C_m): the distance of every point to every cuboid, weighted by
# the soft allocation of the segmentation branch. d is the normal-aware distance of Eq. (5)
# (cuboidlib.distance.point_to_cuboid_distance); the ablations swap it for the nearest-surface distance
# (Table 4) or swap W for a hard nearest-cuboid allocation (P2C-Dis, Table 3).
# ---------------------------------------------------------------------------------------------------------


def reconstruction_loss(W: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """Allocation-weighted point-to-cuboid distance, L_recons of Eq. (4).

    Args:
        W: (B, N, M) allocation, each row summing to 1.
        d: (B, N, M) point-to-cuboid distances d(p_n, C_m), e.g. those of Eq. (5).

    Returns:
        (B,) the loss of each shape, (1/N) sum_n sum_m W[b, n, m] d[b, n, m].
    """
    W = as_float_tensor(W, "W")
    d = as_float_tensor(d, "d")
    if W.dim() != 3 or W.shape != d.shape:
        raise ValueError(
            f"W and d must both have shape (B, N, M); got W {tuple(W.shape)} and d {tuple(d.shape)}"
        )
    if W.shape[1] == 0:
        raise ValueError("W has no points (N = 0); at least one point is needed")
    return _reconstruction(W, d)


def _reconstruction(W: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    return (W * d).sum(dim=-1).mean(dim=-1)


def nearest_cuboid_allocation(d: torch.Tensor) -> torch.Tensor:
    """Hard allocation to the closest cuboid, W_{m,n} = [m = argmin_k d(p_n, C_k)] (P2C-Dis, Table 3).

    Args:
        d: (B, N, M) point-to-cuboid distances.

    Returns:
        (B, N, M) one-hot, in d's dtype; no gradient flows through the choice.
    """
    d = as_float_tensor(d, "d")
    if d.dim() != 3:
        raise ValueError(f"d must have shape (B, N, M), got {tuple(d.shape)}")
    return _nearest_cuboid(d)


def _nearest_cuboid(d: torch.Tensor) -> torch.Tensor:
    return torch.nn.functional.one_hot(d.detach().argmin(dim=-1), d.shape[-1]).to(d.dtype)


def allocation_weighted_centers(W: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Cuboid centres from the allocation, c_m = sum_n W_{m,n} p_n / (sum_n W_{m,n} + 1).

    The authors' public code uses these centres in every loss; the paper uses the predicted translation
    t_m. The +1 keeps an empty cuboid finite (at the origin).

    Args:
        W: (B, N, M) allocation.
        points: (B, N, 3).

    Returns:
        (B, M, 3) centres.
    """
    return torch.einsum("bnm,bnc->bmc", W, points) / (W.sum(dim=1)[..., None] + 1)  # (B, M, 3) / (B, M, 1)


# ---------------------------------------------------------------------------------------------------------
# Cuboid compactness loss: Sec. 3.4.2, Eq. (6), Fig. 5
#
# compactness_loss is the paper's loss, an L0.5 penalty on the portions w. l1_penalty and l2_penalty are the
# two penalties the paper compares it with in Fig. 5: on the simplex sum_m w_m = 1 the L1 norm is constant
# (its gradient with respect to the softmax logits is zero), and the squared L2 norm is smallest at uniform
# portions (it spreads points over all cuboids). Only the concave L0.5 penalty pushes w towards a vertex,
# i.e. towards using few cuboids.
# ---------------------------------------------------------------------------------------------------------


def compactness_loss(w: torch.Tensor, eps_sps: float = 0.01, average_over_cuboids: bool = False) -> torch.Tensor:
    """Cuboid compactness loss L_compact = (sum_m sqrt(w_m + eps_sps))^2, Eq. (6), Sec. 3.4.2.

    The L0.5 penalty of Fig. 5: concave in w, so its minima on the simplex are the vertices (few cuboids).

    Args:
        w: (..., M) non-negative portions (rows normally sum to 1; not checked).
        eps_sps: >= 0; keeps the gradient finite when a cuboid gets no points (paper: 0.01). With 0 it is
            infinite at w_m = 0, and a softmax that underflows to 0 turns every logit's gradient into NaN.
        average_over_cuboids: the authors' code's (mean_m sqrt(w_m + eps_sps))^2, Eq. (6) / M^2: the same
            minimiser with an M^2 times smaller gradient, so a weight lambda_1 on this form equals lambda_1 / M^2
            on Eq. (6). The authors' training script applies its default weight 0.1 to this form.

    Returns:
        (...) one value per row: (B, M) -> (B,), (M,) -> ().
    """
    w = _check_portions(w)
    if eps_sps < 0:
        raise ValueError(f"eps_sps must be non-negative, got {eps_sps}")
    return _compactness(w, eps_sps, average_over_cuboids)


def _compactness(w: torch.Tensor, eps_sps: float, average_over_cuboids: bool) -> torch.Tensor:
    roots = torch.sqrt(w + eps_sps)  # (..., M)
    total = roots.mean(dim=-1) if average_over_cuboids else roots.sum(dim=-1)
    return total**2


def l1_penalty(w: torch.Tensor) -> torch.Tensor:
    """L1 norm of the portions, sum_m |w_m|: the penalty the paper rejects (Sec. 3.4.2, Fig. 5).

    On the simplex it is identically 1: its gradient through a softmax is zero up to float rounding.

    Args:
        w: (..., M) non-negative portions.

    Returns:
        (...) one value per row: (B, M) -> (B,), (M,) -> ().
    """
    w = _check_portions(w)
    return w.abs().sum(dim=-1)


def l2_penalty(w: torch.Tensor) -> torch.Tensor:
    """Squared L2 norm of the portions, sum_m w_m^2: a comparison penalty of Sec. 3.4.2 and Fig. 5.

    Convex, smallest at the uniform w_m = 1/M: it spreads the points over all cuboids.

    Args:
        w: (..., M) non-negative portions.

    Returns:
        (...) one value per row: (B, M) -> (B,), (M,) -> ().
    """
    w = _check_portions(w)
    return (w * w).sum(dim=-1)


# ---------------------------------------------------------------------------------------------------------
# Cuboid existence loss: Sec. 3.4.3, Eq. (7)
#
# The segmentation decides which cuboids exist: delta^gt_m = [w_m > eps_ext], and the abstraction branch's
# existence prediction delta_m learns it by binary cross-entropy. The target is a constant (no gradient).
# ---------------------------------------------------------------------------------------------------------


def existence_targets(w: torch.Tensor, eps_ext: float = 0.05, min_points: float | None = None,
                      num_points: int | None = None) -> torch.Tensor:
    """Existence ground truth delta^gt_m = [w_m > eps_ext] (Sec. 3.4.3), detached.

    Args:
        w: (..., M) portions.
        eps_ext: threshold on the portion, in [0, 1) (paper: 0.05).
        min_points: None, or the authors' code's threshold on the number of points instead,
            N w_m > min_points (code: 24).
        num_points: N, the points per shape; needed with ``min_points``.

    Returns:
        (..., M) floats in {0, 1}, in w's dtype.
    """
    w = _check_portions(w)
    if min_points is None and not 0 <= eps_ext < 1:
        raise ValueError(f"eps_ext must lie in [0, 1), got {eps_ext}")
    if min_points is not None and (num_points is None or num_points < 1):
        raise ValueError("min_points needs num_points, the number N of points per shape")
    return _existence_targets(w, eps_ext, min_points, num_points)


def _existence_targets(w: torch.Tensor, eps_ext: float, min_points: float | None, num_points: int | None):
    if min_points is None:
        return (w.detach() > eps_ext).to(w.dtype)
    return (w.detach() * num_points > min_points).to(w.dtype)


def existence_loss(exist_logits: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy of the predicted existence and its targets, L_exist of Eq. (7).

    Args:
        exist_logits: (B, M) logits, delta_m = sigmoid(logit).
        targets: (B, M) in {0, 1}, e.g. from :func:`existence_targets`.

    Returns:
        (B,) -(1/M) sum_m [t log delta_m + (1 - t) log(1 - delta_m)], computed from the logits for stability.
    """
    exist_logits = as_float_tensor(exist_logits, "exist_logits")
    targets = as_float_tensor(targets, "targets").to(exist_logits)
    if exist_logits.dim() != 2 or exist_logits.shape != targets.shape:
        raise ValueError(
            f"exist_logits and targets must both have shape (B, M); got {tuple(exist_logits.shape)} "
            f"and {tuple(targets.shape)}"
        )
    return _existence_loss(exist_logits, targets)


def _existence_loss(exist_logits: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
    bce = torch.nn.functional.binary_cross_entropy_with_logits(exist_logits, targets, reduction="none")  # (B, M)
    return bce.mean(dim=-1)


# ---------------------------------------------------------------------------------------------------------
# Latent code KL-divergence loss: Sec. 3.4.4, Eq. (8)
# ---------------------------------------------------------------------------------------------------------


def kl_divergence(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """KL(N(mu, diag(exp(logvar))) || N(0, I)), L_KL-div of Eq. (8).

    Args:
        mu, logvar: (B, K) mean and log-variance of the latent code (the paper's sigma_k is the log-variance).

    Returns:
        (B,) (1/2) sum_k [exp(logvar_k) - (1 + logvar_k) + mu_k^2].
    """
    mu = as_float_tensor(mu, "mu")
    logvar = as_float_tensor(logvar, "logvar").to(mu)
    if mu.dim() != 2 or mu.shape != logvar.shape:
        raise ValueError(f"mu and logvar must both have shape (B, K); got {tuple(mu.shape)} and {tuple(logvar.shape)}")
    return _kl_divergence(mu, logvar)


def _kl_divergence(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    return 0.5 * (logvar.exp() - (1 + logvar) + mu.square()).sum(dim=-1)


# ---------------------------------------------------------------------------------------------------------
# Slot consistency across shapes: a course option, not a term of the paper (lambda_consistency = 0 by default)
#
# The paper's network gives cuboid slot m the same role in every shape only implicitly (the same code e_m).
# Nothing stops a slot from holding an armrest in one chair and a leg in another. This term measures how far
# each slot's centre strays over the shapes of a batch, weighted by how many points the slot holds there.
# ---------------------------------------------------------------------------------------------------------


def slot_consistency_loss(centers: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Portion-weighted spread of every slot's centre over the batch, averaged over the slots.

    With mu_m = sum_b w_bm c_bm / sum_b w_bm: mean_m [sum_b w_bm |c_bm - mu_m|^2 / sum_b w_bm].

    Args:
        centers: (B, M, 3) cuboid centres c_bm.
        w: (B, M) allocation portions.

    Returns:
        () a scalar.

    Example::

        >>> c = torch.tensor([[[0.0, 0, 0]], [[0.2, 0, 0]]]); w = torch.tensor([[0.5], [0.5]])
        >>> slot_consistency_loss(c, w)
        tensor(0.0100)
    """
    centers = as_float_tensor(centers, "centers")
    w = _check_portions(w).to(centers)
    if centers.dim() != 3 or centers.shape[-1] != 3 or centers.shape[:2] != w.shape:
        raise ValueError(f"centers must have shape (B, M, 3) and w (B, M); "
                         f"got {tuple(centers.shape)} and {tuple(w.shape)}")
    return _slot_consistency(centers, w)


def _slot_consistency(centers: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    mass = w.sum(dim=0) + 1e-6  # (M,)
    mean = (w[..., None] * centers).sum(dim=0) / mass[:, None]  # (M, 3)
    spread = (w * (centers - mean).square().sum(dim=-1)).sum(dim=0) / mass  # (M,)
    return spread.mean()


# ---------------------------------------------------------------------------------------------------------
# Total loss: Sec. 3.4.5, Eq. (9), with the ablation variants and the authors' public-code choices as options
# ---------------------------------------------------------------------------------------------------------

DISTANCES = ("normal", "nearest_surface", "chamfer")
ALLOCATIONS = ("segmentation", "nearest_cuboid")


@dataclass(frozen=True)
class LossConfig(ConfigDict):
    """Weights and choices of the total loss L = L_recons + l1 L_compact + l2 L_exist + l3 L_KL (Eq. 9).

    The defaults are the paper's; the ablations are those of Sec. 4.3.

    Args:
        lambda_compact, lambda_exist, lambda_kl: lambda_1, lambda_2, lambda_3 of Eq. (9) (0.1, 0.01, 6e-6).
        sigma_s: range of the offsets along the normals, Eq. (5) (0.05).
        eps_sps: shift under the square roots of Eq. (6) (0.01).
        eps_ext: portion above which a cuboid's existence target is 1, Sec. 3.4.3 (0.05).
        distance: "normal" (Eq. 5), "nearest_surface" (Table 4's "Distance" column) or "chamfer"
            (Chamfer-Dis of Table 3: bidirectional Chamfer to samples on the cuboids as L_recons, with the
            hard nearest-cuboid allocation for the other terms).
        allocation: "segmentation" (the network's W, P2C-Seg) or "nearest_cuboid" (P2C-Dis: one-hot of the
            closest cuboid under ``distance``).
        chamfer_samples: points sampled on the cuboids for distance="chamfer" (None: N).
        centers_from_allocation: the authors' code: cuboid centres :func:`allocation_weighted_centers` in
            every loss.
        compactness_average: the authors' code: (mean_m sqrt(w_m + eps_sps))^2, Eq. (6) / M^2.
        existence_min_points: the authors' code: existence target N w_m > this many points (code: 24)
            instead of eps_ext.
        lambda_consistency: weight of :func:`slot_consistency_loss` added to Eq. (9), so that a slot keeps
            one role in every shape (a course option; 0 is off).
    """

    lambda_compact: float = 0.1
    lambda_exist: float = 0.01
    lambda_kl: float = 6e-6
    sigma_s: float = 0.05
    eps_sps: float = 0.01
    eps_ext: float = 0.05
    distance: str = "normal"
    allocation: str = "segmentation"
    chamfer_samples: int | None = None
    centers_from_allocation: bool = False
    compactness_average: bool = False
    existence_min_points: float | None = None
    lambda_consistency: float = 0.0

    def __post_init__(self) -> None:
        if self.distance not in DISTANCES:
            raise ValueError(f"distance must be one of {DISTANCES}, got {self.distance!r}")
        if self.allocation not in ALLOCATIONS:
            raise ValueError(f"allocation must be one of {ALLOCATIONS}, got {self.allocation!r}")
        for name in ("lambda_compact", "lambda_exist", "lambda_kl", "sigma_s", "eps_sps", "eps_ext",
                     "lambda_consistency"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite non-negative number, got {value!r}")

    @classmethod
    def authors_code(cls, **overrides) -> "LossConfig":
        """The choices of the authors' public code (centroid centres, averaged compactness, 24-point existence)."""
        return cls(**{"centers_from_allocation": True, "compactness_average": True, "existence_min_points": 24.0,
                      **overrides})


#: The scalar terms of :class:`LossTerms`, in log-file order: Eq. (9)'s total and its four terms, then the
#: course's slot consistency (measured at every step, added to the total only when its weight is positive).
LOSS_TERMS = ("total", "reconstruction", "compactness", "existence", "kl", "consistency")


@dataclass
class LossTerms:
    """The total loss and its terms, each averaged over the batch, and the W and w they used.

    Attributes:
        total, reconstruction, compactness, existence, kl: () Eq. (9) and its four terms.
        consistency: () :func:`slot_consistency_loss`, detached when its weight is 0.
        W: (B, N, M) the allocation used (one-hot for "nearest_cuboid" or "chamfer").
        portions: (B, M) the portions w.
    """

    total: torch.Tensor
    reconstruction: torch.Tensor
    compactness: torch.Tensor
    existence: torch.Tensor
    kl: torch.Tensor
    consistency: torch.Tensor
    W: torch.Tensor
    portions: torch.Tensor

    def as_floats(self) -> dict[str, float]:
        """The :data:`LOSS_TERMS` as plain floats (for logs and progress bars)."""
        return {k: getattr(self, k).detach().item() for k in LOSS_TERMS}


def _checked_output(output, points: torch.Tensor) -> torch.Tensor:
    """Check the shapes total_loss relies on, once; returns W (B, N, M)."""
    W = as_float_tensor(output.W, "W")
    if W.dim() != 3 or W.shape[1] == 0:
        raise ValueError(f"output.W must have shape (B, N, M) with N >= 1, got {tuple(W.shape)}")
    B, N, M = W.shape
    if tuple(points.shape) != (B, N, 3):
        raise ValueError(f"points must have shape (B, N, 3) = {(B, N, 3)} to match output.W, got {tuple(points.shape)}")
    if tuple(output.exist_logits.shape) != (B, M):
        raise ValueError(f"output.exist_logits must have shape (B, M) = {(B, M)}, got {tuple(output.exist_logits.shape)}")
    if output.mu.dim() != 2 or output.mu.shape != output.logvar.shape or output.mu.shape[0] != B:
        raise ValueError(f"output.mu and output.logvar must both have shape (B, K); got {tuple(output.mu.shape)} "
                         f"and {tuple(output.logvar.shape)}")
    return W


def total_loss(output, points: torch.Tensor, normals: torch.Tensor, config: LossConfig = LossConfig(),
               generator: torch.Generator | None = None) -> LossTerms:
    """L = L_recons + lambda_1 L_compact + lambda_2 L_exist + lambda_3 L_KL-div (Eq. 9), batch-averaged.

    Args:
        output: the network's prediction, e.g. :class:`cuboidlib.model.ModelOutput`: centers (B, M, 3),
            quaternions (B, M, 4), half_sizes (B, M, 3), exist_logits (B, M), W (B, N, M), mu and logvar (B, K).
        points, normals: (B, N, 3) the input shapes, unit normals.
        config: the loss settings (default: the paper's).
        generator: source of the offsets along the normals (Eq. 5) and, for distance="chamfer", of the
            samples on the cuboids (None: torch's global one).

    Returns:
        :class:`LossTerms`.
    """
    c = config
    W = _checked_output(output, points)
    centers = allocation_weighted_centers(W, points) if c.centers_from_allocation else output.centers
    cuboids = (centers, output.quaternions, output.half_sizes)
    if c.distance == "chamfer":
        d = nearest_surface_distance(points, *cuboids)
        W = _nearest_cuboid(d)
        samples = c.chamfer_samples or points.shape[1]
        recons = chamfer_distance_to_cuboids(points, *cuboids, n_samples=samples, generator=generator)
    else:
        if c.distance == "normal":
            d = point_to_cuboid_distance(points, normals, *cuboids, sigma_s=c.sigma_s, generator=generator)
        else:
            d = nearest_surface_distance(points, *cuboids)
        if c.allocation == "nearest_cuboid":
            W = _nearest_cuboid(d)
        recons = _reconstruction(W, d)
    w = W.mean(dim=1)  # (B, M) portions, Sec. 3.4.2
    compact = _compactness(w, c.eps_sps, c.compactness_average)
    targets = _existence_targets(w, c.eps_ext, c.existence_min_points, points.shape[1])
    exist = _existence_loss(output.exist_logits, targets)
    kl = _kl_divergence(output.mu, output.logvar)
    recons, compact, exist, kl = recons.mean(), compact.mean(), exist.mean(), kl.mean()
    total = recons + c.lambda_compact * compact + c.lambda_exist * exist + c.lambda_kl * kl
    consistency = _slot_consistency(centers, w)
    if c.lambda_consistency > 0:
        total = total + c.lambda_consistency * consistency
    if c.centers_from_allocation:
        # No term uses the predicted translation; keep it in the graph with weight 0 so that every parameter
        # gets a (zero) gradient, as DistributedDataParallel requires. The value of the loss is unchanged.
        total = total + 0.0 * output.centers.sum()
    return LossTerms(total, recons, compact, exist, kl, consistency.detach() if c.lambda_consistency == 0 else
                     consistency, W, w)
