"""Where a network's co-segmentation goes wrong, and whether the loss would rather have it right.

For every trained network (default: the four committed ones), on its test split and with the label
transfer of ``cuboidlib evaluate`` (Sec. 4.2: 20 % of the shapes labelled, seed 0, each cuboid slot named
after the most frequent part of its labelled points):

1. **Where the misnamed points are.**
   - *Mixed slots*: a slot is mixed when less than 80 % of its test points belong to the part it is
     named after. The share of the misnamed points that lie in mixed slots says whether the errors
     come from a few slots that cover a junction of two parts in every shape (a chair's seat and the
     bottom of its back) or from everywhere.
   - *Distance to the part they were named*: for every misnamed point, the distance to the nearest
     point of that part in the same shape (shapes have diagonal 1). Errors within a few point spacings
     lie along the junctions of parts.
   - *By structure* (the procedural structure string): which kinds of shapes hold the errors.
   - *mIoU with pure slots*: the mIoU when every point of a mixed slot is named by its true part, the
     most that splitting the mixed slots could give.
2. **Whether the loss prefers pure slots.** For the first test shapes that have points in mixed
   slots, the per-shape fit (:func:`cuboidlib.fitting.fit_cuboids`, Eq. 4 and Eq. 6 with the network's
   lambda_1 and sigma_s) refines the network's solution twice: from its own allocation, and from the
   same allocation with every point of a mixed slot that is not of the slot's part moved to the nearest
   existing box among the slots named after its part. If the second fit ends with the lower loss, the
   joint loss prefers the pure segmentation and the mixed slots are a local minimum of training; if it
   ends higher, the loss itself asks for the junction cuboids.

It prints both and writes ``experiments/results/segmentation_errors.json`` (the command, every
network's figures and refits). No training happens here.

Example::

    python experiments/segmentation_errors.py                       # the four committed networks, about 3 minutes
    python experiments/segmentation_errors.py --networks runs/table/finetune/best.pt --shapes 4
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import torch

from cuboidlib import load_trained_model
from cuboidlib.abstraction import AbstractionBatch
from cuboidlib.dataset import load_splits
from cuboidlib.evaluation import label_transfer_split, predict_cuboids
from cuboidlib.files import write_text_atomic
from cuboidlib.fitting import FitConfig, fit_cuboids
from cuboidlib.geometry import Cuboids
from cuboidlib.metrics import mean_iou, transfer_part_labels
from cuboidlib.rotations import quaternion_to_rotation_matrix
from cuboidlib.shapes import make_collection
from cuboidlib.train_config import TrainConfig

sys.path.insert(0, str(Path(__file__).resolve().parent))
from airplane_engines import composition  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CATEGORIES = ("airplane", "chair", "table", "animal")
PURE = 0.8  # a slot whose named part holds less than this share of its points is mixed
BANDS = (0.02, 0.05, 0.1)


def box_distances(points: torch.Tensor, cuboids: Cuboids, shape: int) -> torch.Tensor:
    """(N, 3) points and shape ``shape`` of a (B, M) cuboid batch -> (N, M) distances to the solid boxes."""
    c, q, h = cuboids.centers[shape], cuboids.quaternions[shape], cuboids.half_sizes[shape]
    R = quaternion_to_rotation_matrix(q)  # (M, 3, 3), columns are the box axes
    local = torch.einsum("nmj,mji->nmi", points[:, None] - c[None], R)
    return (local.abs() - h[None]).clamp_min(0).norm(dim=-1)


def purified_start(one: AbstractionBatch, points: torch.Tensor, parts: torch.Tensor, named: torch.Tensor,
                   mixed: set[int]) -> tuple[AbstractionBatch, int]:
    """One shape's network solution with the foreign points of its mixed slots moved to their own part's slots.

    A point of a mixed slot whose part differs from the slot's name goes to the existing slot, among those
    named after its part and not mixed, whose box is nearest. Returns the start and the number of points
    moved (0 when no such slot exists).
    """
    c = one.cuboids
    labels = one.labels[0].clone()
    exists = c.exists[0]
    dist = box_distances(points, c, 0)
    moved = 0
    for m in mixed:
        foreign = (labels == m) & (parts != named[m])
        for i in torch.nonzero(foreign).flatten().tolist():
            own = [s for s in range(c.num_cuboids) if exists[s] and s not in mixed and named[s] == parts[i]]
            if own:
                labels[i] = min(own, key=lambda s: float(dist[i, s]))
                moved += 1
    still = torch.zeros_like(exists)
    still[labels.unique()] = True  # a slot left without points does not exist in the start
    cuboids = Cuboids(c.centers, c.quaternions, c.half_sizes, still[None])
    return AbstractionBatch(cuboids, labels[None]), moved


def analyse(name: str, n_refits: int, steps: int) -> dict:
    model, state, path = load_trained_model(name)
    config = TrainConfig.from_dict(state["config"])
    loss = config.loss_config
    test = load_splits(config)["test"]
    names = list(test.part_names)
    num_parts = len(names)
    pred, _ = predict_cuboids(model, test, centers_from_allocation=loss.centers_from_allocation)
    slots = pred.num_segments
    labelled, scored = label_transfer_split(len(test))
    seg, gt = pred.labels, test.labels
    named = transfer_part_labels(seg[labelled], gt[labelled], slots, num_parts)
    predicted = named[seg[scored]]
    miou = mean_iou(predicted, gt[scored], num_parts)

    counts = composition(seg[scored], gt[scored], slots, num_parts)
    share = counts[np.arange(slots), named.numpy()] / np.maximum(counts.sum(1), 1)
    mixed = {m for m in range(slots) if counts[m].sum() and share[m] < PURE}
    wrong = predicted != gt[scored]
    in_mixed = torch.isin(seg[scored], torch.tensor(sorted(mixed), dtype=torch.long))
    pure = torch.where(in_mixed, gt[scored], predicted)  # mixed slots named point by point by the truth

    distance, absent = [], 0  # of every misnamed point to the nearest point of the part it was named
    structures = make_collection(config.category, config.n_shapes, config.n_points, seed=config.data_seed,
                                 version=config.generator_version).structures
    by_structure, shapes_of = Counter(), Counter()
    for row, j in enumerate(scored.tolist()):
        p, g, q = test.points[j], gt[j], predicted[row]
        s = str(structures[int(test.indices[j])])
        shapes_of[s] += 1
        by_structure[s] += int(wrong[row].sum())
        for part in q[wrong[row]].unique().tolist():
            err = wrong[row] & (q == part)
            if (g == part).any():  # else: named a part this shape lacks (an airplane's engine on one without)
                distance.append(torch.cdist(p[err], p[g == part]).min(dim=1).values)
            else:
                absent += int(err.sum())
    distance = torch.cat(distance) if distance else torch.zeros(0)
    spacing = float(torch.stack([torch.cdist(test.points[j], test.points[j]).fill_diagonal_(float("inf"))
                                 .min(dim=1).values.median() for j in scored[:20].tolist()]).median())

    fit = FitConfig(steps=steps, normalize=False, loss={k: getattr(loss, k) for k in ("lambda_compact", "compactness_average",
                    "sigma_s", "eps_sps", "distance")})
    refits = []
    for j in range(len(test)):
        if len(refits) == n_refits or not mixed:
            break
        c = pred.cuboids
        one = AbstractionBatch(Cuboids(c.centers[j:j + 1], c.quaternions[j:j + 1], c.half_sizes[j:j + 1],
                                       c.exists[j:j + 1]), seg[j:j + 1])
        start, moved = purified_start(one, test.points[j], gt[j], named, mixed)
        if moved < 10:
            continue
        own = fit_cuboids(test.points[j], test.normals[j], fit, start=one)
        apart = fit_cuboids(test.points[j], test.normals[j], fit, start=start)
        refits.append({"shape": int(test.indices[j]), "moved": moved,
                       "loss_network_start": float(own.final_loss[0]), "loss_pure_start": float(apart.final_loss[0])})

    total = int(wrong.sum())
    ratios = [r["loss_pure_start"] / r["loss_network_start"] for r in refits]
    return {
        "checkpoint": str(path), "category": config.category, "test_shapes": len(test), "scored_shapes": len(scored),
        "miou": miou, "misnamed_points": total, "scored_points": int(wrong.numel()),
        "mixed_slots": [{"slot": m, "named": names[int(named[m])], "share_of_named_part": round(float(share[m]), 3),
                         **{n: int(counts[m, k]) for k, n in enumerate(names)}} for m in sorted(mixed)],
        "misnamed_in_mixed_slots": int((wrong & in_mixed).sum()),
        "miou_with_pure_slots": mean_iou(pure, gt[scored], num_parts),
        "point_spacing": round(spacing, 4),
        "misnamed_as_absent_part": absent,
        "misnamed_within": {str(b): float((distance <= b).double().sum() / max(total, 1)) for b in BANDS},
        "by_structure": [{"structure": s, "shapes": shapes_of[s], "misnamed": n}
                         for s, n in by_structure.most_common(5)],
        "fit": dataclasses.asdict(fit), "refits": refits,
        "pure_lower_on": sum(x < 1 for x in ratios), "median_loss_ratio": float(np.median(ratios)) if ratios else None,
    }


def report(r: dict) -> None:
    pct = lambda a, b: 100 * a / max(b, 1)  # noqa: E731
    print(f"{r['checkpoint']}: {r['category']}, {r['scored_shapes']} scored test shapes, mIoU {100 * r['miou']:.1f} %")
    print(f"  misnamed points: {r['misnamed_points']} ({pct(r['misnamed_points'], r['scored_points']):.1f} %), "
          f"{pct(r['misnamed_in_mixed_slots'], r['misnamed_points']):.0f} % of them in "
          f"{len(r['mixed_slots'])} mixed slots (named part < {PURE:.0%} of their points)")
    for s in r["mixed_slots"]:
        print(f"    slot {s['slot']:2d} named {s['named']:7s} {s['share_of_named_part']:.0%} of its points: "
              + ", ".join(f"{k} {v}" for k, v in s.items() if k not in ("slot", "named", "share_of_named_part") and v))
    print(f"  mIoU if the mixed slots were named point by point: {100 * r['miou_with_pure_slots']:.1f} %")
    print(f"  misnamed points within d of the part they were named (point spacing {r['point_spacing']}): "
          + ", ".join(f"{d}: {v:.0%}" for d, v in r["misnamed_within"].items())
          + f"; named a part the shape lacks: {r['misnamed_as_absent_part']}")
    print("  most misnamed points per structure: " + "; ".join(
        f"{s['structure']} {s['misnamed'] / s['shapes']:.0f} per shape ({s['shapes']} shapes)" for s in r["by_structure"]))
    if r["refits"]:
        print(f"  refits: the pure start ends with the lower loss on {r['pure_lower_on']} of {len(r['refits'])} shapes "
              f"(median ratio {r['median_loss_ratio']:.2f})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--networks", nargs="+", default=list(CATEGORIES),
                        help="trained networks: committed names or checkpoint paths (default: the four committed ones)")
    parser.add_argument("--shapes", type=int, default=8, help="test shapes refitted per network (default 8; 0: none)")
    parser.add_argument("--steps", type=int, default=300, help="Adam steps of each refit (default 300)")
    parser.add_argument("--out", type=Path, default=ROOT / "experiments" / "results")
    args = parser.parse_args(argv)
    if args.shapes < 0 or args.steps < 1:
        parser.error("--shapes must be at least 0 and --steps at least 1")
    torch.set_num_threads(1)
    start = time.time()
    results = []
    for name in args.networks:
        results.append(analyse(name, args.shapes, args.steps))
        report(results[-1])
    record = {"command": "python experiments/segmentation_errors.py" + "".join(f" {a}" for a in (argv or sys.argv[1:])),
              "mixed_below": PURE, "networks": results, "wall_seconds": round(time.time() - start, 1),
              "torch": torch.__version__}
    write_text_atomic(args.out / "segmentation_errors.json", json.dumps(record, indent=1) + "\n")
    print(f"wrote {args.out / 'segmentation_errors.json'} ({time.time() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
