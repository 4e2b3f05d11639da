"""What merging the pieces of one part does to the committed networks: concision, mIoU, N_AC, Chamfer distance.

``cuboidlib.merging.merge_split_cuboids`` merges two cuboids when the box around both is at most
``max_growth`` larger than the two, every extent padded by ``pad`` times the shape's diagonal. This
script scores every network of ``--checkpoints`` on its whole test split (200 shapes; ``--split val``: the validation split, where settings are chosen), once as the
network gives its cuboids and once per (pad, max_growth) pair, with the course's evaluation
(``cuboidlib.evaluation.score_cuboids``). For each row it prints the test mIoU, N_AC, the Chamfer distance,
the box distance and the cuboids per instance / instances per cuboid of every part
(``cuboidlib.metrics.part_concision``). No training happens here.

It writes ``experiments/results/merge_pieces_<split>.json`` and ``.csv`` (the command and every row).

Example::

    python experiments/merge_pieces.py --split val                      # choose the settings: about 5 minutes
    python experiments/merge_pieces.py                                  # then score them on the test split
    python experiments/merge_pieces.py --pads 0.05 --growths 0.25       # one setting
    python experiments/merge_pieces.py --checkpoints experiments/fifteen/results --suffix _15min --out runs/m
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from cuboidlib.applications import load_trained_model
from cuboidlib.dataset import load_splits
from cuboidlib.evaluation import predict_cuboids, score_cuboids
from cuboidlib.files import write_text_atomic
from cuboidlib.merging import merge_split_cuboids
from cuboidlib.train_config import TrainConfig

ROOT = Path(__file__).resolve().parents[1]
CATEGORIES = ("chair", "table", "airplane", "animal")


def _row(category: str, pad, growth, scores: dict, seconds: float) -> dict:
    concision = {part: v for part, v in scores["concision"].items() if v is not None}
    return {"category": category, "pad": pad, "max_growth": growth, "miou": scores["miou"], "n_ac": scores["n_ac"],
            "chamfer": scores["chamfer"][0]["value"], "box_distance": scores["box_distance"],
            "merge_seconds": round(seconds, 2),
            **{f"{part} cuboids per instance": v["cuboids_per_instance"] for part, v in concision.items()},
            **{f"{part} instances per cuboid": v["instances_per_cuboid"] for part, v in concision.items()}}


def measure(checkpoints: Path, suffix: str, pads: list[float], growths: list[float],
            categories=CATEGORIES, split: str = "test") -> list[dict]:
    """Every category's rows: the network's cuboids first, then each (pad, max_growth) merge."""
    rows = []
    for category in categories:
        model, state, _ = load_trained_model(str(checkpoints / f"{category}{suffix}.pt"))
        config = TrainConfig.from_dict(state["config"])
        test = load_splits(config)[split]
        pred, _ = predict_cuboids(model, test, centers_from_allocation=config.loss_config.centers_from_allocation)
        rows.append(_row(category, None, None, score_cuboids(test, pred), 0.0))
        _print(rows[-1])
        for pad in pads:
            for growth in growths:
                start = time.perf_counter()
                merged = merge_split_cuboids(pred, max_growth=growth, pad=pad)
                rows.append(_row(category, pad, growth, score_cuboids(test, merged), time.perf_counter() - start))
                _print(rows[-1])
    return rows


def _print(r: dict) -> None:
    setting = "network" if r["pad"] is None else f"pad {r['pad']:g}, growth {r['max_growth']:g}"
    parts = [k[:-len(" cuboids per instance")] for k in r if k.endswith(" cuboids per instance")]
    parts = ", ".join(f"{p} {r[p + ' cuboids per instance']:.2f} / {r[p + ' instances per cuboid']:.2f}" for p in parts)
    print(f"{r['category']:<9} {setting:<22} mIoU {100 * r['miou']:5.1f}  N_AC {r['n_ac']:5.2f}  "
          f"CD x1000 {1000 * r['chamfer']:.3f}  box {r['box_distance']:.4f}  | {parts}", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoints", type=Path, default=ROOT / "data_samples" / "checkpoints",
                        help="the folder of the networks <category><suffix>.pt (default: the committed ones)")
    parser.add_argument("--suffix", default="", help="the networks' file names after the category (e.g. _15min)")
    parser.add_argument("--pads", default="0.03,0.05", help="comma-separated pads (default 0.03,0.05)")
    parser.add_argument("--growths", default="0.25,0.4,0.5",
                        help="comma-separated max_growth values (default 0.25,0.4,0.5)")
    parser.add_argument("--split", choices=("val", "test"), default="test",
                        help="the split scored (default test; choose the settings on val)")
    parser.add_argument("--categories", default=",".join(CATEGORIES), help="comma-separated (default: all four)")
    parser.add_argument("--out", type=Path, default=ROOT / "experiments" / "results")
    args = parser.parse_args(argv)
    try:
        pads, growths = ([float(v) for v in text.split(",")] for text in (args.pads, args.growths))
    except ValueError:
        parser.error("--pads and --growths take comma-separated numbers")
    torch.set_num_threads(1)
    start = time.time()
    print(f"cuboids per instance / instances per cuboid for every part; {args.split} split of each network")
    categories = args.categories.split(",")
    if not set(categories) <= set(CATEGORIES):
        parser.error(f"--categories: choose among {', '.join(CATEGORIES)}")
    rows = measure(args.checkpoints, args.suffix, pads, growths, categories, args.split)
    record = {"command": "python experiments/merge_pieces.py" + "".join(f" {a}" for a in (argv or sys.argv[1:])),
              "split": args.split,
              "wall_seconds": round(time.time() - start, 1), "torch": torch.__version__, "rows": rows}
    stem = args.out / f"merge_pieces_{args.split}"
    write_text_atomic(stem.with_suffix(".json"), json.dumps(record, indent=1) + "\n")
    fields = list(dict.fromkeys(k for r in rows for k in r))
    lines = [",".join(fields)] + [",".join("" if r.get(k) is None else str(r[k]) for k in fields) for r in rows]
    write_text_atomic(stem.with_suffix(".csv"), "\n".join(lines) + "\n")
    print(f"wrote {stem}.json and .csv ({time.time() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
