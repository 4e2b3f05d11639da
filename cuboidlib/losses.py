"""The training losses of the paper (Sec. 3.4).

The network is trained with L = L_recons + lambda_1 L_compact + lambda_2 L_exist + lambda_3 L_KL (Eq. 9).
Each loss term has its own section below, headed by the paper's subsection and equation number.

Shapes: the allocation W (the paper's W_{m,n}) is a tensor of shape (B, N, M) whose last axis sums to 1
(softmax over the M cuboids, Eq. 3). The portions w_m = (1/N) sum_n W_{m,n} have shape (B, M).
"""

from __future__ import annotations

import torch

from ._checks import as_float_tensor, check_finite, check_positive

__all__ = [
    "allocation_portions",
    "compactness_loss",
    "l1_penalty",
    "l2_penalty",
]


# ---------------------------------------------------------------------------------------------------------
# Allocation portions w_m (Sec. 3.4.2), shared by the compactness loss (Eq. 6) and the existence targets (Eq. 7)
# ---------------------------------------------------------------------------------------------------------


def allocation_portions(W: torch.Tensor) -> torch.Tensor:
    """Portion of the points allocated to each cuboid, w_m = (1/N) sum_n W_{m,n} (Sec. 3.4.2).

    W: (B, N, M) soft allocation (rows sum to 1). Returns w: (B, M), summing to 1 over M.
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
# Cuboid compactness loss: Sec. 3.4.2, Eq. (6), Fig. 8
#
# compactness_loss is the paper's loss, an L0.5 penalty on the portions w. l1_penalty and l2_penalty are the
# two penalties the paper compares it with in Fig. 8: on the simplex sum_m w_m = 1 the L1 norm is constant
# (its gradient with respect to the softmax logits is zero), and the squared L2 norm is smallest at uniform
# portions (it spreads points over all cuboids). Only the concave L0.5 penalty pushes w towards a vertex,
# i.e. towards using few cuboids.
# ---------------------------------------------------------------------------------------------------------


def compactness_loss(w: torch.Tensor, eps_sps: float = 0.01, average_over_cuboids: bool = False) -> torch.Tensor:
    """Cuboid compactness loss L_compact = (sum_m sqrt(w_m + eps_sps))^2, Eq. (6), Sec. 3.4.2.

    This is the L0.5 penalty of the paper's Fig. 8 (the squared L0.5 "norm" of w, shifted by eps_sps).
    It is concave in w, so on the simplex sum_m w_m = 1 its minima are the vertices: minimising it
    drives the allocation towards few cuboids.

    w: (..., M) allocation portions, non-negative (each row normally sums to 1; not checked, so the
    penalty can also be evaluated off the simplex). Returns (...): one value per shape, e.g.
    (B, M) -> (B,) and (M,) -> ().

    eps_sps >= 0 keeps the gradient finite when a cuboid gets no points (paper: 0.01):
    d/dw_m L = S / sqrt(w_m + eps_sps) with S = sum_k sqrt(w_k + eps_sps), bounded by S / sqrt(eps_sps).
    With eps_sps = 0 the gradient is infinite at w_m = 0 (and a softmax that underflows to an exact
    0 then turns every logit's gradient into NaN).

    average_over_cuboids=True gives the variant of the authors' public code, (mean_m sqrt(w_m + eps_sps))^2.
    It equals the paper's value divided by M^2: same minimiser, but a gradient M^2 times smaller, so its
    lambda_1 is M^2 times smaller in effect (for M = 16, the code's lambda_1 = 0.1 acts like 0.1 / 256 here).
    """
    w = _check_portions(w)
    if eps_sps < 0:
        raise ValueError(f"eps_sps must be non-negative, got {eps_sps}")
    roots = torch.sqrt(w + eps_sps)
    total = roots.mean(dim=-1) if average_over_cuboids else roots.sum(dim=-1)
    return total**2


def l1_penalty(w: torch.Tensor) -> torch.Tensor:
    """L1 norm of the portions, sum_m |w_m|: the penalty the paper rejects (Sec. 3.4.2, Fig. 8).

    w: (..., M) non-negative allocation portions. Returns (...), e.g. (B, M) -> (B,), (M,) -> ().
    On the simplex sum_m w_m = 1 it is identically 1. With w = softmax(z) its gradient with respect to
    the logits is J^T 1 = w * (1 - sum_m w_m) = 0 (J = diag(w) - w w^T is the softmax Jacobian), so it
    cannot change the allocation; numerically the gradient is at rounding level, since sum_m w_m is 1
    only up to float rounding.
    """
    w = _check_portions(w)
    return w.abs().sum(dim=-1)


def l2_penalty(w: torch.Tensor) -> torch.Tensor:
    """Squared L2 norm of the portions, sum_m w_m^2: a comparison penalty of Sec. 3.4.2 and Fig. 8.

    w: (..., M) non-negative allocation portions. Returns (...), e.g. (B, M) -> (B,), (M,) -> ().
    It is convex; on the simplex its minimum is 1/M, at the uniform portions w_m = 1/M, so minimising it
    spreads the points over all cuboids (the opposite of compactness). Squaring the norm keeps the same
    minimiser and a smooth gradient 2 w.
    """
    w = _check_portions(w)
    return (w * w).sum(dim=-1)
