"""Where the engine points of test airplanes go, and whether the loss would rather give them cuboids of their own.

Two measurements on the test split of a trained airplane network (default: the committed one):

1. **Where the engine points go.** For every cuboid slot, how many test points it is given and which
   parts they belong to. The label transfer names a slot after its most frequent part, so a slot that
   holds an engine together with more wing points is called "wing" (with lambda_1 = 0.005 no slot was
   ever "engine"; the committed network, lambda_1 = 0.001, has engine slots but still mixed wing slots).
2. **Whether the loss would rather split them off.** For the first test airplanes with engines, the
   per-shape fit (:func:`cuboidlib.fitting.fit_cuboids`, the losses of Eq. 4 and Eq. 6 with the
   network's weights lambda_1 and sigma_s) refines the network's solution twice: once from the network's
   own allocation, once from the same allocation with the engine points of every mixed slot moved to an
   unused slot (its cuboid started as their bounding box). If the second fit ends with the lower loss,
   the joint loss prefers engines of their own, and the network's allocation is a local minimum of
   training rather than what the loss asks for.

It prints both and writes ``experiments/results/airplane_engines.json`` (the command, the composition of
every slot, every refit's final losses). No training happens here.

Example::

    python experiments/airplane_engines.py                 # 8 shapes refitted, about 1 minute
    python experiments/airplane_engines.py --checkpoint runs/airplane/finetune/best.pt --shapes 16
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from cuboidlib import load_trained_model
from cuboidlib.abstraction import AbstractionBatch
from cuboidlib.dataset import load_splits
from cuboidlib.evaluation import predict_cuboids
from cuboidlib.files import write_text_atomic
from cuboidlib.fitting import FitConfig, fit_cuboids
from cuboidlib.geometry import Cuboids
from cuboidlib.metrics import transfer_part_labels
from cuboidlib.train_config import TrainConfig

ROOT = Path(__file__).resolve().parents[1]
ENGINE = "engine"


def composition(labels: torch.Tensor, parts: torch.Tensor, num_slots: int, num_parts: int) -> np.ndarray:
    """(S, N) segment labels and (S, N) part labels -> (num_slots, num_parts) point counts."""
    flat = labels.reshape(-1) * num_parts + parts.reshape(-1)
    return np.bincount(flat.numpy(), minlength=num_slots * num_parts).reshape(num_slots, num_parts)


def split_start(one: AbstractionBatch, points: torch.Tensor, parts: torch.Tensor, engine: int,
                min_points: int = 10) -> tuple[AbstractionBatch, int]:
    """The network's solution of one shape with the engine points of every mixed slot moved to a free slot.

    A slot is mixed when it holds at least ``min_points`` engine points and other points too. The free slot's
    cuboid starts as the axis-aligned bounding box of the moved points. Returns the start and the number of
    points moved.
    """
    c = one.cuboids
    centers, quats, halves, exists = c.centers.clone(), c.quaternions.clone(), c.half_sizes.clone(), c.exists.clone()
    labels = one.labels.clone()
    free = [m for m in range(c.num_cuboids) if not exists[0, m]]
    moved = 0
    for m in range(c.num_cuboids):
        mine = one.labels[0] == m
        engine_points = mine & (parts == engine)
        if not free or int(engine_points.sum()) < min_points or bool(engine_points.sum() == mine.sum()):
            continue
        s = free.pop(0)
        labels[0, engine_points] = s
        p = points[engine_points]
        centers[0, s] = (p.amax(0) + p.amin(0)) / 2
        halves[0, s] = ((p.amax(0) - p.amin(0)) / 2).clamp_min(1e-3)
        quats[0, s] = torch.tensor([1.0, 0.0, 0.0, 0.0])
        exists[0, s] = True
        moved += int(engine_points.sum())
    return AbstractionBatch(Cuboids(centers, quats, halves, exists), labels), moved


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", default="airplane", help="a trained airplane network (default: the committed one)")
    parser.add_argument("--shapes", type=int, default=8, help="test airplanes with engines to refit (default 8)")
    parser.add_argument("--steps", type=int, default=300, help="Adam steps of each refit (default 300)")
    parser.add_argument("--out", type=Path, default=ROOT / "experiments" / "results")
    args = parser.parse_args(argv)
    if args.shapes < 1 or args.steps < 1:
        parser.error("--shapes and --steps must be at least 1")
    torch.set_num_threads(1)
    start = time.time()
    model, state, path = load_trained_model(args.checkpoint)
    config = TrainConfig.from_dict(state["config"])
    if config.category != "airplane":
        parser.error(f"{path} is a {config.category} network; this check needs an airplane network")
    loss = config.loss_config
    test = load_splits(config)["test"]
    names = list(test.part_names)
    engine = names.index(ENGINE)
    pred, _ = predict_cuboids(model, test, centers_from_allocation=loss.centers_from_allocation)
    slots, num_parts = pred.num_segments, len(names)

    # 1. which parts every slot holds, and what the label transfer calls it (all 200 test shapes label here)
    counts = composition(pred.labels, test.labels, slots, num_parts)
    named = transfer_part_labels(pred.labels, test.labels, slots, num_parts).tolist()
    rows = [{"slot": m, "points": int(counts[m].sum()), "named": names[named[m]],
             **{n: int(counts[m, j]) for j, n in enumerate(names)}} for m in range(slots) if counts[m].sum()]
    total_engine = int(counts[:, engine].sum())
    print(f"{path}: test split, {len(test)} airplanes, {total_engine} engine points")
    print(f"{'slot':>4} {'points':>7} " + " ".join(f"{n:>7}" for n in names) + "  named")
    for r in rows:
        print(f"{r['slot']:>4} {r['points']:>7} " + " ".join(f"{100 * r[n] / r['points']:>6.0f}%" for n in names)
              + f"  {r['named']}")
    in_named_engine = sum(r[ENGINE] for r in rows if r["named"] == ENGINE)
    print(f"engine points in slots named 'engine': {in_named_engine} of {total_engine}")

    # 2. refit from the network's allocation and from the split one
    fit = FitConfig(steps=args.steps, normalize=False, loss={k: getattr(loss, k) for k in ("lambda_compact", "compactness_average",
                    "sigma_s", "eps_sps", "distance")})
    with_engines = [i for i in range(len(test)) if int((test.labels[i] == engine).sum()) >= 50][:args.shapes]
    refits = []
    for i in with_engines:
        c = pred.cuboids
        one = AbstractionBatch(Cuboids(c.centers[i:i + 1], c.quaternions[i:i + 1], c.half_sizes[i:i + 1],
                                       c.exists[i:i + 1]), pred.labels[i:i + 1])
        split, moved = split_start(one, test.points[i], test.labels[i], engine)
        if not moved:
            continue
        own = fit_cuboids(test.points[i], test.normals[i], fit, start=one)
        apart = fit_cuboids(test.points[i], test.normals[i], fit, start=split)
        refits.append({"shape": int(test.indices[i]), "engine_points": int((test.labels[i] == engine).sum()),
                       "moved": moved, "loss_network_start": float(own.final_loss[0]),
                       "loss_split_start": float(apart.final_loss[0]),
                       "cuboids_network_start": int(own.cuboids.exists.sum()),
                       "cuboids_split_start": int(apart.cuboids.exists.sum())})
        r = refits[-1]
        print(f"shape {r['shape']}: {r['moved']} engine points moved; final loss {r['loss_network_start']:.5f} from the "
              f"network's allocation ({r['cuboids_network_start']} cuboids), {r['loss_split_start']:.5f} with the "
              f"engines apart ({r['cuboids_split_start']} cuboids)")
    ratios = [r["loss_split_start"] / r["loss_network_start"] for r in refits]
    lower = sum(x < 1 for x in ratios)
    if ratios:
        print(f"engines apart end with the lower loss on {lower} of {len(ratios)} shapes "
              f"(median ratio {np.median(ratios):.2f})")
    record = {"command": "python experiments/airplane_engines.py" + "".join(f" {a}" for a in (argv or sys.argv[1:])),
              "checkpoint": str(path), "test_shapes": len(test), "engine_points": total_engine,
              "engine_points_in_slots_named_engine": in_named_engine, "slots": rows,
              "fit": dataclasses.asdict(fit), "refits": refits,
              "split_lower_on": lower, "median_loss_ratio": float(np.median(ratios)) if ratios else None,
              "wall_seconds": round(time.time() - start, 1), "torch": torch.__version__}
    write_text_atomic(args.out / "airplane_engines.json", json.dumps(record, indent=1) + "\n")
    print(f"wrote {args.out / 'airplane_engines.json'} ({time.time() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
