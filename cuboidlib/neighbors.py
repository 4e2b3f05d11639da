"""Exact nearest-neighbour search, the one used everywhere in cuboidlib.

EdgeConv's kNN graph (Sec. 3.1, :mod:`cuboidlib.model`), normal estimation (:mod:`cuboidlib.normals`) and
the Chamfer distance (:mod:`cuboidlib.distance`, :mod:`cuboidlib.metrics`) all call the three functions
here. Squared distances are computed block by block as |x|^2 + |y|^2 - 2 x.y (bounded memory, O(N^2)
work), after moving the points' mean to the origin, where that identity keeps its precision. No gradient
flows through the choice of neighbours; callers recompute the distances of the chosen pairs.
"""

from __future__ import annotations

import math

import torch

from . import kernels
from ._checks import check_shape

__all__ = ["knn_indices", "nearest_index", "nearest_indices"]

# Entries of one distance-matrix block (16 MiB in float32).
_BLOCK = 1 << 22
# Above this coordinate magnitude (after centring) a float32 search switches to float64: squared
# distances of float32 overflow at about 1.8e19.
_FLOAT32_SEARCH_LIMIT = 1e15


def _centred(*sets: torch.Tensor) -> list[torch.Tensor]:
    """The sets moved by their common mean (per batch element); float64 if float32 would overflow."""
    with torch.no_grad():
        sets = [s.detach() for s in sets]
        total = sum(s.shape[1] for s in sets)
        mean = sum(s.sum(dim=1, keepdim=True, dtype=torch.float64) for s in sets) / max(total, 1)
        moved = [s - mean.to(s.dtype) for s in sets]
        if all(s.dtype == torch.float32 for s in sets):
            extent = max(float(m.abs().amax()) for m in moved)
            if extent > _FLOAT32_SEARCH_LIMIT:  # NaN compares False: non-finite input stays as it is
                moved = [s.double() - mean for s in sets]
        return moved


def knn_indices(x: torch.Tensor, k: int, sorted: bool = False) -> torch.Tensor:
    """Indices of the k nearest neighbours of every point in its own cloud, the point itself included.

    Args:
        x: (B, N, C) coordinates or features (Euclidean distance in C dimensions).
        k: neighbours per point, 1 <= k <= N.
        sorted: put the point itself first and the others by increasing distance; False leaves the
            order unspecified (faster).

    Returns:
        (B, N, k) int64 indices into dim 1. Non-finite rows (a diverged network) still get valid
        indices, so the NaNs reach the outputs instead of raising an indexing error.

    Example::

        >>> x = torch.tensor([[[0.0, 0, 0], [1, 0, 0], [3, 0, 0]]])
        >>> knn_indices(x, 2, sorted=True)
        tensor([[[0, 1], [1, 0], [2, 1]]])
    """
    check_shape(x, ("B", "N", "C"), "x")
    batch, n, _ = x.shape
    if not isinstance(k, int) or not 1 <= k <= n:
        raise ValueError(f"k must be an integer in [1, N] = [1, {n}], got k = {k!r}")
    (x,) = _centred(x)
    out = torch.empty(batch, n, k, dtype=torch.long, device=x.device)
    compiled = kernels.enabled() and x.device.type == "cpu" and not sorted
    # torch.topk on the CPU switches from a selection algorithm to a faster partial sort on rows
    # of at least 64 k entries; shorter rows are padded with +inf, which is never selected.
    width = max(n, 64 * k) if x.device.type == "cpu" and not compiled else n
    rows = max(1, min(n, _BLOCK // width))
    block = x.new_full((rows, width), math.inf)
    sq = (x * x).sum(-1)
    with torch.no_grad():
        for b in range(batch):
            for r0 in range(0, n, rows):
                r1 = min(n, r0 + rows)
                d = block[: r1 - r0]
                # |x_i|^2 is the same for a whole row, so it does not change the ranking and is left out
                torch.addmm(sq[b].unsqueeze(0), x[b, r0:r1], x[b].T, alpha=-2.0, out=d[:, :n])
                own = torch.arange(r0, r1, device=x.device)
                d[own - r0, own] = -math.inf  # the point itself is always one of its neighbours
                if compiled:  # the same selection, compiled (cuboidlib.kernels)
                    out[b, r0:r1] = kernels.ops().smallest_k(d, k)
                else:
                    out[b, r0:r1] = d.topk(k, dim=1, largest=False, sorted=sorted).indices
    return out.clamp_(max=n - 1)


def _chunk(a: torch.Tensor, b: torch.Tensor, chunk: int | None) -> int:
    return chunk if chunk is not None else max(1, (1 << 24) // max(1, a.shape[0] * b.shape[1]))


def _squared_distances(part: torch.Tensor, b: torch.Tensor, b_sq: torch.Tensor) -> torch.Tensor:
    """(B, n, Nb) squared distances of the points of ``part`` (B, n, C) to b (B, Nb, C); b_sq: (B, 1, Nb)."""
    return torch.baddbmm(b_sq + part.square().sum(-1)[..., None], part, b.transpose(1, 2), alpha=-2)


def nearest_index(a: torch.Tensor, b: torch.Tensor, chunk: int | None = None) -> torch.Tensor:
    """Nearest point of b for every point of a: the first half of :func:`nearest_indices`.

    Args:
        a: (B, Na, C) query points, Na >= 1.
        b: (B, Nb, C) reference points, Nb >= 1.
        chunk: points of a searched at once; None: about 2^24 distances per chunk.

    Returns:
        (B, Na) int64 indices into b.

    Example::

        >>> nearest_index(torch.tensor([[[0.0, 0, 0], [2, 0, 0]]]), torch.tensor([[[1.9, 0, 0], [0.1, 0, 0]]]))
        tensor([[1, 0]])
    """
    check_shape(a, ("B", "Na", "C"), "a")
    check_shape(b, ("B", "Nb", "C"), "b")
    chunk = _chunk(a, b, chunk)
    a, b = _centred(a, b)
    with torch.no_grad():
        b_sq = b.square().sum(-1)[:, None, :]
        return torch.cat([_squared_distances(a[:, start : start + chunk], b, b_sq).argmin(dim=2)
                          for start in range(0, a.shape[1], chunk)], dim=1)


def nearest_indices(a: torch.Tensor, b: torch.Tensor, chunk: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Nearest point of b for every point of a, and of a for every point of b, in one pass.

    Args:
        a: (B, Na, C) points, Na >= 1.
        b: (B, Nb, C) points, Nb >= 1.
        chunk: points of a searched at once; None: about 2^24 distances per chunk.

    Returns:
        ``(a_to_b, b_to_a)``: (B, Na) int64 indices into b and (B, Nb) int64 indices into a. Where
        several points of a are equally near a point of b, any one of them may be returned.

    Example::

        >>> a = torch.tensor([[[0.0, 0, 0], [2, 0, 0]]]); b = torch.tensor([[[1.9, 0, 0]]])
        >>> nearest_indices(a, b)
        (tensor([[0, 0]]), tensor([[1]]))
    """
    check_shape(a, ("B", "Na", "C"), "a")
    check_shape(b, ("B", "Nb", "C"), "b")
    chunk = _chunk(a, b, chunk)
    a, b = _centred(a, b)
    with torch.no_grad():
        b_sq = b.square().sum(-1)[:, None, :]  # (B, 1, Nb)
        a_to_b = torch.empty(a.shape[:2], dtype=torch.long, device=a.device)
        best_b = torch.full(b.shape[:2], math.inf, dtype=a.dtype, device=a.device)
        b_to_a = torch.zeros(b.shape[:2], dtype=torch.long, device=a.device)
        for start in range(0, a.shape[1], chunk):  # loop over memory-sized chunks, not over points
            d2 = _squared_distances(a[:, start : start + chunk], b, b_sq)
            a_to_b[:, start : start + chunk] = d2.argmin(dim=2)
            # The best point of this chunk for every point of b. d2.min(dim=1) would give it directly, but a
            # reduction with indices across rows is several times slower on the CPU than amin; so: the
            # smallest value, then the (largest) row that holds it, as a float index (exact below 2^24).
            value = d2.amin(dim=1)
            rows = torch.arange(d2.shape[1], device=d2.device, dtype=torch.float32)[None, :, None]
            index = torch.where(d2 == value[:, None, :], rows, -1.0).amax(dim=1).long()
            better = value < best_b
            best_b = torch.where(better, value, best_b)
            b_to_a = torch.where(better, index + start, b_to_a)
    return a_to_b, b_to_a
