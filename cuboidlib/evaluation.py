"""Scoring a trained network or the k-means baseline on a split of shapes (Sec. 4.1-4.2).

:func:`evaluate_model` runs the network on a :class:`~cuboidlib.dataset.ShapeSet` and
:func:`evaluate_baseline` fits the boxes of :mod:`cuboidlib.baseline` to each shape; both return the
same dict of metrics (:mod:`cuboidlib.metrics`), which :func:`format_table` prints with the convention
behind every number:

* CD under one or more :class:`~cuboidlib.metrics.ChamferConvention`, and NC from the points
  (``normal_consistency``) and both ways (``normal_consistency_both``), averaged over shapes.
* mIoU by label transfer (Sec. 4.2): the paper labels with a random 20 % of the shapes and scores a test
  set; here a seeded 20 % of the evaluated split gives the labels and the other 80 % is scored, so no
  scored shape chose the labels. ``part_iou`` keeps every part's IoU beside the mean.
* N_AC: existing cuboids per shape, existence probability > 0.5 (Tables 5-6).
* Box distance and reassigned points, the course's measures: agreement of segmentation and abstraction,
  and of allocation and existence.

A shape on which the network predicts no existing cuboid is scored with its most probable cuboid
(counted in ``shapes_without_existing_cuboid``); N_AC counts the cuboids actually used.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from ._checks import MAX_CUBOIDS, check_size
from .results import AbstractionBatch
from .applications import abstract_shapes
from .baseline import fit_cluster_boxes
from .merging import merge_split_cuboids
from .metrics import (
    ChamferConvention,
    cuboid_chamfer_distance,
    mean_iou,
    normal_consistency_terms,
    number_of_existing_cuboids,
    part_concision,
    part_confusion,
    part_ious,
    reassigned_fraction,
    segment_box_distance,
    transfer_part_labels,
)
from .dataset import ShapeSet
from .geometry import Cuboids
from .model import CuboidAbstractionNet

__all__ = [
    "predict_cuboids",
    "label_transfer_split",
    "score_cuboids",
    "segmentation_scores",
    "evaluate_model",
    "evaluate_baseline",
    "format_table",
]


def predict_cuboids(
    model: CuboidAbstractionNet, shapes: ShapeSet, batch_size: int = 32, centers_from_allocation: bool = False
) -> tuple[AbstractionBatch, int]:
    """Run the network in evaluation mode (z = mu) on every shape (:func:`cuboidlib.applications.abstract_shapes`).

    A cuboid exists when its existence probability exceeds 0.5, and a shape with none keeps its most
    probable cuboid; every point is segmented to its most allocated existing cuboid.

    Args:
        model: the network.
        shapes: S shapes, points (S, N, 3).
        batch_size: shapes per forward pass.
        centers_from_allocation: place each cuboid at the allocation-weighted centroid of the points
            (:func:`cuboidlib.losses.allocation_weighted_centers`), for networks trained with
            ``LossConfig(centers_from_allocation=True)``, whose translation head the losses never see.

    Returns:
        (pred, fallback): an :class:`~cuboidlib.results.AbstractionBatch` on the CPU (labels (S, N),
        W (S, N, M), exist_probs (S, M)), and the number of shapes that kept their most probable cuboid.
    """
    out = abstract_shapes(model, shapes.points, 0.5, centers_from_allocation, batch_size, normals=shapes.normals)
    empty = ~(out.exist_probs > 0.5).any(dim=1)
    pred = AbstractionBatch(out.cuboids.to(device="cpu"), out.labels.cpu(), out.W.cpu(), out.exist_probs.cpu())
    return pred, int(empty.sum())


def label_transfer_split(n_shapes: int, fraction: float = 0.2, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Seeded split of the shapes into labelled and scored ones, for the label transfer (Sec. 4.2).

    Args:
        n_shapes: at least 2.
        fraction: in (0, 1); round(fraction * n_shapes) shapes are labelled, at least 1, leaving at least 1.
        seed: seed of the permutation.

    Returns:
        (labelled, scored): sorted int64 index tensors.
    """
    if not 0 < fraction < 1:
        raise ValueError(f"label_transfer_fraction must lie in (0, 1), got {fraction}")
    if n_shapes < 2:
        raise ValueError(f"label transfer needs at least 2 shapes (some to label, some to score), got {n_shapes}")
    k = min(n_shapes - 1, max(1, round(fraction * n_shapes)))
    perm = torch.randperm(n_shapes, generator=torch.Generator().manual_seed(seed))
    return perm[:k].sort().values, perm[k:].sort().values


def _shape_generator(seed: int, shape: int) -> torch.Generator:
    """The generator of the surface samples of one shape: results do not depend on batching."""
    return torch.Generator().manual_seed(int(np.random.SeedSequence([seed, shape]).generate_state(1)[0]))


def score_cuboids(
    shapes: ShapeSet,
    pred: AbstractionBatch,
    label_transfer_fraction: float = 0.2,
    conventions: Sequence[ChamferConvention] = (ChamferConvention(),),
    seed: int = 0,
) -> dict:
    """CD (one entry per convention), NC, mIoU by label transfer and N_AC of cuboids fitted to ``shapes``.

    The surface samples of shape i come from a generator seeded with (seed, i): conventions with the same
    ``n_samples`` compare the same samples, and NC uses the samples of the first convention.

    Args:
        shapes: S shapes, points and normals (S, N, 3), labels (S, N) or None.
        pred: their cuboids and segmentation, an :class:`~cuboidlib.results.AbstractionBatch` of S shapes.
        label_transfer_fraction: share of the shapes that label the cuboids (:func:`label_transfer_split`).
        conventions: the Chamfer conventions to report, at least one.
        seed: seed of the surface samples and of the label-transfer split.

    Returns:
        A dict of JSON types: ``n_shapes``; ``chamfer``, per convention its fields, its ``convention``
        (:meth:`~cuboidlib.metrics.ChamferConvention.describe`) and ``value``; ``normal_consistency``,
        ``normal_consistency_both``, ``normal_samples``; the keys of :func:`segmentation_scores`; ``concision``
        (part name -> {"cuboids_per_instance", "instances_per_cuboid"} of :func:`~cuboidlib.metrics.part_concision`,
        None for a part absent from the shapes; None without part labels or instances).
    """
    if not conventions:
        raise ValueError("give at least one Chamfer convention")
    n = len(shapes)
    points, normals = shapes.points.cpu(), shapes.normals.cpu()
    c = pred.cuboids
    cuboids = lambda i: (c.centers[i:i + 1], c.quaternions[i:i + 1], c.half_sizes[i:i + 1], c.exists[i:i + 1])  # noqa: E731
    chamfer = []
    for convention in conventions:
        values = torch.cat([
            cuboid_chamfer_distance(points[i:i + 1], *cuboids(i), convention=convention,
                                    generator=_shape_generator(seed, i))
            for i in range(n)
        ])
        chamfer.append({"norm": convention.norm, "directions": convention.directions, "scale": convention.scale,
                        "n_samples": convention.n_samples, "convention": convention.describe(),
                        "value": float(values.double().mean())})
    n_samples = conventions[0].n_samples
    terms = [normal_consistency_terms(points[i:i + 1], normals[i:i + 1], *cuboids(i), n_samples=n_samples,
                                      generator=_shape_generator(seed, i)) for i in range(n)]
    from_points, from_cuboids = (torch.cat([t[j] for t in terms]) for j in (0, 1))  # (S,) each
    nc = {"points": from_points, "both": 0.5 * (from_points + from_cuboids)}  # normal_consistency's two definitions
    return {
        "n_shapes": n,
        "chamfer": chamfer,
        "normal_consistency": float(nc["points"].double().mean()),
        "normal_consistency_both": float(nc["both"].double().mean()),
        "normal_samples": n_samples,
        **segmentation_scores(shapes, pred, label_transfer_fraction, seed),
        "concision": _concision(shapes, pred.labels.cpu()),
    }


def _concision(shapes: ShapeSet, segmentation: torch.Tensor) -> dict | None:
    """Part name -> {"cuboids_per_instance", "instances_per_cuboid"} of :func:`~cuboidlib.metrics.part_concision`
    over all the shapes (None for a part absent from them); None without part labels or instances."""
    if shapes.labels is None or shapes.instances is None or segmentation.shape != shapes.labels.shape:
        return None
    num_parts = shapes.num_parts if shapes.num_parts is not None else int(shapes.labels.max()) + 1
    names = shapes.part_names or tuple(f"part {i}" for i in range(num_parts))
    conc = part_concision(segmentation, shapes.labels.cpu(), shapes.instances.cpu(), num_parts)
    return {names[i]: None if conc["cuboids_per_instance"][i].isnan() else
            {key: None if v[i].isnan() else float(v[i]) for key, v in conc.items()} for i in range(num_parts)}


def segmentation_scores(shapes: ShapeSet, pred: AbstractionBatch, label_transfer_fraction: float = 0.2,
                        seed: int = 0) -> dict:
    """The scores of the segmentation alone (no surface sampling: cheap enough to run during training).

    Args:
        shapes, pred, label_transfer_fraction, seed: as in :func:`score_cuboids`.

    Returns:
        A dict: ``miou`` (None without part labels); ``part_iou`` (part name -> IoU, None for a part absent
        from the scored shapes); ``label_transfer`` (the split, ``cuboid_labels`` and the ``confusion`` of
        the scored points: ``counts[t][p]`` points of part ``parts[t]`` labelled ``parts[p]``);
        ``box_distance`` (mean of :func:`~cuboidlib.metrics.segment_box_distance`, None when ``pred``
        segments other points than ``shapes``); ``reassigned`` (mean of
        :func:`~cuboidlib.metrics.reassigned_fraction`, None without an allocation W); ``n_ac``.
    """
    seg, c = pred.labels.cpu(), pred.cuboids
    box = None
    if seg.shape == shapes.points.shape[:2]:  # scored on the points that were segmented (not another density)
        box = segment_box_distance(shapes.points.cpu(), seg, c.centers, c.quaternions, c.half_sizes)
    miou, transfer, per_part = None, None, None
    if shapes.labels is not None:
        labelled, scored = label_transfer_split(len(shapes), label_transfer_fraction, seed)
        gt = shapes.labels.cpu()
        num_parts = shapes.num_parts if shapes.num_parts is not None else int(gt.max()) + 1
        cuboid_labels = transfer_part_labels(seg[labelled], gt[labelled], pred.num_segments, num_parts)
        miou = mean_iou(cuboid_labels[seg[scored]], gt[scored], num_parts)
        ious = part_ious(cuboid_labels[seg[scored]], gt[scored], num_parts)
        names = shapes.part_names or tuple(f"part {i}" for i in range(num_parts))
        per_part = {names[i]: (None if ious[i].isnan() else float(ious[i])) for i in range(num_parts)}
        confusion = part_confusion(cuboid_labels[seg[scored]], gt[scored], num_parts)
        transfer = {"fraction": label_transfer_fraction, "n_labelled": len(labelled), "n_scored": len(scored),
                    "seed": seed, "cuboid_labels": cuboid_labels.tolist(),
                    "confusion": {"parts": list(names[:num_parts]), "counts": confusion.tolist()}}
    reassigned = None if pred.W is None else float(reassigned_fraction(pred.W, c.exists).double().mean())
    return {"miou": miou, "part_iou": per_part, "label_transfer": transfer,
            "box_distance": None if box is None else float(box.double().mean()),
            "reassigned": reassigned, "n_ac": float(number_of_existing_cuboids(c.exists))}


def evaluate_model(
    model: CuboidAbstractionNet,
    shapes: ShapeSet,
    label_transfer_fraction: float = 0.2,
    conventions: Sequence[ChamferConvention] = (ChamferConvention(),),
    seed: int = 0,
    batch_size: int = 32,
    name: str = "network",
    centers_from_allocation: bool = False,
    merge_growth: float | None = None,
) -> dict:
    """Metrics of the network on ``shapes``: :func:`predict_cuboids`, then :func:`score_cuboids`.

    Args:
        model: the network, run in evaluation mode (BatchNorm running statistics, z = mu).
        shapes, label_transfer_fraction, conventions, seed: as in :func:`score_cuboids`.
        batch_size: shapes per forward pass.
        name: the result's ``method``.
        centers_from_allocation: the value the network was trained with (:func:`predict_cuboids`).
        merge_growth: None scores the network's cuboids; a number first merges the pieces of one part,
            :func:`cuboidlib.merging.merge_split_cuboids` with that ``max_growth``.

    Returns:
        The dict of :func:`score_cuboids` and ``method``, ``num_cuboids`` (M),
        ``shapes_without_existing_cuboid`` and ``merge_growth``.
    """
    pred, fallback = predict_cuboids(model, shapes, batch_size, centers_from_allocation)
    if merge_growth is not None:
        pred = merge_split_cuboids(pred, max_growth=merge_growth)
    result = {"method": name, "num_cuboids": pred.num_segments}
    result.update(score_cuboids(shapes, pred, label_transfer_fraction, conventions, seed))
    result["shapes_without_existing_cuboid"] = fallback
    result["merge_growth"] = merge_growth
    return result


def evaluate_baseline(
    shapes: ShapeSet,
    num_boxes: int | Sequence[int],
    label_transfer_fraction: float = 0.2,
    conventions: Sequence[ChamferConvention] = (ChamferConvention(),),
    seed: int = 0,
    normal_weight: float = 0.2,
) -> dict:
    """The k-means boxes of :func:`cuboidlib.baseline.fit_cluster_boxes`, scored like the network.

    A point's cluster is its segment for the label transfer; cluster indices do not correspond across shapes.

    Args:
        shapes, label_transfer_fraction, conventions: as in :func:`score_cuboids`.
        num_boxes: clusters per shape, at most ``cuboidlib._checks.MAX_CUBOIDS``: one K for every shape, or one
            per shape (e.g. the network's existing cuboids of each shape, as ``cuboidlib evaluate --baseline``).
        seed: seed of k-means, of the surface samples and of the label-transfer split.
        normal_weight: weight of the normals in the k-means features.

    Returns:
        The dict of :func:`evaluate_model`, with ``method`` "k-means boxes (K=num_boxes)" or, per shape,
        "k-means boxes (K per shape, mean ...)", ``num_cuboids`` the largest K and ``boxes_per_shape`` the Ks.
    """
    if isinstance(num_boxes, (int, np.integer)) and not isinstance(num_boxes, bool):
        if num_boxes < 1:
            raise ValueError(f"num_boxes must be a positive integer, got {num_boxes!r}")
        counts = [int(num_boxes)] * len(shapes)
    else:
        try:
            counts = list(num_boxes)
        except TypeError:
            raise ValueError(f"num_boxes must be a positive integer or one per shape, got {num_boxes!r}") from None
        if len(counts) != len(shapes):
            raise ValueError(f"num_boxes gives {len(counts)} counts for {len(shapes)} shapes; give one per shape")
    counts = [check_size(k, "num_boxes", MAX_CUBOIDS, "boxes") for k in counts]
    top = max(counts)
    pred = AbstractionBatch.concatenate([
        _padded(fit_cluster_boxes(p, nrm, k, normal_weight=normal_weight, seed=seed), top)
        for p, nrm, k in zip(shapes.points.cpu(), shapes.normals.cpu(), counts)])
    same = len(set(counts)) == 1
    method = f"k-means boxes (K={top})" if same else f"k-means boxes (K per shape, mean {np.mean(counts):.2f})"
    result = {"method": method, "num_cuboids": top}
    result.update(score_cuboids(shapes, pred, label_transfer_fraction, conventions, seed))
    result["shapes_without_existing_cuboid"] = 0
    result["boxes_per_shape"] = counts[0] if same else counts
    return result


def _padded(batch: AbstractionBatch, m: int) -> AbstractionBatch:
    """One shape's boxes with slots added up to ``m`` (not existing), so that shapes of different K stack."""
    c, extra = batch.cuboids, m - batch.num_segments
    if extra == 0:
        return batch
    identity = c.quaternions.new_tensor([1.0, 0.0, 0.0, 0.0]).repeat(1, extra, 1)
    cuboids = Cuboids(torch.cat([c.centers, c.centers.new_zeros(1, extra, 3)], 1),
                      torch.cat([c.quaternions, identity], 1),
                      torch.cat([c.half_sizes, c.half_sizes.new_full((1, extra, 3), 1e-3)], 1),
                      torch.cat([c.exists, c.exists.new_zeros(1, extra)], 1), validate=False)
    return AbstractionBatch(cuboids, batch.labels)


def format_table(results: Sequence[dict], title: str | None = None) -> str:
    """A plain-text table of :func:`evaluate_model` / :func:`evaluate_baseline` results.

    Args:
        results: the result dicts, one row each.
        title: a first line, or None.

    Returns:
        The table, then the convention of every column (Chamfer conventions numbered [1], [2], ...).
    """
    if not results:
        raise ValueError("no results to format")
    conventions: list[str] = []
    for r in results:
        for c in r["chamfer"]:
            if c["convention"] not in conventions:
                conventions.append(c["convention"])
    header = (["method", "shapes"] + [f"CD [{i + 1}]" for i in range(len(conventions))]
              + ["NC", "mIoU", "N_AC", "box dist"])
    rows = []
    for r in results:
        cd = {c["convention"]: c["value"] for c in r["chamfer"]}
        rows.append(
            [r["method"], str(r["n_shapes"])]
            + [f"{cd[c]:.5f}" if c in cd else "-" for c in conventions]
            + [f"{r['normal_consistency']:.4f}", "-" if r["miou"] is None else f"{100 * r['miou']:.1f}",
               f"{r['n_ac']:.2f}", "-" if r.get("box_distance") is None else f"{r['box_distance']:.4f}"]
        )
    widths = [max(len(row[i]) for row in [header] + rows) for i in range(len(header))]

    def fmt(row: list[str]) -> str:  # method name left-aligned, numbers right-aligned
        return "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths)))

    lines = ([title] if title else []) + [fmt(header), fmt(["-" * w for w in widths])] + [fmt(r) for r in rows]
    lines += [f"[{i + 1}] {c}" for i, c in enumerate(conventions)]
    lines.append(f"NC: normal consistency, mean |n . n'| of the input normals and the normals of the nearest of "
                 f"{results[0]['normal_samples']} points sampled on the cuboids (1 = perfect).")
    transfer = next((r["label_transfer"] for r in results if r["label_transfer"]), None)
    if transfer:
        lines.append(
            f"mIoU (%): part labels transferred from {transfer['n_labelled']} shapes "
            f"({100 * transfer['fraction']:.0f} % of the split, seed {transfer['seed']}) to the other "
            f"{transfer['n_scored']}; per-label IoU over all their points, averaged over the labels (Sec. 4.2)."
        )
        for r in results:
            if r.get("part_iou"):
                parts = ", ".join(f"{k} {'-' if v is None else f'{100 * v:.1f}'}" for k, v in r["part_iou"].items())
                lines.append(f"  IoU per part (%), {r['method']}: {parts}")
    else:
        lines.append("mIoU: not computed (the shapes have no part labels).")
    lines.append("N_AC: average number of existing cuboids (existence probability > 0.5; k-means: boxes fitted).")
    lines.append("box dist: mean distance of a point to the solid box of the cuboid it is segmented to (shape "
                 "diagonal 1; 0 = every segment inside its box), the agreement of segmentation and abstraction.")
    for r in results:
        if r.get("concision"):
            parts = ", ".join(f"{k} {v['cuboids_per_instance']:.2f} / {v['instances_per_cuboid']:.2f}"
                              if v and v["instances_per_cuboid"] is not None else f"{k} -"
                              for k, v in r["concision"].items())
            lines.append(f"  cuboids per instance / instances per cuboid, {r['method']}: {parts}")
    if any(r.get("concision") for r in results):
        lines.append("cuboids per instance: cuboids holding >= 20 % of a part instance's points (a leg, one slat), "
                     "1 = no instance cut into pieces; instances per cuboid: instances giving a cuboid >= 20 % of its "
                     "points, above 1 = instances merged.")
    for r in results:
        if r.get("reassigned") is not None:
            lines.append(f"{r['method']}: {100 * r['reassigned']:.1f} % of the points are allocated most to a cuboid "
                         "that does not exist and are segmented to another one.")
    for r in results:
        if r.get("shapes_without_existing_cuboid"):
            lines.append(f"{r['method']}: {r['shapes_without_existing_cuboid']} of {r['n_shapes']} shapes have no "
                         "cuboid with existence probability > 0.5; their most probable cuboid was scored.")
    return "\n".join(lines)

