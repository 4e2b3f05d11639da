"""Merging the pieces of one part: a post-process of any abstraction, not a step of the paper.

A network, or the per-shape fit, may cut one box-like part into several cuboids: a leg in two, a back
in an upper and a lower half. The reconstruction loss (Eq. 4) does not see it: the pieces cover the
surface as well as one box would. The mIoU does not see it either, since both pieces carry the same
part label. The cuboids-per-instance measure does (:func:`cuboidlib.metrics.part_concision`).

:func:`merge_split_cuboids` merges two cuboids when one box holds them as tightly as they hold
themselves. It compares volumes:

    growth(a, b) = V(a u b) / (V(a) + V(b)) - 1

V(a) is the volume of cuboid a. V(a u b) is the volume of the smallest box around both cuboids, in the
frame of a or of b, whichever is smaller. Every extent is padded by ``pad`` times the abstraction's
diagonal, so that a flat cuboid still has a volume.

* Two halves of one leg: the merged box is the two boxes end to end, growth about 0.
* Two legs side by side: the merged box is mostly the empty space between them, growth well above 1.
* A seat and its back: an L fills a small share of its box, growth well above 1.

The greedy loop merges the pair of least growth while it is at most ``max_growth``. The merged cuboid is
the box around both, in the chosen frame. It keeps the index of the cuboid that held more points, and the
other's points follow it. The other cuboids are left as they were.
"""

from __future__ import annotations

import torch

from .geometry import CORNER_SIGNS, Cuboids
from .results import AbstractionBatch

__all__ = ["merge_growth", "merge_split_cuboids"]


def _extents(centers: torch.Tensor, R: torch.Tensor, half_sizes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """lo, hi (M, M, 3): lo[f, a] and hi[f, a] bound cuboid a in frame f, the frame of cuboid f."""
    corners = centers[:, None] + torch.einsum("aij,akj->aki", R, CORNER_SIGNS.to(centers) * half_sizes[:, None])
    local = torch.einsum("fakj,fji->faki", corners[None] - centers[:, None, None], R)  # (M frames, M, 8, 3)
    return local.amin(dim=2), local.amax(dim=2)


def _pair_growth(lo: torch.Tensor, hi: torch.Tensor, half_sizes: torch.Tensor,
                 pad: float) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`merge_growth` from the extents of :func:`_extents`, without checks (the greedy loop's inner step)."""
    m = half_sizes.shape[0]
    own = (2 * half_sizes + pad).prod(-1)  # (M,)
    # union[f, a, b]: the volume of the box around cuboids a and b in frame f
    union = (torch.maximum(hi[:, :, None], hi[:, None]) - torch.minimum(lo[:, :, None], lo[:, None]) + pad).prod(-1)
    in_a = union.diagonal(dim1=0, dim2=1).T  # in_a[a, b] = union[a, a, b]
    in_b = union.diagonal(dim1=0, dim2=2)  # in_b[a, b] = union[b, a, b]
    index = torch.arange(m, device=half_sizes.device)
    frame = torch.where(in_a <= in_b, index[:, None].expand(m, m), index[None].expand(m, m))
    growth = torch.minimum(in_a, in_b) / (own[:, None] + own[None]) - 1
    return growth.masked_fill(torch.eye(m, dtype=torch.bool, device=half_sizes.device), torch.inf), frame


def _check_non_negative(value, name: str) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
        raise ValueError(f"{name} must be a number >= 0, got {value!r}")


def merge_growth(centers, R, half_sizes, pad: float) -> tuple[torch.Tensor, torch.Tensor]:
    """growth(a, b) of every pair of one shape's cuboids (the module's formula), and the frame that gives it.

    Args:
        centers: (M, 3) the cuboids' centres.
        R: (M, 3, 3) their rotation matrices, columns the local axes (:meth:`Cuboids.rotation_matrices`).
        half_sizes: (M, 3) positive half sizes.
        pad: added to every extent, in the cuboids' units, >= 0.

    Returns:
        (growth, frame), (M, M) each: growth[a, b], symmetric, inf on the diagonal; frame[a, b], a or b, the
        cuboid whose frame gives the smaller box around both.
    """
    centers, R, half_sizes = (torch.as_tensor(t) for t in (centers, R, half_sizes))
    m = centers.shape[0] if centers.dim() == 2 else -1
    if centers.shape != (m, 3) or R.shape != (m, 3, 3) or half_sizes.shape != (m, 3):
        raise ValueError(f"expected centers (M, 3), R (M, 3, 3) and half_sizes (M, 3) of one M; got "
                         f"{tuple(centers.shape)}, {tuple(R.shape)} and {tuple(half_sizes.shape)}")
    _check_non_negative(pad, "pad")
    if not (torch.isfinite(centers).all() and torch.isfinite(R).all() and (half_sizes > 0).all()):
        raise ValueError("centers and R must be finite and half_sizes positive")
    return _pair_growth(*_extents(centers, R, half_sizes), half_sizes, float(pad))


def _merge_shape(labels, centers, quaternions, R, half_sizes, exists, max_growth: float, pad: float):
    """The greedy loop on one shape's tensors (float64); returns changed copies of all but R."""
    labels, centers, quaternions, R, half_sizes, exists = (
        t.clone() for t in (labels, centers, quaternions, R, half_sizes, exists))
    points = torch.bincount(labels, minlength=len(centers))
    while int(exists.sum()) > 1:
        lo, hi = _extents(centers, R, half_sizes)
        growth, frame = _pair_growth(lo, hi, half_sizes, pad)
        growth[~exists] = torch.inf
        growth[:, ~exists] = torch.inf
        a, b = divmod(int(growth.argmin()), len(centers))
        if not growth[a, b] <= max_growth:
            break
        if points[b] > points[a]:  # the merged cuboid keeps the index of the one that held more points
            a, b = b, a
        f = int(frame[a, b])
        lo, hi = torch.minimum(lo[f, a], lo[f, b]), torch.maximum(hi[f, a], hi[f, b])
        centers[a] = centers[f] + R[f] @ (0.5 * (lo + hi))
        quaternions[a], R[a], half_sizes[a] = quaternions[f], R[f], 0.5 * (hi - lo)
        labels[labels == b] = a
        points[a], points[b], exists[b] = points[a] + points[b], 0, False
    return labels, centers, quaternions, half_sizes, exists


def merge_split_cuboids(abstraction: AbstractionBatch, max_growth: float = 0.25, pad: float = 0.05) -> AbstractionBatch:
    """Merge the cuboids that one box holds as tightly as two (the module's greedy loop), shape by shape.

    Args:
        abstraction: B shapes' cuboids (M slots) and, optionally, their segmentation ``labels`` (B, N).
        max_growth: the largest growth(a, b) that still merges, >= 0. 0 merges only cuboids whose box is
            no larger than theirs (overlapping, or touching end to end).
        pad: added to every extent, as a fraction of the diagonal of the box around each shape's cuboids
            (axis-aligned), >= 0.

    Returns:
        An :class:`~cuboidlib.results.AbstractionBatch` with the same M slots: of a merged pair, the slot that
        held more points becomes the box around both, and the other no longer exists. ``labels`` follow the
        merges; ``W`` and ``exist_probs`` are dropped, since they describe the cuboids before merging; ``z``
        is kept.

    Example::

        >>> pred, _ = predict_cuboids(model, shapes)
        >>> merged = merge_split_cuboids(pred)
        >>> merged.num_existing()          # fewer cuboids where a part was cut into pieces
    """
    if not isinstance(abstraction, AbstractionBatch):
        raise TypeError(f"abstraction must be an AbstractionBatch, got {type(abstraction).__name__}")
    _check_non_negative(max_growth, "max_growth")
    _check_non_negative(pad, "pad")
    c = abstraction.cuboids
    b, m = c.batch_size, c.num_cuboids
    exists = c.existing().cpu()
    labels = abstraction.labels
    if labels is None:
        labels = torch.zeros(b, 0, dtype=torch.long)
    elif labels.dim() != 2 or labels.shape[0] != b:
        raise ValueError(f"labels must be (B, N) with B = {b}, got {tuple(labels.shape)}")
    labels = labels.cpu().long()
    if labels.numel() and ((labels < 0).any() or (labels >= m).any() or not exists.gather(1, labels).all()):
        raise ValueError(f"labels must name an existing cuboid (an index in [0, {m}) whose exists is True) "
                         "for every point")
    centers, half = c.centers.detach().cpu().double(), c.half_sizes.detach().cpu().double()
    quats, R = c.quaternions.detach().cpu().double(), c.rotation_matrices().detach().cpu().double()
    corners = c.corners().detach().cpu().double()  # (B, M, 8, 3)
    out = []
    for i in range(b):
        box = corners[i][exists[i]].reshape(-1, 3)
        diagonal = float((box.max(dim=0).values - box.min(dim=0).values).norm()) if len(box) else 0.0
        out.append(_merge_shape(labels[i], centers[i], quats[i], R[i], half[i], exists[i], float(max_growth),
                                float(pad) * diagonal))
    seg, cen, quat, hs, ex = (torch.stack(t) for t in zip(*out))
    to = dict(dtype=c.centers.dtype, device=c.centers.device)
    cuboids = Cuboids(cen.to(**to), quat.to(**to), hs.to(**to), ex.to(c.centers.device), validate=False)
    merged_labels = None if abstraction.labels is None else seg.to(abstraction.labels.device)
    return AbstractionBatch(cuboids, merged_labels, z=abstraction.z)
