"""FAST VERSION of the EdgeConv and global layers of :mod:`cuboidlib.model` (Sec. 3.1).

:class:`FastEdgeConv` and :class:`FastGlobalFeature` compute exactly the functions of the readable
:class:`cuboidlib.model.EdgeConv` and :class:`cuboidlib.model.GlobalFeature`, with the same parameters
(state dicts load into either), faster and with far less memory; the network uses them unless built
with ``fast=False``. They live apart so that the readable network reads on its own; this module does
not import :mod:`cuboidlib.model`. tests/test_model.py checks values, gradients and BatchNorm statistics
against the readable layers in float64; ``benchmarks/bench_model.py --variant fast readable`` times both.
On a CPU whose cores are busy with other work, ``torch.set_num_threads(1)`` keeps the chunked EdgeConv's
many small multi-threaded operations from waiting for each other.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from . import kernels
from ._checks import check_shape
from .neighbors import knn_indices

__all__ = ["FastEdgeConv", "FastGlobalFeature"]

# Edges processed at once by the chunked EdgeConv: small enough for a chunk's (edges, channels)
# tensors to stay in the CPU cache, large enough for matrix products to run at full speed.
_EDGES_PER_CHUNK = 1 << 14
# On a GPU every operation of a chunk costs a kernel launch whatever its size, and memory is ample: chunks
# of 1 << 20 edges (a 64-channel float32 chunk tensor is 256 MiB) launch 64 times fewer kernels.
_EDGES_PER_CHUNK_GPU = 1 << 20


# ----------------------------------------------------------------------------------------------
# BatchNorm from statistics computed outside nn.BatchNorm1d
# ----------------------------------------------------------------------------------------------


def _uses_batch_stats(bn: nn.BatchNorm1d) -> bool:
    """Whether ``bn`` normalises with batch statistics (training) or running ones (evaluation)."""
    return bn.training or bn.running_mean is None


def _update_running_stats(bn: nn.BatchNorm1d, mean: torch.Tensor, var: torch.Tensor, count: int) -> None:
    """Count one more batch in ``bn`` and update its running statistics as nn.BatchNorm does, from the
    batch mean and biased variance of ``count`` values."""
    if not bn.training or bn.running_mean is None:
        return
    with torch.no_grad():
        bn.num_batches_tracked.add_(1)
        momentum = bn.momentum if bn.momentum is not None else 1.0 / float(bn.num_batches_tracked)
        bn.running_mean.mul_(1 - momentum).add_(mean.detach(), alpha=momentum)
        unbiased = var.detach() * (count / max(count - 1, 1))
        bn.running_var.mul_(1 - momentum).add_(unbiased, alpha=momentum)


def _scale_sign(gamma: torch.Tensor) -> torch.Tensor:
    """+1 where the BatchNorm scale is >= 0, else -1 (the max over a set commutes with a monotone map)."""
    return torch.where(gamma.detach() >= 0, 1.0, -1.0).to(gamma.dtype)


# ----------------------------------------------------------------------------------------------
# The per-edge part of EdgeConv, chunk by chunk, with its hand-written backward
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


class FastEdgeConv(nn.Module):
    """FAST VERSION of :class:`cuboidlib.model.EdgeConv`: the same function of the same parameters
    (``conv1``, ``bn1``, ``conv2``, ``bn2``; state dicts load into either), faster and in far less memory.

    It differs only in how it computes, none of which changes the result beyond rounding: (1) the first
    1x1 layer, linear in [x_j - x_i, x_i], runs once per point (P_j + Q_i) instead of once per edge;
    (2) BatchNorm's affine map and LeakyReLU are monotone per channel, so the max over the k neighbours
    is taken before the second pair (the min where its scale is negative); (3) the per-edge part runs
    in chunks of ``edges_per_chunk`` edges (default 2^14 on the CPU, 2^20 on a GPU) with a hand-written
    backward (:class:`_EdgeMLP`) that recomputes each chunk instead of storing (B, N, k, C) tensors.
    BatchNorm still uses the statistics of all edges (:meth:`_edge_stats`) and updates its running ones
    as nn.BatchNorm does.

    Args:
        in_dim, out_dim, k, negative_slope, relative_dims: as for :class:`cuboidlib.model.EdgeConv`.
        edges_per_chunk: edges per chunk of the per-edge loop; None: the device's default.
    """

    def __init__(self, in_dim: int, out_dim: int, k: int, negative_slope: float = 0.2,
                 edges_per_chunk: int | None = None, relative_dims: int = 0):
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
        self.edges_per_chunk = edges_per_chunk

    def _neighbours(self, x: torch.Tensor, neighbours: torch.Tensor | None) -> torch.Tensor:
        if neighbours is None:
            return knn_indices(x, self.k)
        check_shape(neighbours, (x.shape[0], x.shape[1], self.k), "neighbours")
        return neighbours

    def _chunk_rows(self, device: torch.device) -> int:
        """Points per chunk: ``edges_per_chunk`` (or the device's default) edges, at least one point."""
        edges = self.edges_per_chunk or (_EDGES_PER_CHUNK if device.type == "cpu" else _EDGES_PER_CHUNK_GPU)
        return max(1, edges // self.k)

    def forward(self, x: torch.Tensor, neighbours: torch.Tensor | None = None) -> torch.Tensor:
        """One EdgeConv layer.

        Args:
            x: (B, N, C_in) point features.
            neighbours: (B, N, k) indices of each point's neighbours; None: the kNN graph of x.

        Returns:
            (B, N, C_out) new point features.
        """
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


class FastGlobalFeature(nn.Module):
    """FAST VERSION of :class:`cuboidlib.model.GlobalFeature`: the same parameters (``linear``, ``bn``),
    values and gradients.

    The max over points is taken of the linear layer's output before BatchNorm and LeakyReLU (monotone
    per channel; the min where the scale is negative), and BatchNorm's statistics come from the mean
    and covariance of the input, so the (B, N, C_out) activations are never stored.
    """

    def __init__(self, in_dim: int, out_dim: int, negative_slope: float = 0.2):
        super().__init__()
        self.linear = nn.Linear(in_dim, out_dim, bias=False)
        self.bn = nn.BatchNorm1d(out_dim)
        self.negative_slope = negative_slope

    def forward(self, f: torch.Tensor) -> torch.Tensor:
        """Args: f: (B, N, C_in) point features. Returns: (B, C_out) the global feature f^g."""
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
