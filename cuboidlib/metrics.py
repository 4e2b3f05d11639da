"""Evaluation metrics (Sec. 4.1-4.3): Chamfer distance, normal consistency, mIoU by label transfer, N_AC.

The authors published no evaluation code and papers report the Chamfer distance in incompatible ways,
so every choice is explicit: a :class:`ChamferConvention` says how a Chamfer distance is computed, and
its :meth:`~ChamferConvention.describe` is printed beside every number. :func:`segment_box_distance`
(do segmentation and abstraction agree?) and :func:`reassigned_fraction` (do allocation and existence
agree?) are the course's measures, not the paper's; so is :func:`part_concision` (is a part split into several
cuboids, or are several parts merged into one?).

Shapes: points and normals (B, N, 3); cuboids as in :mod:`cuboidlib.geometry`; segmentations and
part labels (S, N) integer tensors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ._checks import as_float_tensor, check_finite, check_shape
from .geometry import sample_cuboid_surfaces, validate_cuboids
from .neighbors import nearest_index, nearest_indices
from .rotations import quaternion_to_rotation_matrix

__all__ = [
    "ChamferConvention",
    "cuboid_chamfer_distance",
    "normal_consistency",
    "normal_consistency_terms",
    "number_of_existing_cuboids",
    "transfer_part_labels",
    "part_ious",
    "part_confusion",
    "mean_iou",
    "part_concision",
    "segment_box_distance",
    "reassigned_fraction",
]

_NORMS = ("squared_l2", "l2", "l1")


@dataclass(frozen=True)
class ChamferConvention:
    """How a Chamfer distance is computed and reported; the defaults read the paper's "symmetric L2 CD".

    Args:
        norm: distance of a point to its nearest neighbour (found in Euclidean distance): "squared_l2"
            |a - b|^2 (the paper's "L2 CD"), "l2" |a - b| (point-completion papers' "L1-CD") or "l1" |a - b|_1.
        directions: "sum" or "mean" of the two one-directional means.
        scale: factor on the result (papers often report x100 or x1000).
        n_samples: points sampled on the cuboid surfaces (paper: 4096).
    """

    norm: str = "squared_l2"
    directions: str = "sum"
    scale: float = 1.0
    n_samples: int = 4096

    def __post_init__(self) -> None:
        if self.norm not in _NORMS:
            raise ValueError(f"norm must be one of {_NORMS}, got {self.norm!r}")
        if self.directions not in ("sum", "mean"):
            raise ValueError(f"directions must be 'sum' or 'mean', got {self.directions!r}")
        if not self.scale > 0:
            raise ValueError(f"scale must be positive, got {self.scale!r}")
        if not (isinstance(self.n_samples, int) and self.n_samples >= 1):
            raise ValueError(f"n_samples must be a positive integer, got {self.n_samples!r}")

    def describe(self) -> str:
        """One line stating the convention, printed beside every reported Chamfer distance."""
        norm = {"squared_l2": "squared L2", "l2": "L2 (not squared)", "l1": "L1"}[self.norm]
        scale = "" if self.scale == 1 else f", x{self.scale:g}"
        return (
            f"Chamfer distance: {norm}, mean over points per direction, {self.directions} of the two "
            f"directions{scale}, {self.n_samples} points sampled on the cuboids"
        )

    def pair_distance(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """Distance between matched points under this convention's norm.

        Args:
            a, b: (..., 3) matched points.

        Returns:
            (...) distances.
        """
        diff = a - b
        if self.norm == "squared_l2":
            return diff.square().sum(dim=-1)
        if self.norm == "l2":
            return diff.square().sum(dim=-1).clamp_min(1e-30).sqrt()
        return diff.abs().sum(dim=-1)


def _gather(points: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """points (B, N, C), index (B, K) -> (B, K, C)."""
    return torch.gather(points, 1, index[..., None].expand(-1, -1, points.shape[-1]))


def _sample_cuboids(points, centers, quaternions, half_sizes, exists, n_samples, generator):
    centers, quaternions, half_sizes, exists = validate_cuboids(centers, quaternions, half_sizes, exists)
    return sample_cuboid_surfaces(
        centers.to(points), quaternions.to(points), half_sizes.to(points), n_samples,
        exists=exists, generator=generator, validate=False,
    )


def cuboid_chamfer_distance(
    points,
    centers,
    quaternions,
    half_sizes,
    exists=None,
    convention: ChamferConvention = ChamferConvention(),
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Chamfer distance between the points and the surfaces of the existing cuboids (Table 1).

    CD = scale * [mean_i d(a_i, NN_b(a_i)) + mean_j d(b_j, NN_a(b_j))], halved for directions="mean":
    a are the points, b ``convention.n_samples`` samples uniform by area on the existing cuboids, d the
    convention's norm.

    Args:
        points: (B, N, 3).
        centers, quaternions, half_sizes: (B, M, 3), (B, M, 4) unit (w, x, y, z), (B, M, 3).
        exists: (B, M) bool, or None (every cuboid exists).
        convention: how the distance is computed and scaled (default: the paper's).
        generator: source of the surface samples (None: torch's global one).

    Returns:
        (B,) distances.
    """
    points = as_float_tensor(points, "points")
    check_shape(points, ("B", "N", 3), "points")
    samples = _sample_cuboids(points, centers, quaternions, half_sizes, exists, convention.n_samples, generator)
    to_cuboids, to_points = nearest_indices(points, samples.points)  # both directions in one pass
    forward = convention.pair_distance(points, _gather(samples.points, to_cuboids)).mean(dim=1)  # (B,)
    backward = convention.pair_distance(samples.points, _gather(points, to_points)).mean(dim=1)  # (B,)
    total = forward + backward
    if convention.directions == "mean":
        total = total / 2
    return convention.scale * total


def normal_consistency(
    points,
    normals,
    centers,
    quaternions,
    half_sizes,
    exists=None,
    n_samples: int = 4096,
    generator: torch.Generator | None = None,
    directions: str = "points",
) -> torch.Tensor:
    """Normal consistency of a point cloud and cuboids (Table 4), mean_n |n_n . n(q_n)|.

    q_n is the nearest to p_n of ``n_samples`` points sampled uniformly on the existing cuboids, n(q_n)
    the outward normal of its face. The absolute value ignores how the input normals are oriented;
    1 is perfect, random directions give about 0.5.

    Args:
        points, normals: (B, N, 3); normals non-zero (normalised here).
        centers, quaternions, half_sizes, exists: the cuboids, as in :func:`cuboid_chamfer_distance`.
        n_samples: points sampled on the cuboids.
        generator: source of the surface samples (None: torch's global one).
        directions: "points" (the formula above) or "both": its mean with the other direction,
            mean_s |n(s) . n_p(s)| over the samples s and their nearest input points p(s). Only "both" sees
            cuboid faces that no input point is near, such as the inner faces of stacked slabs (Fig. 9;
            tests/test_metrics.py).

    Returns:
        (B,) values in [0, 1].
    """
    if directions not in ("points", "both"):
        raise ValueError(f"directions must be 'points' or 'both', got {directions!r}")
    from_points, from_cuboids = normal_consistency_terms(points, normals, centers, quaternions, half_sizes, exists,
                                                         n_samples, generator, both=directions == "both")
    return from_points if directions == "points" else 0.5 * (from_points + from_cuboids)


def normal_consistency_terms(points, normals, centers, quaternions, half_sizes, exists=None, n_samples: int = 4096,
                             generator: torch.Generator | None = None, both: bool = True):
    """Both directions of :func:`normal_consistency`, from one nearest-neighbour search on the same samples.

    Args:
        points, normals, centers, quaternions, half_sizes, exists, n_samples, generator: as in
            :func:`normal_consistency`.
        both: also compute the direction from the cuboids.

    Returns:
        (from_points, from_cuboids): (B,) each; from_cuboids is None unless ``both``.
    """
    points = as_float_tensor(points, "points")
    normals = as_float_tensor(normals, "normals").to(points)
    check_shape(points, ("B", "N", 3), "points")
    if normals.shape != points.shape:
        raise ValueError(f"normals must have the shape of points {tuple(points.shape)}, got {tuple(normals.shape)}")
    check_finite(normals, "normals")
    length = normals.norm(dim=-1)
    if (length < 1e-12).any():
        raise ValueError(f"normals: {int((length < 1e-12).sum())} have zero length; every point needs a normal "
                         "(estimate them with cuboidlib.normals.estimate_normals)")
    samples = _sample_cuboids(points, centers, quaternions, half_sizes, exists, n_samples, generator)
    if both:
        nearest, back = nearest_indices(points, samples.points)  # back: (B, S), each sample's nearest input point
    else:
        nearest, back = nearest_index(points, samples.points), None
    unit = normals / length[..., None]
    from_points = (unit * _gather(samples.normals, nearest)).sum(dim=-1).abs().mean(dim=1)  # (B,)
    if back is None:
        return from_points, None
    return from_points, (samples.normals * _gather(unit, back)).sum(dim=-1).abs().mean(dim=1)


def number_of_existing_cuboids(exists) -> torch.Tensor:
    """N_AC of Tables 5-6: the number of existing cuboids, averaged over the shapes.

    Args:
        exists: (B, M) bool.

    Returns:
        () float64.
    """
    exists = torch.as_tensor(exists)
    if exists.dim() != 2:
        raise ValueError(f"exists must have shape (B, M), got {tuple(exists.shape)}")
    return exists.to(torch.float64).sum(dim=1).mean()


def _check_labels(x, name: str) -> torch.Tensor:
    x = torch.as_tensor(x)
    if x.dtype.is_floating_point or x.dtype == torch.bool:
        raise ValueError(f"{name} must hold integer indices, got dtype {x.dtype}")
    if x.dim() != 2:
        raise ValueError(f"{name} must have shape (S, N) (shapes x points), got {tuple(x.shape)}")
    return x.long()


def transfer_part_labels(segmentation, part_labels, num_cuboids: int, num_parts: int) -> torch.Tensor:
    """The part of every cuboid index: the part most of its points carry on labelled shapes (Sec. 4.2).

    The paper labels with a random 20 % of the data.

    Args:
        segmentation: (S, N) int, each point's cuboid index (argmax of W) on the labelled shapes.
        part_labels: (S, N) int, their ground-truth parts.
        num_cuboids: M; the segmentation lies in [0, M).
        num_parts: the part labels lie in [0, num_parts).

    Returns:
        (num_cuboids,) int64, each cuboid index's part; -1 for an index that got no point (its points in a
        scored shape then count as wrong).
    """
    seg = _check_labels(segmentation, "segmentation")
    gt = _check_labels(part_labels, "part_labels")
    if seg.shape != gt.shape:
        raise ValueError(f"segmentation {tuple(seg.shape)} and part_labels {tuple(gt.shape)} must have the same shape")
    if seg.numel() and (seg.min() < 0 or seg.max() >= num_cuboids):
        raise ValueError(f"segmentation indices must lie in [0, {num_cuboids}), got [{int(seg.min())}, {int(seg.max())}]")
    if gt.numel() and (gt.min() < 0 or gt.max() >= num_parts):
        raise ValueError(f"part_labels must lie in [0, {num_parts}), got [{int(gt.min())}, {int(gt.max())}]")
    counts = torch.zeros(num_cuboids * num_parts, dtype=torch.long)
    counts.index_add_(0, (seg * num_parts + gt).flatten(), torch.ones(seg.numel(), dtype=torch.long))
    counts = counts.view(num_cuboids, num_parts)
    labels = counts.argmax(dim=1)
    labels[counts.sum(dim=1) == 0] = -1
    return labels


def _intersections_and_unions(predicted_parts, part_labels, num_parts: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Per shape and label, |pred = l and gt = l| and |pred = l or gt = l|: two (S, num_parts) float64 tensors."""
    pred = _check_labels(predicted_parts, "predicted_parts")
    gt = _check_labels(part_labels, "part_labels")
    if pred.shape != gt.shape:
        raise ValueError(f"predicted_parts {tuple(pred.shape)} and part_labels {tuple(gt.shape)} must have the same shape")
    if pred.numel() == 0:
        raise ValueError("an IoU needs at least one point")
    if isinstance(num_parts, bool) or not isinstance(num_parts, int) or num_parts < 1:
        raise ValueError(f"num_parts must be a positive integer, got {num_parts!r}")
    for t, name in ((gt, "part_labels"), (pred, "predicted_parts")):
        if int(t.max()) >= num_parts:
            raise ValueError(f"{name} holds label {int(t.max())}, but num_parts = {num_parts} allows 0 .. {num_parts - 1}")
    if int(gt.min()) < 0:
        raise ValueError(f"part_labels holds label {int(gt.min())}; true part labels are >= 0")
    labels = torch.arange(num_parts)
    p = pred[..., None] == labels  # (S, N, L)
    g = gt[..., None] == labels
    return (p & g).sum(dim=1).double(), (p | g).sum(dim=1).double()


def part_ious(predicted_parts, part_labels, num_parts: int) -> torch.Tensor:
    """Per-label intersection over union of a part segmentation, over all points of all shapes (Sec. 4.2).

    Args:
        predicted_parts: (S, N) int part indices; -1 is no label.
        part_labels: (S, N) int ground truth in [0, num_parts).
        num_parts: the number of part labels.

    Returns:
        (num_parts,) float64, |pred = l and gt = l| / |pred = l or gt = l|; NaN for a label in neither.
    """
    inter, union = (x.sum(dim=0) for x in _intersections_and_unions(predicted_parts, part_labels, num_parts))
    return torch.where(union > 0, inter / union.clamp_min(1), torch.full_like(union, math.nan))


def part_confusion(predicted_parts, part_labels, num_parts: int) -> torch.Tensor:
    """Confusion matrix of a part segmentation: where the points of every true part went.

    Args:
        predicted_parts, part_labels, num_parts: as in :func:`part_ious`; points labelled -1 are not counted.

    Returns:
        (num_parts, num_parts) int64: [t, p] counts the points of true part t labelled p, over all shapes;
        the diagonal is the intersection of :func:`part_ious`.
    """
    _intersections_and_unions(predicted_parts, part_labels, num_parts)  # the same checks
    pred, gt = torch.as_tensor(predicted_parts).long(), torch.as_tensor(part_labels).long()
    keep = pred >= 0
    return torch.bincount(gt[keep] * num_parts + pred[keep], minlength=num_parts * num_parts).view(num_parts, num_parts)


def mean_iou(predicted_parts, part_labels, num_parts: int, per_shape: bool = False) -> float:
    """Mean per-label intersection over union of a part segmentation (Sec. 4.2).

    Args:
        predicted_parts, part_labels, num_parts: as in :func:`part_ious`.
        per_shape: False: :func:`part_ious` over all points, averaged over the labels that occur (in
            prediction or ground truth). True: the ShapeNet-part variant, the mean over the labels of each
            shape (a label absent from both counts as 1), then over the shapes.

    Returns:
        The mean IoU, a float in [0, 1].
    """
    if not per_shape:
        iou = part_ious(predicted_parts, part_labels, num_parts)
        return float(iou[~iou.isnan()].mean())
    inter, union = _intersections_and_unions(predicted_parts, part_labels, num_parts)  # (S, L)
    return float(torch.where(union > 0, inter / union.clamp_min(1), torch.ones_like(union)).mean())


def part_concision(segmentation, part_labels, instances, num_parts: int, share: float = 0.2) -> dict[str, torch.Tensor]:
    """How concise a segmentation is, per part label: are part instances split, are they merged?

    mIoU sees neither a part cut into several cuboids nor several instances under one cuboid. A part
    instance is one solid of a procedural shape (one leg, one slat of a back; :attr:`cuboidlib.shapes.Shape.instances`).

    * cuboids per instance: for each instance, the number of cuboids that hold at least ``share`` of its
      points; averaged over the instances of each part. 1 means no instance is cut into pieces.
    * instances per cuboid: for each cuboid that holds points, the number of instances that give it at least
      ``share`` of its points; averaged over the cuboids whose points are mostly of each part. Above 1 means
      merging: the right answer for the slats of one back, the wrong one for four legs.

    Args:
        segmentation: (S, N) int, each point's cuboid (any non-negative indices).
        part_labels: (S, N) int ground-truth parts in [0, num_parts).
        instances: (S, N) int part instances, non-negative; indices are per shape, and every point of one
            instance carries one part label.
        num_parts: the number of part labels.
        share: the share of points that makes a cuboid count for an instance (and the other way round),
            in (0, 1].

    Returns:
        {"cuboids_per_instance", "instances_per_cuboid"}: (num_parts,) float64 tensors, NaN for a part with
        no instance (no cuboid).
    """
    seg = _check_labels(segmentation, "segmentation")
    gt = _check_labels(part_labels, "part_labels")
    inst = _check_labels(instances, "instances")
    if not (seg.shape == gt.shape == inst.shape):
        raise ValueError(f"segmentation {tuple(seg.shape)}, part_labels {tuple(gt.shape)} and instances "
                         f"{tuple(inst.shape)} must have the same shape")
    if isinstance(num_parts, bool) or not isinstance(num_parts, int) or num_parts < 1:
        raise ValueError(f"num_parts must be a positive integer, got {num_parts!r}")
    if not (isinstance(share, (int, float)) and 0 < share <= 1):
        raise ValueError(f"share must be a number in (0, 1], got {share!r}")
    for t, name in ((seg, "segmentation"), (inst, "instances")):
        if t.numel() and int(t.min()) < 0:
            raise ValueError(f"{name} must be non-negative indices, got {int(t.min())}")
    if gt.numel() and (int(gt.min()) < 0 or int(gt.max()) >= num_parts):
        raise ValueError(f"part_labels must lie in [0, {num_parts}), got [{int(gt.min())}, {int(gt.max())}]")
    per_instance = [[] for _ in range(num_parts)]
    per_cuboid = [[] for _ in range(num_parts)]
    for s in range(seg.shape[0]):
        n_inst, n_seg = int(inst[s].max()) + 1, int(seg[s].max()) + 1
        # counts[i, j]: points of instance i in cuboid j; part[i]: the label of instance i.
        counts = torch.bincount(inst[s] * n_seg + seg[s], minlength=n_inst * n_seg).view(n_inst, n_seg).double()
        labels = torch.bincount(inst[s] * num_parts + gt[s], minlength=n_inst * num_parts).view(n_inst, num_parts)
        instance_part = labels.argmax(dim=1)
        in_instance, in_cuboid = counts.sum(dim=1), counts.sum(dim=0)
        for i in torch.nonzero(in_instance > 0).flatten().tolist():
            per_instance[int(instance_part[i])].append(int((counts[i] >= share * in_instance[i]).sum()))
        cuboid_labels = torch.bincount(seg[s] * num_parts + gt[s], minlength=n_seg * num_parts).view(n_seg, num_parts)
        for j in torch.nonzero(in_cuboid > 0).flatten().tolist():
            per_cuboid[int(cuboid_labels[j].argmax())].append(int((counts[:, j] >= share * in_cuboid[j]).sum()))

    def means(lists):
        return torch.tensor([sum(v) / len(v) if v else math.nan for v in lists], dtype=torch.float64)

    return {"cuboids_per_instance": means(per_instance), "instances_per_cuboid": means(per_cuboid)}


def segment_box_distance(points, segmentation, centers, quaternions, half_sizes) -> torch.Tensor:
    """Agreement of segmentation and abstraction: mean distance of a point to the solid box of its cuboid.

    With l = R^T (p - c) the point in its cuboid's frame, the distance is |max(|l| - h, 0)|, 0 inside the box.
    On a shape of diagonal 1, 0.01 means the segments lie 1 % of the shape's size outside their boxes.

    Args:
        points: (B, N, 3).
        segmentation: (B, N) int, each point's cuboid index (argmax of W, Sec. 3.3).
        centers, quaternions, half_sizes: (B, M, 3), (B, M, 4), (B, M, 3).

    Returns:
        (B,) the mean over the points.
    """
    points = as_float_tensor(points, "points")
    sizes = check_shape(points, ("B", "N", 3), "points")
    seg = torch.as_tensor(segmentation)
    if seg.dtype.is_floating_point or seg.shape != points.shape[:2]:
        raise ValueError(f"segmentation must be integer indices of shape {tuple(points.shape[:2])}, "
                         f"got dtype {seg.dtype} and shape {tuple(seg.shape)}")
    centers, quaternions, half_sizes, _ = validate_cuboids(centers, quaternions, half_sizes)
    m = centers.shape[1]
    if centers.shape[0] != sizes["B"]:
        raise ValueError(f"the cuboids hold {centers.shape[0]} shapes but points holds {sizes['B']}")
    seg = seg.to(points.device).long()
    if seg.numel() and (seg.min() < 0 or seg.max() >= m):
        raise ValueError(f"segmentation indices must lie in [0, {m}), got [{int(seg.min())}, {int(seg.max())}]")
    pick = lambda x: torch.gather(x.to(points), 1, seg[..., None].expand(-1, -1, x.shape[-1]))  # noqa: E731
    R = quaternion_to_rotation_matrix(pick(quaternions), validate=False)  # (B, N, 3, 3)
    local = torch.einsum("bnj,bnji->bni", points - pick(centers), R)  # (B, N, 3) R^T (p - c)
    outside = (local.abs() - pick(half_sizes)).clamp_min(0)  # (B, N, 3)
    return outside.norm(dim=-1).mean(dim=1)


def reassigned_fraction(allocation, exists) -> torch.Tensor:
    """Share of the points whose most allocated cuboid (Eq. 3) does not exist (Sec. 3.4.3).

    The segmentation moves these points to their most allocated EXISTING cuboid, usually one that does
    not cover them (raising :func:`segment_box_distance`). It happens when the existence target needs more
    points than a small part holds, e.g. the authors' 24 points with 1024 points per shape instead of 4096.

    Args:
        allocation: (B, N, M) the soft allocation W.
        exists: (B, M) bool.

    Returns:
        (B,) in [0, 1].
    """
    allocation = as_float_tensor(allocation, "allocation")
    sizes = check_shape(allocation, ("B", "N", "M"), "allocation")
    exists = torch.as_tensor(exists)
    if exists.dtype != torch.bool or tuple(exists.shape) != (sizes["B"], sizes["M"]):
        raise ValueError(f"exists must be a bool tensor of shape {(sizes['B'], sizes['M'])}, "
                         f"got dtype {exists.dtype} and shape {tuple(exists.shape)}")
    best = allocation.argmax(dim=-1)  # (B, N)
    return (~torch.gather(exists.to(allocation.device), 1, best)).to(allocation.dtype).mean(dim=1)
