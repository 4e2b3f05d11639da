"""How well the orientation warning of ``cuboidlib.abstract`` separates upright shapes from turned ones.

``abstract(shape, model)`` without ``up`` runs the network with each of the six axes taken as up
(``cuboidlib.abstraction.up_axis_scores``) and warns when another axis gives a Chamfer distance below
``ORIENTATION_RATIO`` times the +y-up one. This script measures, for every committed network, on the
first test shapes of its category (the network's own 1024 points):

- upright shapes: how often the warning fires (a false alarm);
- the same shapes turned so that another axis is up (+z with the front along -y, the convention of
  Blender and many CAD exports; and +x): how often it fires and names the right axis.

It prints one row per category and input frame and writes ``experiments/results/orientation_check.json``
and ``.csv`` (the command, the ratio, every shape's six scores). No training happens here.

Example::

    python experiments/orientation_check.py                 # 24 test shapes per category, about 4 minutes
    python experiments/orientation_check.py --shapes 4      # a quick look
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from cuboidlib.abstraction import ORIENTATION_RATIO, frame_rotation, up_axis_scores
from cuboidlib.dataset import load_splits
from cuboidlib.files import write_text_atomic
from cuboidlib.release import read_card
from cuboidlib.train_config import TrainConfig

ROOT = Path(__file__).resolve().parents[1]
CATEGORIES = ("chair", "table", "airplane", "animal")
FRAMES = ("y", "z", "x")  # the input's up axis; each with its default front (frame_rotation)


def turned(points: np.ndarray, up: str) -> np.ndarray:
    """(N, 3) points in the course's frame (+y up) -> the same shape as a file with ``up`` as its up axis."""
    return points @ frame_rotation(up)  # p_course = R p_input, so p_input = R^T p_course (rows: p @ R)


def measure(checkpoints: Path, shapes: int) -> list[dict]:
    rows = []
    for category in CATEGORIES:
        checkpoint = checkpoints / f"{category}.pt"
        config = TrainConfig.from_dict(read_card(checkpoint)["config"])
        test = load_splits(config)["test"]
        for i in range(min(shapes, len(test))):
            points, normals = test.points[i].numpy(), test.normals[i].numpy()
            for up in FRAMES:
                cloud = np.concatenate([turned(points, up), turned(normals, up)], axis=1)
                scores = up_axis_scores(cloud, str(checkpoint))
                best = min(scores, key=scores.get)
                warned = best != "y" and scores[best] < ORIENTATION_RATIO * scores["y"]
                rows.append({"category": category, "shape": int(test.indices[i]), "input_up": up,
                             "warned": bool(warned), "suggested": best if warned else None,
                             "ratio_best_to_y": scores[best] / scores["y"],
                             **{f"chamfer_up_{u}": round(c, 7) for u, c in scores.items()}})
    return rows


def summarise(rows: list[dict]) -> list[dict]:
    out = []
    for category in CATEGORIES:
        for up in FRAMES:
            sel = [r for r in rows if r["category"] == category and r["input_up"] == up]
            if not sel:
                continue
            right = sum(r["suggested"] == up for r in sel) if up != "y" else None
            out.append({"category": category, "input_up": up, "shapes": len(sel),
                        "warned": sum(r["warned"] for r in sel), "named_the_right_axis": right,
                        "median_ratio_best_to_y": float(np.median([r["ratio_best_to_y"] for r in sel]))})
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoints", type=Path, default=ROOT / "data_samples" / "checkpoints")
    parser.add_argument("--shapes", type=int, default=24, help="test shapes per category (default 24)")
    parser.add_argument("--out", type=Path, default=ROOT / "experiments" / "results")
    args = parser.parse_args(argv)
    if args.shapes < 1:
        parser.error("--shapes must be at least 1")
    torch.set_num_threads(1)
    start = time.time()
    rows = measure(args.checkpoints, args.shapes)
    summary = summarise(rows)
    print(f"warning when another up axis gives a Chamfer distance below {ORIENTATION_RATIO} x the +y-up one")
    print(f"{'category':<10}{'input up':>9}{'shapes':>8}{'warned':>8}{'right axis':>12}{'median best/y':>15}")
    for s in summary:
        right = "-" if s["named_the_right_axis"] is None else s["named_the_right_axis"]
        print(f"{s['category']:<10}{s['input_up']:>9}{s['shapes']:>8}{s['warned']:>8}{right:>12}"
              f"{s['median_ratio_best_to_y']:>15.2f}")
    record = {"command": "python experiments/orientation_check.py" + "".join(f" {a}" for a in (argv or sys.argv[1:])),
              "ratio": ORIENTATION_RATIO, "shapes_per_category": args.shapes, "frames": FRAMES,
              "wall_seconds": round(time.time() - start, 1), "torch": torch.__version__, "summary": summary,
              "shapes": rows}
    write_text_atomic(args.out / "orientation_check.json", json.dumps(record, indent=1) + "\n")
    fields = list(rows[0])
    lines = [",".join(fields)] + [",".join("" if r[k] is None else str(r[k]) for k in fields) for r in rows]
    write_text_atomic(args.out / "orientation_check.csv", "\n".join(lines) + "\n")
    print(f"wrote {args.out / 'orientation_check.json'} and .csv ({time.time() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
