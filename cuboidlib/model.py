"""The network of the paper (Sec. 3.1-3.3, Fig. 3): feature embedding, shape abstraction, segmentation.

Shapes (batch-first): points (B, N, 3); cuboid centers (B, M, 3), unit quaternions (B, M, 4) in
(w, x, y, z) order, half sizes (B, M, 3); allocation W (B, N, M), softmax over the last axis (over
cuboids), i.e. the transpose of the paper's W_{m,n}.

Building blocks, named after the paper:

* :class:`EdgeConv` (the layers of E_pp, [DGCNN]), :class:`GlobalFeature` (shared layer + max-pool),
  :class:`FeatureEmbedding` (E_pp, global feature and the VAE head predicting mu and log-variance), Sec. 3.1;
* :class:`ShapeAbstraction` (E_cb, E_cf and the cuboid decoder D_cp = :class:`CuboidDecoder`), Sec. 3.2;
* :class:`CuboidSegmentation` (affinity and point-to-cuboid allocation, Eq. (2)-(3)), Sec. 3.3;
* :class:`CuboidAbstractionNet` (the whole network, configured by :class:`ModelConfig`).

Readable and fast. EdgeConv and the global layer dominate the cost of a training step.
:class:`EdgeConv` and :class:`GlobalFeature` are written as the paper describes them (the explicit
(B, 2C, N, k) edge tensor, 1x1 layers, BatchNorm, LeakyReLU, max over neighbours).
:class:`FastEdgeConv` and :class:`FastGlobalFeature`, below them, compute exactly the same functions
of the same parameters faster; their docstrings list how they differ. The network uses the fast
versions unless built with ``fast=False``. Tests check values, gradients and BatchNorm statistics of
both against each other in float64; ``benchmarks/bench_model.py --variant fast readable`` times a
training step of each. The chunked EdgeConv runs many small multi-threaded operations: on a CPU
whose cores are already busy with other work, ``torch.set_num_threads(1)`` avoids threads waiting
for each other.

Why one file: it is the network of Fig. 3 in one place, the readable EdgeConv and its fast version
side by side.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from ._checks import as_float_tensor, check_finite, check_shape
from . import kernels
from .config import ConfigDict
from .neighbors import knn_indices

__all__ = [
    "ModelConfig",
    "knn_indices",
    "EdgeConv",
    "FastEdgeConv",
    "GlobalFeature",
    "FastGlobalFeature",
    "FeatureEmbedding",
    "CuboidDecoder",
    "ShapeAbstraction",
    "CuboidSegmentation",
    "allocation_saturation",
    "read_normals_from_start",
    "CuboidPrediction",
    "ModelOutput",
    "CuboidAbstractionNet",
    "reparameterize",
]

# Edges processed at once by the chunked EdgeConv: small enough for a chunk's (edges, channels)
# tensors to stay in the CPU cache, large enough for matrix products to run at full speed.
_EDGES_PER_CHUNK = 1 << 14
# On a GPU every operation of a chunk costs a kernel launch whatever its size, and memory is ample: chunks
# of 1 << 20 edges (a 64-channel float32 chunk tensor is 256 MiB) launch 64 times fewer kernels.
_EDGES_PER_CHUNK_GPU = 1 << 20


# Limits of a ModelConfig (checked before anything is allocated): far above the paper's network.
_MAX_WIDTH = 8192
_MAX_LAYERS = 8
_MAX_PARAMETERS = 50_000_000

#: The values of ModelConfig.input_normals: what the encoder reads of the normals.
INPUT_NORMALS = ("none", "differences", "absolute")

# ----------------------------------------------------------------------------------------------
# Configuration
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ModelConfig(ConfigDict):
    """Sizes of :class:`CuboidAbstractionNet`. The defaults are the paper's (Sec. 3.1-3.3).

    num_cuboids: M, the number of cuboids predicted per shape.
    k: neighbours of each point in the EdgeConv graph, the point itself included.
    edge_dims: output width of each EdgeConv layer of E_pp (both 1x1 layers of a block have it);
        the point feature f^p has sum(edge_dims) channels (paper: 64 + 64 = 128).
    global_dim: width of the global feature f^g (paper: 1024).
    latent_dim: size of the latent code z (paper: 512).
    cuboid_code_dim: width of the one-hot cuboid code embedding E_cb (paper: 64).
    cuboid_feature_dims: widths of the layers of E_cf; the last one is the cuboid feature f^c
        (paper: 128; the public code's hidden layer has 256).
    exist_hidden_dim: hidden width of the existence head of D_cp (public code: 32).
    seg_dim: width of g^p and g^c in the segmentation branch (paper: 64).
    attention_scale: divide the affinity A_mn = g^c_m . g^p_n by sqrt(seg_dim) before the softmax,
        as the public code does; the paper's Eq. (2) has no scale (default False).
    cosine_affinity: None (the paper's dot product, default) or a positive number s: the affinity
        becomes A_mn = s cos(g^c_m, g^p_n), bounded by |A_mn| <= s, so the softmax of Eq. (3) can
        never saturate beyond a gap of 2 s (a change of the course's recipe, not the paper's).
    affinity_temperature: T >= 1 divides the affinity before the softmax, W = softmax(A / T), so the
        allocation stays softer and a misallocated point keeps a gradient towards other cuboids; the
        argmax, hence the segmentation, does not change with T (default 1: the paper's Eq. (3)).
    negative_slope: slope of every LeakyReLU (public code: 0.2).
    input_normals: what the first EdgeConv reads of each point's unit normal. "none" (default): the
        coordinates alone, as in the paper and the public code, which use the normals only in the
        loss. "differences": the edge feature becomes [x_j - x_i, n_j - n_i, x_i], so a point feature
        sees where the surface bends (a crease between two parts) but not which way a flat face
        points. "absolute": [x_j - x_i, n_j - n_i, x_i, n_i], the normal itself too. The kNN graph stays
        that of the 3-D points; with either of the last two the network needs the normals at
        inference (``forward(points, normals)``).

    ``to_dict`` / ``from_dict`` convert to and from a dict of plain JSON types (for checkpoints).
    """

    num_cuboids: int = 16
    k: int = 20
    edge_dims: tuple[int, ...] = (64, 64)
    global_dim: int = 1024
    latent_dim: int = 512
    cuboid_code_dim: int = 64
    cuboid_feature_dims: tuple[int, ...] = (256, 128)
    exist_hidden_dim: int = 32
    seg_dim: int = 64
    attention_scale: bool = False
    negative_slope: float = 0.2
    cosine_affinity: float | None = None
    affinity_temperature: float = 1.0
    input_normals: str = "none"

    def __post_init__(self) -> None:
        for name in ("edge_dims", "cuboid_feature_dims"):
            value = getattr(self, name)
            if isinstance(value, (list, tuple)):
                object.__setattr__(self, name, tuple(value))
        counts = ("num_cuboids", "k", "global_dim", "latent_dim", "cuboid_code_dim", "exist_hidden_dim", "seg_dim")
        for name in counts:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"ModelConfig.{name} must be a positive integer, got {value!r}")
        for name in ("edge_dims", "cuboid_feature_dims"):
            value = getattr(self, name)
            if (
                not isinstance(value, tuple)
                or not value
                or any(isinstance(v, bool) or not isinstance(v, int) or v < 1 for v in value)
            ):
                raise ValueError(
                    f"ModelConfig.{name} must be a non-empty sequence of positive integers, got {value!r}"
                )
        if not isinstance(self.attention_scale, bool):
            raise ValueError(f"ModelConfig.attention_scale must be True or False, got {self.attention_scale!r}")
        if self.input_normals not in INPUT_NORMALS:
            raise ValueError(f"ModelConfig.input_normals must be one of {INPUT_NORMALS}, got {self.input_normals!r}")
        cos = self.cosine_affinity
        if cos is not None:
            if isinstance(cos, bool) or not isinstance(cos, (int, float)) or not 0.0 < cos <= 1000.0:
                raise ValueError(f"ModelConfig.cosine_affinity must be None or a number in (0, 1000], got {cos!r}")
            if self.attention_scale:
                raise ValueError("ModelConfig.cosine_affinity and attention_scale exclude each other; set one of them")
            object.__setattr__(self, "cosine_affinity", float(cos))
        temp = self.affinity_temperature
        if isinstance(temp, bool) or not isinstance(temp, (int, float)) or not 1.0 <= temp <= 100.0:
            raise ValueError(f"ModelConfig.affinity_temperature must be a number in [1, 100], got {temp!r}")
        object.__setattr__(self, "affinity_temperature", float(temp))
        slope = self.negative_slope
        if isinstance(slope, bool) or not isinstance(slope, (int, float)) or not 0.0 <= slope < 1.0:
            raise ValueError(f"ModelConfig.negative_slope must be a number in [0, 1), got {slope!r}")
        object.__setattr__(self, "negative_slope", float(slope))
        # Bounds, so that a config read from a file cannot ask for an absurd allocation
        for name in counts:
            if getattr(self, name) > _MAX_WIDTH:
                raise ValueError(f"ModelConfig.{name} = {getattr(self, name)} is above the limit of {_MAX_WIDTH}")
        for name in ("edge_dims", "cuboid_feature_dims"):
            value = getattr(self, name)
            if len(value) > _MAX_LAYERS or max(value) > _MAX_WIDTH:
                raise ValueError(f"ModelConfig.{name} = {list(value)} has more than {_MAX_LAYERS} layers or a "
                                 f"width above {_MAX_WIDTH}")
        if self.k > 1024:
            raise ValueError(f"ModelConfig.k = {self.k} is above the limit of 1024 neighbours")
        if self.approximate_parameters() > _MAX_PARAMETERS:
            raise ValueError(
                f"ModelConfig describes a network of about {self.approximate_parameters() / 1e6:.0f} million "
                f"parameters; at most {_MAX_PARAMETERS / 1e6:.0f} million are accepted (the paper's: "
                f"{ModelConfig().approximate_parameters() / 1e6:.1f} million)"
            )

    def approximate_parameters(self) -> int:
        """Number of weights of the network's matrices (biases and normalisation left out)."""
        widths, total, prev = self.edge_dims, 0, self.input_dim
        relative = self.relative_dims
        for w in widths:  # EdgeConv blocks: two 1x1 layers on (x_i, x_j - x_i)
            total += (2 * prev - relative) * w + w * w
            prev, relative = w, 0
        total += self.point_feature_dim * self.global_dim + 2 * self.global_dim * self.latent_dim
        chain = (self.latent_dim + self.cuboid_code_dim,) + self.cuboid_feature_dims
        total += sum(a * b for a, b in zip(chain, chain[1:])) + self.num_cuboids * self.cuboid_code_dim
        f_c = self.cuboid_feature_dims[-1]
        total += f_c * (self.exist_hidden_dim + 10) + (self.point_feature_dim + f_c) * self.seg_dim
        return total

    @classmethod
    def small(cls, **overrides) -> "ModelConfig":
        """A narrow model for quick CPU experiments (same structure, about 17x fewer parameters)."""
        sizes = dict(
            k=16,
            edge_dims=(32, 32),
            global_dim=256,
            latent_dim=64,
            cuboid_code_dim=32,
            cuboid_feature_dims=(128, 64),
            exist_hidden_dim=16,
            seg_dim=32,
        )
        sizes.update(overrides)
        return cls(**sizes)

    @property
    def input_dim(self) -> int:
        """Channels per point that enter the first EdgeConv: 3 coordinates, plus the normal's 3 unless
        ``input_normals`` is "none"."""
        return 3 if self.input_normals == "none" else 6

    @property
    def relative_dims(self) -> int:
        """Trailing input channels of the first EdgeConv that enter only as differences n_j - n_i."""
        return 3 if self.input_normals == "differences" else 0

    @property
    def point_feature_dim(self) -> int:
        """Channels of the point feature f^p (concatenation of the EdgeConv outputs)."""
        return sum(self.edge_dims)


# ----------------------------------------------------------------------------------------------
# Helpers
# ----------------------------------------------------------------------------------------------


def _uses_batch_stats(bn: nn.BatchNorm1d) -> bool:
    """Whether ``bn`` normalises with batch statistics (training) or running ones (evaluation)."""
    return bn.training or bn.running_mean is None


def _next_momentum(bn: nn.BatchNorm1d) -> float:
    """Count one more training batch in ``bn`` and return its running-average factor (as nn.BatchNorm)."""
    bn.num_batches_tracked.add_(1)
    return bn.momentum if bn.momentum is not None else 1.0 / float(bn.num_batches_tracked)


def _update_running_stats(bn: nn.BatchNorm1d, mean: torch.Tensor, var: torch.Tensor, count: int) -> None:
    """Update ``bn``'s running statistics as nn.BatchNorm does, from the batch mean and biased variance."""
    if not bn.training or bn.running_mean is None:
        return
    with torch.no_grad():
        momentum = _next_momentum(bn)
        bn.running_mean.mul_(1 - momentum).add_(mean.detach(), alpha=momentum)
        unbiased = var.detach() * (count / max(count - 1, 1))
        bn.running_var.mul_(1 - momentum).add_(unbiased, alpha=momentum)


def _scale_sign(gamma: torch.Tensor) -> torch.Tensor:
    """+1 where the BatchNorm scale is >= 0, else -1 (the max over a set commutes with a monotone map)."""
    return torch.where(gamma.detach() >= 0, 1.0, -1.0).to(gamma.dtype)


def reparameterize(
    mu: torch.Tensor, logvar: torch.Tensor, generator: torch.Generator | None = None
) -> torch.Tensor:
    """z = mu + sigma * n with sigma = exp(logvar / 2) and n ~ N(0, I), Eq. (1).

    mu, logvar: (B, D). The paper writes sigma for the standard deviation in Eq. (1) and for the
    log-variance in its KL loss (Eq. (8)); the network predicts the log-variance.
    """
    noise = torch.randn(mu.shape, generator=generator, dtype=mu.dtype, device=mu.device)
    return mu + noise * torch.exp(0.5 * logvar)


# ----------------------------------------------------------------------------------------------
# EdgeConv and the global feature (Sec. 3.1): readable versions first, then the fast ones
# ----------------------------------------------------------------------------------------------


class EdgeConv(nn.Module):
    """One EdgeConv layer [DGCNN] of the point-feature encoder E_pp (Sec. 3.1), as the paper describes it.

    For every point i and each of its k nearest neighbours j (itself included) the edge feature
    [x_j - x_i, x_i] goes through two shared 1x1 layers (``conv1``: 2 C_in -> C_out and ``conv2``:
    C_out -> C_out, no bias), each followed by BatchNorm over all B*N*k edges and LeakyReLU; the
    output is the max over the k edges. This is the readable version: it builds the explicit
    (B, 2 C_in, N, k) edge tensor. :class:`FastEdgeConv` computes the same function with the same
    parameters faster; the network uses it unless built with ``fast=False``. ``relative_dims`` = r: the
    last r input channels enter the edge feature only as differences, [x_j - x_i, x_i without them]
    (2 C_in - r channels; the first layer of a network with ``input_normals="differences"``).

    Example::

        >>> conv = EdgeConv(3, 64, k=20)
        >>> conv(torch.rand(2, 1024, 3)).shape
        torch.Size([2, 1024, 64])
    """

    def __init__(self, in_dim: int, out_dim: int, k: int, negative_slope: float = 0.2, relative_dims: int = 0):
        super().__init__()
        if not 0 <= relative_dims < in_dim:
            raise ValueError(f"relative_dims must lie in [0, in_dim) = [0, {in_dim}), got {relative_dims}")
        self.in_dim, self.out_dim, self.k = in_dim, out_dim, k
        self.relative_dims = relative_dims
        self.negative_slope = negative_slope
        self.conv1 = nn.Linear(2 * in_dim - relative_dims, out_dim, bias=False)
        self.bn1 = nn.BatchNorm1d(out_dim)
        self.conv2 = nn.Linear(out_dim, out_dim, bias=False)
        self.bn2 = nn.BatchNorm1d(out_dim)

    def _neighbours(self, x: torch.Tensor, neighbours: torch.Tensor | None) -> torch.Tensor:
        if neighbours is None:
            return knn_indices(x, self.k)
        check_shape(neighbours, (x.shape[0], x.shape[1], self.k), "neighbours")
        return neighbours

    def forward(self, x: torch.Tensor, neighbours: torch.Tensor | None = None) -> torch.Tensor:
        """x: (B, N, C_in) -> (B, N, C_out). neighbours: (B, N, k) indices, default kNN of x."""
        nbr = self._neighbours(x, neighbours)
        batch, n, c = x.shape
        offsets = torch.arange(batch, device=x.device).view(batch, 1, 1) * n
        x_j = x.reshape(batch * n, c)[(nbr + offsets).reshape(-1)].view(batch, n, self.k, c)
        x_i = x.unsqueeze(2).expand(batch, n, self.k, c)
        x_i_kept = x_i[..., : c - self.relative_dims]  # the last relative_dims channels enter as differences only
        edges = torch.cat([x_j - x_i, x_i_kept], dim=-1).permute(0, 3, 1, 2)  # (B, 2C - r, N, k)
        h = edges
        for conv, bn in ((self.conv1, self.bn1), (self.conv2, self.bn2)):
            h = F.conv2d(h, conv.weight[:, :, None, None])
            momentum = _next_momentum(bn) if bn.training and bn.running_mean is not None else 0.0
            h = F.batch_norm(h, bn.running_mean, bn.running_var, bn.weight, bn.bias, bn.training, momentum, bn.eps)
            h = F.leaky_relu(h, self.negative_slope)
        return h.max(dim=-1).values.transpose(1, 2)  # (B, N, C_out)


class GlobalFeature(nn.Module):
    """Shared fully connected layer + BatchNorm + LeakyReLU applied to every point, then max-pooled.

    (B, N, C_in) point features -> (B, C_out) global feature f^g (Sec. 3.1, as in PointNet). The
    readable version; :class:`FastGlobalFeature` is the same function, faster.
    """

    def __init__(self, in_dim: int, out_dim: int, negative_slope: float = 0.2):
        super().__init__()
        self.linear = nn.Linear(in_dim, out_dim, bias=False)
        self.bn = nn.BatchNorm1d(out_dim)
        self.negative_slope = negative_slope

    def forward(self, f: torch.Tensor) -> torch.Tensor:
        """f: (B, N, C_in) -> (B, C_out)."""
        h = self.linear(f).transpose(1, 2)  # (B, C_out, N)
        h = self.bn(h)
        return F.leaky_relu(h, self.negative_slope).max(dim=-1).values


# ----------------------------------------------------------------------------------------------
# Fast versions (same functions, same parameters; see FastEdgeConv for the differences)
# ----------------------------------------------------------------------------------------------


def _use_compiled(P: torch.Tensor, k: int) -> bool:
    """Whether _EdgeMLP runs its chunk loops with the compiled kernels (:mod:`cuboidlib.kernels`)."""
    return kernels.enabled() and P.device.type == "cpu" and k <= 256


class _EdgeMLP(torch.autograd.Function):
    """Per-edge part of EdgeConv, computed chunk by chunk over points, and its exact gradient.

    Inputs (R = B * N rows, E = R * k edges):
        P, Q (R, C1): per-point projections; the first layer's value on edge (i, j) is u = P_j + Q_i.
        nbr (R, k): global row index j of each neighbour of row i.
        gamma1, beta1 (C1): BatchNorm of u;  mean1, var1 (C1): its mean and biased variance.
        W2 (C2, C1): second layer (its rows already multiplied by the sign of BatchNorm-2's scale).
        batch_stats: whether mean1, var1 are the batch statistics of u (training), so that the
            gradient flows through them too, or fixed running statistics (evaluation).
        eps, slope: BatchNorm epsilon, LeakyReLU slope;  rows: points per chunk.
    Per edge: v = LeakyReLU(gamma1 (u - mean1) / sqrt(var1 + eps) + beta1), h = W2 v.
    Outputs: hmax (R, C2) = max of h over the k neighbours, and the mean and biased variance of h
    over all E edges (C2 each), from which the caller applies BatchNorm-2 and LeakyReLU to hmax.
    The gradient of the max goes to one maximising edge (as torch.max), the one that was kept
    in the forward pass. Only (R, C) tensors are kept for the backward pass, which recomputes each
    chunk's edges.
    """

    @staticmethod
    def forward(ctx, P, Q, nbr, gamma1, beta1, W2, mean1, var1, batch_stats, eps, slope, rows):
        R, k = nbr.shape
        rstd1 = torch.rsqrt(var1 + eps)
        scale1 = gamma1 * rstd1
        P1 = P * scale1  # u -> gamma1 (u - mean1) rstd1 + beta1 = P1_j + Q1_i
        Q1 = Q * scale1 + (beta1 - scale1 * mean1)
        # The value of h on an edge at the BatchNorm mean, a typical value of h: the chunks produce
        # h - shift, whose sums give an accurate variance.
        shift = W2 @ F.leaky_relu(beta1, slope)
        if _use_compiled(P, k):
            hmax, harg, s1, s2 = kernels.ops().edge_mlp_forward(P1, Q1, nbr, W2, shift, slope, rows)
        else:
            hmax, harg, s1, s2 = _EdgeMLP._forward_chunks(P1, Q1, nbr, W2, shift, slope, rows)
        hmax += shift
        n_edges = R * k
        m = s1 / n_edges
        h_mean = shift + m
        h_var = (s2 / n_edges - m * m).clamp_min(0)
        ctx.save_for_backward(P, Q, nbr, gamma1, beta1, W2, mean1, rstd1, harg, h_mean)
        ctx.batch_stats = batch_stats
        ctx.slope = slope
        ctx.rows = rows
        return hmax, h_mean, h_var

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, g_hmax, g_hmean, g_hvar):
        P, Q, nbr, gamma1, beta1, W2, mean1, rstd1, harg, h_mean = ctx.saved_tensors
        slope, rows = ctx.slope, ctx.rows
        R, k = nbr.shape
        n_edges = R * k
        P_hat = P * rstd1  # normalised u: xhat = P_hat_j + Q_hat_i
        Q_hat = (Q - mean1) * rstd1
        g_hmax = g_hmax.contiguous()
        # dL/dh = dL/dmean / E + dL/dvar * 2 (h - mean) / E, plus dL/dhmax on the maximising edge
        c_var = g_hvar * (2.0 / n_edges)
        c_mean = g_hmean / n_edges - c_var * h_mean
        W2_var = W2 * c_var.unsqueeze(1)
        chunks = (P_hat, Q_hat, nbr, gamma1, beta1, W2, W2_var, c_mean, harg, g_hmax, slope, rows, ctx.batch_stats)
        if _use_compiled(P, k):
            g_W2, g_rowsum, g_scatter, x_scatter = kernels.ops().edge_mlp_backward(*chunks)
        else:
            g_W2, g_rowsum, g_scatter, x_scatter = _EdgeMLP._backward_chunks(*chunks)
        # Sums over all edges, from the per-point sums: sum dL/dz and sum dL/dz * xhat.
        sum_gz = g_rowsum.sum(0)
        sum_gzx = (g_scatter * P_hat).sum(0) + (g_rowsum * Q_hat).sum(0)
        # BatchNorm backward, dL/du = gamma rstd (dL/dz - mean(dL/dz) - xhat mean(dL/dz xhat)), summed
        # over the k edges (i, .) of each point (for Q) and over the edges (., j) ending at it (for P).
        scale1 = gamma1 * rstd1
        if ctx.batch_stats:
            mean_gz = sum_gz / n_edges
            mean_gzx = sum_gzx / n_edges
            in_degree = torch.bincount(nbr.reshape(-1), minlength=R).to(P.dtype).unsqueeze(1)
            x_rowsum = k * Q_hat + F.embedding_bag(nbr, P_hat, mode="sum")
            g_Q = scale1 * (g_rowsum - k * mean_gz - x_rowsum * mean_gzx)
            g_P = scale1 * (g_scatter - in_degree * mean_gz - x_scatter * mean_gzx)
        else:
            g_Q = scale1 * g_rowsum
            g_P = scale1 * g_scatter
        return g_P, g_Q, None, sum_gzx, sum_gz, g_W2, None, None, None, None, None, None

    @staticmethod
    def _forward_chunks(P1, Q1, nbr, W2, shift, slope, rows):
        """The per-edge loop of forward: (hmax - shift, argmax over the k neighbours, sum of h - shift,
        sum of (h - shift)^2). ``kernels.cpp``'s edge_mlp_forward is the compiled version of it."""
        R, C1 = P1.shape
        k = nbr.shape[1]
        C2 = W2.shape[0]
        hmax = P1.new_empty(R, C2)
        harg = torch.empty(R, C2, dtype=torch.uint8 if k <= 256 else torch.long, device=P1.device)
        position = torch.arange(k, dtype=P1.dtype, device=P1.device).view(1, k, 1)
        s1 = P1.new_zeros(C2)
        s2 = P1.new_zeros(C2)
        for r0 in range(0, R, rows):
            r1 = min(R, r0 + rows)
            v = P1.index_select(0, nbr[r0:r1].reshape(-1)).view(r1 - r0, k, C1)
            F.leaky_relu_(v.add_(Q1[r0:r1].unsqueeze(1)), slope)
            hc = torch.addmm(-shift, v.view(-1, C1), W2.T)  # h - shift, (edges, C2)
            s1 += hc.sum(0)
            hc3 = hc.view(r1 - r0, k, C2)
            top = torch.amax(hc3, dim=1, keepdim=True)
            hmax[r0:r1] = top.squeeze(1)
            # index of a maximising neighbour (the last one if several tie): 1 + sign(h - max) is 1
            # at the maxima and 0 elsewhere (float arithmetic is much faster here than comparisons)
            at_max = torch.sub(hc3, top).sign_().add_(1).mul_(position)
            harg[r0:r1] = torch.amax(at_max, dim=1)
            s2 += hc.mul_(hc).sum(0)
        return hmax, harg, s1, s2

    @staticmethod
    def _backward_chunks(P_hat, Q_hat, nbr, gamma1, beta1, W2, W2_var, c_mean, harg, g_hmax, slope, rows, batch_stats):
        """The per-edge loop of backward: (dL/dW2, per point i the sum of dL/dz over its edges (i, .),
        per point j the sums of dL/dz and of xhat over the edges (., j) ending at it (the latter only
        with ``batch_stats``, else None)). ``kernels.cpp``'s edge_mlp_backward is the compiled version; it
        returns the same sums computed with two matrix products per chunk instead of three (its comments
        derive them)."""
        R, C1 = P_hat.shape
        k = nbr.shape[1]
        C2 = W2.shape[0]
        g_W2 = torch.zeros_like(W2)
        g_rowsum = torch.empty_like(Q_hat)  # per point i: sum over its k edges of dL/dz
        g_scatter = torch.zeros_like(P_hat)  # per point j: sum over the edges (i, j) of dL/dz
        x_scatter = torch.zeros_like(P_hat) if batch_stats else None  # the same for xhat
        for r0 in range(0, R, rows):
            r1 = min(R, r0 + rows)
            idx = nbr[r0:r1].reshape(-1)
            xhat = P_hat.index_select(0, idx).view(r1 - r0, k, C1).add_(Q_hat[r0:r1].unsqueeze(1))
            if x_scatter is not None:
                x_scatter.index_add_(0, idx, xhat.view(-1, C1))
            v = F.leaky_relu_(torch.addcmul(beta1, xhat, gamma1), slope).view(-1, C1)
            gh = torch.addmm(c_mean, v, W2_var.T)  # c_mean + c_var * h
            gh.view(r1 - r0, k, C2).scatter_add_(1, harg[r0:r1].long().unsqueeze(1), g_hmax[r0:r1].unsqueeze(1))
            g_W2.addmm_(gh.T, v)
            # LeakyReLU backward from its output (v > 0 exactly where its input is > 0)
            gz = torch.ops.aten.leaky_relu_backward(gh @ W2, v, slope, True)
            g_rowsum[r0:r1] = gz.view(r1 - r0, k, C1).sum(1)
            g_scatter.index_add_(0, idx, gz)
        return g_W2, g_rowsum, g_scatter, x_scatter


class FastEdgeConv(EdgeConv):
    """FAST VERSION of :class:`EdgeConv`: the same function of the same parameters (state dicts are
    interchangeable), faster and with far less memory (``benchmarks/bench_model.py --variant fast
    readable`` measures a training step of each).

    Differences from the readable version, none of which changes the result beyond rounding:

    1. the first 1x1 layer of the edge feature [x_j - x_i, x_i] is linear, so it is computed once per
       point (P_j + Q_i) and gathered, instead of once per edge;
    2. LeakyReLU and BatchNorm's per-channel affine map are monotone, so the max over the k
       neighbours is taken before the second BatchNorm and LeakyReLU (the min where its scale is
       negative);
    3. the per-edge part runs in chunks of ``edges_per_chunk`` edges (default: 2^14 on the CPU, 2^20 on a
       GPU) with a hand-written backward
       (:class:`_EdgeMLP`) that recomputes each chunk instead of storing (B, N, k, C) tensors; the
       first BatchNorm's statistics come from per-point sums (:meth:`_edge_stats`).

    BatchNorm still uses the statistics of all edges, and the running statistics are updated the same
    way. Tests compare values, gradients and running statistics with :class:`EdgeConv` in float64.
    """

    def __init__(self, in_dim: int, out_dim: int, k: int, negative_slope: float = 0.2,
                 edges_per_chunk: int | None = None, relative_dims: int = 0):
        super().__init__(in_dim, out_dim, k, negative_slope, relative_dims)
        self.edges_per_chunk = edges_per_chunk

    def _chunk_rows(self, device: torch.device) -> int:
        """Points per chunk: ``edges_per_chunk`` (or the device's default) edges, at least one point."""
        edges = self.edges_per_chunk or (_EDGES_PER_CHUNK if device.type == "cpu" else _EDGES_PER_CHUNK_GPU)
        return max(1, edges // self.k)

    def forward(self, x: torch.Tensor, neighbours: torch.Tensor | None = None) -> torch.Tensor:
        """x: (B, N, C_in) -> (B, N, C_out). neighbours: (B, N, k) indices, default kNN of x."""
        nbr = self._neighbours(x, neighbours)
        batch, n, _ = x.shape
        rows, k = batch * n, self.k
        W_a, W_b = self.conv1.weight[:, : self.in_dim], self.conv1.weight[:, self.in_dim :]
        # conv1 [x_j - x_i, x_i] = W_a (x_j - c) + (W_b x_i - W_a (x_i - c)) = P_j + Q_i for any c; c =
        # the cloud's mean keeps P and Q small, so that little precision is lost when they cancel.
        # (W_b reads x_i without its last relative_dims channels.)
        centred = x - x.detach().mean(dim=1, keepdim=True)
        P = (centred @ W_a.T).reshape(rows, self.out_dim)
        Q = (x[..., : self.in_dim - self.relative_dims] @ W_b.T).reshape(rows, self.out_dim) - P
        offsets = torch.arange(batch, device=x.device).view(batch, 1, 1) * n
        flat_nbr = (nbr + offsets).reshape(rows, k)

        if _uses_batch_stats(self.bn1):
            with torch.no_grad():
                mean1, var1 = self._edge_stats(P.detach(), Q.detach(), flat_nbr, self._chunk_rows(x.device))
            _update_running_stats(self.bn1, mean1, var1, rows * k)
        else:
            mean1, var1 = self.bn1.running_mean, self.bn1.running_var

        sign = _scale_sign(self.bn2.weight)
        hmax, h_mean, h_var = _EdgeMLP.apply(
            P,
            Q,
            flat_nbr,
            self.bn1.weight,
            self.bn1.bias,
            self.conv2.weight * sign.unsqueeze(1),
            mean1,
            var1,
            _uses_batch_stats(self.bn1),
            self.bn1.eps,
            self.negative_slope,
            self._chunk_rows(x.device),
        )
        if _uses_batch_stats(self.bn2):
            _update_running_stats(self.bn2, sign * h_mean, h_var, rows * k)
        else:
            h_mean, h_var = sign * self.bn2.running_mean, self.bn2.running_var
        y = (hmax - h_mean) * (self.bn2.weight * sign) * torch.rsqrt(h_var + self.bn2.eps) + self.bn2.bias
        return F.leaky_relu(y, self.negative_slope).view(batch, n, self.out_dim)

    @staticmethod
    def _edge_stats(P: torch.Tensor, Q: torch.Tensor, nbr: torch.Tensor, rows: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and biased variance over all edges of u = P_j + Q_i, from per-point sums.

        With Qc = Q - mean and S_i = sum of P_j over the neighbours j of i:
        sum over edges of (u - mean)^2 = sum_j indegree_j P_j^2 + k sum_i Qc_i^2 + 2 sum_i Qc_i S_i.
        The terms can be much larger than their sum (P and Q nearly cancel on close neighbours), so
        the sums are taken in float64, where that cancellation costs nothing visible. S is summed
        ``rows`` points at a time, so no (B * N, C) float64 tensor of it is ever stored.
        """
        n_rows, k = nbr.shape
        in_degree = torch.bincount(nbr.reshape(-1), minlength=n_rows)
        if _use_compiled(P, k):  # the same sums, compiled (cuboidlib.kernels)
            mean, var = kernels.ops().edge_stats(P, Q, nbr, in_degree).to(P.dtype)
            return mean, var
        P64, Q64 = P.double(), Q.double()
        in_degree = in_degree.to(P64.dtype)
        mean = (in_degree @ P64 + k * Q64.sum(0)) / (n_rows * k)
        Qc = Q64 - mean
        cross = torch.zeros_like(mean)  # sum_i Qc_i S_i
        for r0 in range(0, n_rows, rows):
            S = P64.index_select(0, nbr[r0 : r0 + rows].reshape(-1)).view(-1, k, P.shape[1]).sum(1)
            cross += (Qc[r0 : r0 + rows] * S).sum(0)
        sq = in_degree @ (P64 * P64) + k * (Qc * Qc).sum(0) + 2 * cross
        return mean.to(P.dtype), (sq / (n_rows * k)).clamp_min(0).to(P.dtype)


class FastGlobalFeature(GlobalFeature):
    """FAST VERSION of :class:`GlobalFeature` (same parameters, same values and gradients).

    Differences: the max over points is taken of the linear layer's output before BatchNorm and
    LeakyReLU (monotone per channel; the min where the scale is negative), and the BatchNorm
    statistics come from the mean and covariance of the input, so the (B, N, C_out) activations are
    never stored.
    """

    def forward(self, f: torch.Tensor) -> torch.Tensor:
        batch, n, c = f.shape
        sign = _scale_sign(self.bn.weight)
        W = self.linear.weight * sign.unsqueeze(1)
        if _uses_batch_stats(self.bn):
            flat = f.reshape(batch * n, c)
            mean_f = flat.mean(0)
            centred = flat - mean_f
            cov = centred.T @ centred / (batch * n)
            mean = W @ mean_f
            var = ((W @ cov) * W).sum(1)
            _update_running_stats(self.bn, sign * mean, var, batch * n)
        else:
            mean, var = sign * self.bn.running_mean, self.bn.running_var
        with torch.no_grad():  # the point where each channel is largest: (B, C_out) row indices
            arg = torch.stack([(W @ f[b].T).argmax(1) for b in range(batch)])
            arg += torch.arange(batch, device=f.device).unsqueeze(1) * n
        chosen = f.reshape(batch * n, c).index_select(0, arg.view(-1)).view(batch, -1, c)  # (B, C_out, C_in)
        hmax = (chosen * W).sum(-1)
        y = (hmax - mean) * (self.bn.weight * sign) * torch.rsqrt(var + self.bn.eps) + self.bn.bias
        return F.leaky_relu(y, self.negative_slope)


# ----------------------------------------------------------------------------------------------
# Feature embedding (Sec. 3.1)
# ----------------------------------------------------------------------------------------------


class FeatureEmbedding(nn.Module):
    """E_pp (EdgeConv layers), the global feature and the VAE head, Sec. 3.1.

    forward(points (B, N, 3), normals (B, N, 3) or None) -> (point_features (B, N, sum(edge_dims)),
    global_feature (B, global_dim), mu (B, latent_dim), logvar (B, latent_dim)). The first EdgeConv
    reads the coordinates (and the normals beside them unless ``input_normals`` is "none") and uses the kNN graph
    of the 3-D points, each later one recomputes it in the previous layer's feature space.
    ``fast=False`` builds the readable :class:`EdgeConv` / :class:`GlobalFeature` instead of their
    fast versions (same parameters and results, slower).
    """

    def __init__(self, config: ModelConfig, fast: bool = True):
        super().__init__()
        dims = (config.input_dim,) + config.edge_dims
        self.input_normals = config.input_normals != "none"
        edge_conv, global_layer = (FastEdgeConv, FastGlobalFeature) if fast else (EdgeConv, GlobalFeature)
        self.edge_convs = nn.ModuleList(
            edge_conv(dims[i], dims[i + 1], config.k, config.negative_slope,
                      relative_dims=config.relative_dims if i == 0 else 0)
            for i in range(len(config.edge_dims))
        )
        self.global_feature = global_layer(config.point_feature_dim, config.global_dim, config.negative_slope)
        self.fc_mu = nn.Linear(config.global_dim, config.latent_dim)
        self.fc_logvar = nn.Linear(config.global_dim, config.latent_dim)

    def forward(
        self, points: torch.Tensor, normals: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """points (B, N, 3), and normals (B, N, 3) unless the config's ``input_normals`` is "none"."""
        h, features, neighbours = points, [], None
        if self.input_normals:  # [x, n] per point; the first graph is that of the 3-D points
            h, neighbours = torch.cat([points, normals], dim=-1), knn_indices(points, self.edge_convs[0].k)
        for conv in self.edge_convs:
            h = conv(h, neighbours)
            features.append(h)
            neighbours = None  # every later layer builds its graph in feature space
        point_features = torch.cat(features, dim=-1)
        global_feature = self.global_feature(point_features)
        return point_features, global_feature, self.fc_mu(global_feature), self.fc_logvar(global_feature)


# ----------------------------------------------------------------------------------------------
# Shape abstraction (Sec. 3.2)
# ----------------------------------------------------------------------------------------------


@dataclass(eq=False)
class CuboidPrediction:
    """Cuboid parameters predicted by D_cp (Sec. 3.2) for B shapes and M cuboids.

    centers (B, M, 3) in (-1, 1) (tanh); quaternions (B, M, 4) unit, (w, x, y, z); half_sizes
    (B, M, 3) in (0, 1) (sigmoid); exist_logits (B, M), the existence delta_m = sigmoid(logit);
    cuboid_features (B, M, C) the cuboid features f^c.
    """

    centers: torch.Tensor
    quaternions: torch.Tensor
    half_sizes: torch.Tensor
    exist_logits: torch.Tensor
    cuboid_features: torch.Tensor

    @property
    def exist_probs(self) -> torch.Tensor:
        """Existence probabilities delta_m = sigmoid(exist_logits), (B, M)."""
        return torch.sigmoid(self.exist_logits)


class CuboidDecoder(nn.Module):
    """D_cp: cuboid feature f^c (..., C) -> centre, quaternion, half size and existence logit (Sec. 3.2).

    Linear heads: half sizes = sigmoid (in (0, 1)), quaternion normalised to unit length, centre =
    tanh (in (-1, 1)); existence = a logit from a small MLP (C -> hidden -> 1). As the paper says
    (Sec. 3.4.5), the biases of the size and translation heads start at 0 and the quaternion
    head's at [1, 0, 0, 0], so training starts from axis-aligned cuboids of half size 0.5 at the
    origin.
    """

    def __init__(self, in_dim: int, exist_hidden_dim: int = 32, negative_slope: float = 0.2):
        super().__init__()
        self.size = nn.Linear(in_dim, 3)
        self.rotation = nn.Linear(in_dim, 4)
        self.translation = nn.Linear(in_dim, 3)
        self.existence = nn.Sequential(
            nn.Linear(in_dim, exist_hidden_dim), nn.LeakyReLU(negative_slope), nn.Linear(exist_hidden_dim, 1)
        )
        with torch.no_grad():
            self.size.bias.zero_()
            self.translation.bias.zero_()
            self.rotation.bias.copy_(torch.tensor([1.0, 0.0, 0.0, 0.0]))

    def forward(self, cuboid_features: torch.Tensor) -> CuboidPrediction:
        return CuboidPrediction(
            centers=torch.tanh(self.translation(cuboid_features)),
            quaternions=F.normalize(self.rotation(cuboid_features), dim=-1),
            half_sizes=torch.sigmoid(self.size(cuboid_features)),
            exist_logits=self.existence(cuboid_features).squeeze(-1),
            cuboid_features=cuboid_features,
        )


class ShapeAbstraction(nn.Module):
    """Latent code z (B, latent_dim) -> M cuboids (Sec. 3.2).

    For cuboid m, the one-hot code v_m goes through E_cb (a bias-free linear layer + LeakyReLU, a
    learned 64-d code per cuboid), is concatenated with z and goes through E_cf (fully connected
    layers with LeakyReLU) to the cuboid feature f^c_m, which D_cp decodes. E_cb, E_cf and D_cp are
    shared by all cuboids; only the one-hot code tells them apart. (The public code's E_cf layers
    have no bias; here they are ordinary fully connected layers with a bias.)
    """

    def __init__(self, config: ModelConfig):
        super().__init__()
        self.num_cuboids = config.num_cuboids
        slope = config.negative_slope
        self.E_cb = nn.Sequential(
            nn.Linear(config.num_cuboids, config.cuboid_code_dim, bias=False), nn.LeakyReLU(slope)
        )
        layers: list[nn.Module] = []
        width = config.latent_dim + config.cuboid_code_dim
        for out in config.cuboid_feature_dims:
            layers += [nn.Linear(width, out), nn.LeakyReLU(slope)]
            width = out
        self.E_cf = nn.Sequential(*layers)
        self.D_cp = CuboidDecoder(width, config.exist_hidden_dim, slope)

    def forward(self, z: torch.Tensor) -> CuboidPrediction:
        batch, m = z.shape[0], self.num_cuboids
        codes = self.E_cb(torch.eye(m, dtype=z.dtype, device=z.device))  # (M, code)
        joint = torch.cat([z.unsqueeze(1).expand(batch, m, -1), codes.expand(batch, m, -1)], dim=-1)
        return self.D_cp(self.E_cf(joint))


# ----------------------------------------------------------------------------------------------
# Cuboid-associated segmentation (Sec. 3.3)
# ----------------------------------------------------------------------------------------------


class CuboidSegmentation(nn.Module):
    """Point-to-cuboid allocation from point and cuboid features, Eq. (2)-(3) (Sec. 3.3).

    g^p = point features reduced to seg_dim, g^c = cuboid features reduced to seg_dim (bias-free
    linear layers); affinity A[b, n, m] = g^c_m . g^p_n (Eq. (2), stored (B, N, M)); W = softmax of
    A over the M cuboids (Eq. (3)); argmax over M gives the segmentation. ``attention_scale=True``
    divides A by sqrt(seg_dim) as the public code does (the paper has no scale);
    ``cosine_affinity=s`` uses A = s cos(g^c_m, g^p_n) instead, bounded by s;
    ``temperature=T`` divides A by T (the returned logits include every factor).
    """

    def __init__(self, point_dim: int, cuboid_dim: int, seg_dim: int = 64, attention_scale: bool = False,
                 cosine_affinity: float | None = None, temperature: float = 1.0):
        super().__init__()
        self.point_proj = nn.Linear(point_dim, seg_dim, bias=False)
        self.cuboid_proj = nn.Linear(cuboid_dim, seg_dim, bias=False)
        self.scale = 1.0 / math.sqrt(seg_dim) if attention_scale else 1.0
        self.cosine_affinity = cosine_affinity
        self.temperature = float(temperature)

    def forward(
        self, point_features: torch.Tensor, cuboid_features: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, N, C_p), (B, M, C_c) -> affinity logits (B, N, M), allocation W (B, N, M)."""
        g_p, g_c = self.point_proj(point_features), self.cuboid_proj(cuboid_features)
        if self.cosine_affinity is not None:
            g_p, g_c = F.normalize(g_p, dim=-1), F.normalize(g_c, dim=-1)
        affinity = g_p @ g_c.transpose(1, 2)
        if self.cosine_affinity is not None:
            affinity = affinity * self.cosine_affinity
        elif self.scale != 1.0:
            affinity = affinity * self.scale
        if self.temperature != 1.0:
            affinity = affinity / self.temperature
        return affinity, torch.softmax(affinity, dim=-1)


@torch.no_grad()
def allocation_saturation(affinity: torch.Tensor, threshold: float = 0.999) -> tuple[torch.Tensor, torch.Tensor]:
    """How hard the allocation softmax (Eq. (3)) is: affinity logits (B, N, M) -> two scalars.

    Returns the fraction of points whose largest weight max_m W_nm exceeds ``threshold`` and the
    median gap between the largest and the second-largest logit. A gap g leaves the other cuboids
    a weight of at most e^-g, and the loss gradient that could move a point to them shrinks with it:
    a point whose gap is 30 is allocated for good.
    """
    if affinity.shape[-1] < 2:
        zero = affinity.new_zeros(())
        return affinity.new_ones(()), zero
    top = affinity.topk(2, dim=-1).values
    gap = top[..., 0] - top[..., 1]
    largest = torch.softmax(affinity, dim=-1).amax(dim=-1)
    return (largest > threshold).to(affinity.dtype).mean(), gap.flatten().median()


# ----------------------------------------------------------------------------------------------
# The whole network
# ----------------------------------------------------------------------------------------------


@dataclass(eq=False)
class ModelOutput(CuboidPrediction):
    """Everything :class:`CuboidAbstractionNet` predicts for a batch of B point clouds of N points.

    Cuboids as in :class:`CuboidPrediction` (M per shape); W (B, N, M) the allocation (rows sum to
    1); affinity (B, N, M) its logits; mu, logvar (B, latent_dim) the mean and LOG-variance of
    q(z | points) (the paper's sigma in the KL loss, Eq. (8)); z (B, latent_dim) the code that was
    decoded; point_features (B, N, C_p) f^p; global_feature (B, global_dim) f^g.
    """

    W: torch.Tensor
    affinity: torch.Tensor
    mu: torch.Tensor
    logvar: torch.Tensor
    z: torch.Tensor
    point_features: torch.Tensor
    global_feature: torch.Tensor

    @property
    def segmentation(self) -> torch.Tensor:
        """Cuboid label of every point, argmax over M of W, (B, N) int64 (Sec. 3.3)."""
        return self.W.argmax(dim=-1)


def read_normals_from_start(state: dict[str, torch.Tensor], input_normals: str) -> dict[str, torch.Tensor]:
    """The weights of a network that reads coordinates only, as those of one that also reads the normals.

    ``state``: the state dict of a network with ``input_normals="none"``, whose first EdgeConv reads the
    edge feature [p_j - p_i, p_i] (``conv1.weight`` of shape (C, 6)). Returned: a copy for the same
    network with ``input_normals`` = "differences" (edge feature [p_j - p_i, n_j - n_i, p_i], weight
    (C, 9)) or "absolute" ([p_j - p_i, n_j - n_i, p_i, n_i], (C, 12)); the columns of the normal channels
    are zero, so that the new network computes exactly the old one's function until training moves them.
    A second training stage uses it to start reading normals from a first stage that did not.

    Example::

        >>> old = CuboidAbstractionNet(ModelConfig.small())
        >>> new = CuboidAbstractionNet(ModelConfig.small(input_normals="differences"))
        >>> new.load_state_dict(read_normals_from_start(old.state_dict(), "differences"))
        <All keys matched successfully>
    """
    if input_normals not in INPUT_NORMALS[1:]:
        raise ValueError(f"input_normals must be one of {INPUT_NORMALS[1:]}, got {input_normals!r}")
    key = "embedding.edge_convs.0.conv1.weight"
    if key not in state:
        raise ValueError(f"the state dict has no {key!r}: it is not that of a CuboidAbstractionNet")
    weight = state[key]
    if weight.dim() != 2 or weight.shape[1] != 6:
        raise ValueError(f"{key} has shape {tuple(weight.shape)}; a network that reads coordinates only has "
                         f"(C, 6) there")
    zeros = weight.new_zeros(weight.shape[0], 3)
    columns = [weight[:, :3], zeros, weight[:, 3:]] + ([zeros] if input_normals == "absolute" else [])
    widened = dict(state)
    widened[key] = torch.cat(columns, dim=1)
    return widened


class CuboidAbstractionNet(nn.Module):
    """The paper's network (Fig. 3): point cloud -> M cuboids + point-to-cuboid allocation.

    ``forward(points)`` runs the feature embedding (Sec. 3.1), the shape abstraction (Sec. 3.2) and
    the segmentation (Sec. 3.3). The latent code is sampled with the re-parameterisation of Eq. (1)
    in training mode and is the mean mu in evaluation mode, unless ``sample_latent`` says otherwise
    (the public code samples in both). ``encode`` gives (mu, logvar); ``decode(z)`` the cuboids of
    latent codes (for generation and interpolation). ``fast=False`` builds the readable EdgeConv and
    global layer (:class:`EdgeConv`, :class:`GlobalFeature`) instead of their fast versions: the
    same parameters (a state dict loads into either) and the same results, several times slower.
    """

    def __init__(self, config: ModelConfig | None = None, fast: bool = True):
        super().__init__()
        self.config = config if config is not None else ModelConfig()
        cfg = self.config
        self.embedding = FeatureEmbedding(cfg, fast)
        self.abstraction = ShapeAbstraction(cfg)
        self.segmentation = CuboidSegmentation(
            cfg.point_feature_dim, cfg.cuboid_feature_dims[-1], cfg.seg_dim, cfg.attention_scale,
            cfg.cosine_affinity, cfg.affinity_temperature,
        )

    def _check_points(self, points) -> torch.Tensor:
        param = next(self.parameters())
        points = as_float_tensor(points, "points", dtype=param.dtype, device=param.device)
        sizes = check_shape(points, ("B", "N", 3), "points")
        if sizes["B"] == 0:
            raise ValueError("points is an empty batch (B = 0); at least one point cloud is needed")
        if sizes["N"] <= self.config.k:
            raise ValueError(
                f"points has N = {sizes['N']} points per cloud but the EdgeConv graph needs N > k = "
                f"{self.config.k}; use more points or a smaller ModelConfig.k"
            )
        check_finite(points, "points")
        return points

    def _check_normals(self, normals, points: torch.Tensor) -> torch.Tensor | None:
        """The normals the encoder reads, (B, N, 3) and finite; None when ``input_normals`` is "none"."""
        if self.config.input_normals == "none":
            return None
        if normals is None:
            raise ValueError(
                f"this network was trained with ModelConfig.input_normals = {self.config.input_normals!r} and reads "
                "each point's normal: "
                "pass normals (B, N, 3) beside the points (cuboidlib.normals.estimate_normals makes them)"
            )
        normals = as_float_tensor(normals, "normals", dtype=points.dtype, device=points.device)
        check_shape(normals, tuple(points.shape), "normals")
        check_finite(normals, "normals")
        return normals

    def encode(self, points: torch.Tensor, normals: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """points (B, N, 3) [, normals (B, N, 3) for a network that reads them, ``input_normals``] -> mu,
        logvar (B, latent_dim) of q(z | points) (Sec. 3.1)."""
        points = self._check_points(points)
        _, _, mu, logvar = self.embedding(points, self._check_normals(normals, points))
        return mu, logvar

    def decode(self, z: torch.Tensor) -> CuboidPrediction:
        """Latent codes z (B, latent_dim) -> cuboids and existence logits (Sec. 3.2)."""
        param = next(self.parameters())
        z = as_float_tensor(z, "z", dtype=param.dtype, device=param.device)
        check_shape(z, ("B", self.config.latent_dim), "z")
        check_finite(z, "z")
        return self.abstraction(z)

    def forward(
        self,
        points: torch.Tensor,
        normals: torch.Tensor | None = None,
        sample_latent: bool | None = None,
        generator: torch.Generator | None = None,
    ) -> ModelOutput:
        """points (B, N, 3) with N > k -> :class:`ModelOutput`.

        normals: (B, N, 3) unit normals, read (and required) when ``ModelConfig.input_normals`` is
            "differences" or "absolute", ignored when it is "none".

        sample_latent: draw z = mu + sigma * n (Eq. (1)) if True, use z = mu if False; None means
            "sample in training mode only". generator: the source of n (default: torch's global one).
        """
        points = self._check_points(points)
        point_features, global_feature, mu, logvar = self.embedding(points, self._check_normals(normals, points))
        if sample_latent is None:
            sample_latent = self.training
        z = reparameterize(mu, logvar, generator) if sample_latent else mu
        cuboids = self.abstraction(z)
        affinity, W = self.segmentation(point_features, cuboids.cuboid_features)
        return ModelOutput(
            **{f.name: getattr(cuboids, f.name) for f in dataclasses.fields(CuboidPrediction)},
            W=W,
            affinity=affinity,
            mu=mu,
            logvar=logvar,
            z=z,
            point_features=point_features,
            global_feature=global_feature,
        )
