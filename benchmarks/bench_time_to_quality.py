"""What a time budget buys: the 15-minute recipe for one category, its validation scores against wall time.

It runs the one command of the recipe (``data_samples/checkpoints/configs/15min/``) in a fresh process, from an
empty shape cache so that making the data counts, and times it from start to the written card:

    python -m cuboidlib train --config configs/15min/<category>.json --finetune configs/15min/finetune/<category>.json
        --out OUT --release OUT/released.pt

Then it prints, against the wall time since the command started, every validation of both stages (mIoU by
label transfer within the validation split, N_AC, box distance) and the Chamfer distance on the validation
split of each stage's selected weights, and last the released network's test scores against the course's
targets. The recipe is sized to end within 15 minutes on a 2-core machine (a 9-minute first stage, a 500-step
second stage, 1000 steps for animals; its commands took 11-14 minutes on a quiet one). ``--budget B`` gives the first stage ``B - 15``
minutes more (or less). Time it on a quiet machine: the command takes every core that other processes leave
free.

Example::

    python benchmarks/bench_time_to_quality.py --category chair
    python benchmarks/bench_time_to_quality.py --category table --budget 10 --out runs/ttq_table_10
    python benchmarks/bench_time_to_quality.py --category chair --set seed=1 --out runs/ttq_chair_seed1
    python benchmarks/bench_time_to_quality.py --category chair --report-only --out runs/chair_15min
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECIPE = ROOT / "data_samples" / "checkpoints" / "configs" / "15min"
#: The minutes the recipe is sized for, on a 2-core machine, from the command's start to its card.
RECIPE_MINUTES = 15.0
#: The course's targets (experiments/fifteen/README.md): test mIoU %, N_AC, and for every category the same three more.
TARGETS = {"chair": (85, 8), "table": (95, 6), "airplane": (70, 9), "animal": (80, 7)}
KMEANS_FACTOR, BOX_DISTANCE = 3.0, 0.01


def _first_stage_minutes(category: str, budget: float) -> float:
    first = json.loads((RECIPE / f"{category}.json").read_text())["max_minutes"]
    minutes = first + budget - RECIPE_MINUTES
    if minutes <= 0:
        raise SystemExit(f"--budget {budget}: leaves the first stage no time (it has {first} of the recipe's "
                         f"{RECIPE_MINUTES:g} minutes; the rest is data, the second stage and scoring)")
    return minutes


def train(category: str, out: Path, budget: float, changes: list[str]) -> float:
    """Run the recipe's one command; the wall seconds from its start to its card."""
    if out.exists():
        raise SystemExit(f"{out} exists: give another --out, or --report-only to report on it")
    command = [sys.executable, "-m", "cuboidlib", "train", "--config", str(RECIPE / f"{category}.json"),
               "--finetune", str(RECIPE / "finetune" / f"{category}.json"), "--out", str(out),
               "--release", str(out / "released.pt"), "--quiet",
               "--set", f"max_minutes={_first_stage_minutes(category, budget)}"]
    for change in changes:
        command += ["--set", change]
    with tempfile.TemporaryDirectory() as cache:
        start = time.time()
        subprocess.run(command, check=True, cwd=ROOT, env={**os.environ, "CUBOIDLIB_CACHE": cache})
        seconds = time.time() - start
    (out / "wall_seconds.json").write_text(json.dumps({"start": start, "seconds": seconds}) + "\n")
    return seconds


def _validations(stage: Path, offset: float) -> list[dict]:
    with open(stage / "log.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["split"] == "val"]
    return [{"wall_minutes": (offset + float(r["seconds"])) / 60, "step": int(r["step"]), "miou": float(r["miou"]),
             "n_ac": float(r["n_ac"]), "box_distance": float(r["box_distance"])} for r in rows]


def _validation_chamfer(checkpoint: Path) -> float:
    from cuboidlib.applications import load_trained_model
    from cuboidlib.dataset import load_splits
    from cuboidlib.evaluation import evaluate_model
    from cuboidlib.train_config import TrainConfig

    model, state, _ = load_trained_model(str(checkpoint), "cpu")
    config = TrainConfig.from_dict(state["config"])
    result = evaluate_model(model, load_splits(config)["val"],
                            centers_from_allocation=config.loss_config.centers_from_allocation)
    return result["chamfer"][0]["value"]


def report(category: str, out: Path, card_file: Path | None = None) -> dict:
    """The validation curve of both stages against wall time, and the card's test scores against the targets."""
    timing = json.loads((out / "wall_seconds.json").read_text()) if (out / "wall_seconds.json").is_file() else None
    start = timing["start"] if timing else (out / "config.json").stat().st_mtime
    stages = [("first", out), ("second", out / "finetune")]
    rows = []
    for name, folder in stages:  # a stage starts when it writes its config.json
        for r in _validations(folder, (folder / "config.json").stat().st_mtime - start):
            rows.append({"stage": name, **r})
        rows[-1]["chamfer"] = _validation_chamfer(folder / "best.pt")
    print(f"{category}: validation split, against the wall time since the command started")
    print(f"{'minutes':>8} {'stage':>6} {'step':>5} {'mIoU %':>7} {'N_AC':>6} {'box dist':>9} {'CD x1000':>9}")
    for r in rows:
        cd = f"{1000 * r['chamfer']:.3f}" if "chamfer" in r else "-"
        print(f"{r['wall_minutes']:8.1f} {r['stage']:>6} {r['step']:5d} {100 * r['miou']:7.1f} {r['n_ac']:6.2f} "
              f"{r['box_distance']:9.4f} {cd:>9}")
    card = json.loads((card_file or out / "released.json").read_text())
    if timing is None and "command_seconds" in card:  # the card of the one command records its wall time
        timing = {"seconds": card["command_seconds"]}
    net, kmeans = card["test"]["results"][0], card["test"]["results"][1]
    cd, cd_k = net["chamfer"][0]["value"], kmeans["chamfer"][0]["value"]
    miou_target, nac_target = TARGETS[category]
    smallest = min(v for v in net["part_iou"].values() if v is not None)
    checks = [("test mIoU %", 100 * net["miou"], f">= {miou_target}", 100 * net["miou"] >= miou_target),
              ("N_AC", net["n_ac"], f">= {nac_target}", net["n_ac"] >= nac_target),
              ("smallest part IoU %", 100 * smallest, "> 0 (every part wins a cuboid)", smallest > 0),
              ("k-means CD / network CD", cd_k / cd, f">= {KMEANS_FACTOR:g}", cd_k / cd >= KMEANS_FACTOR),
              ("box distance", net["box_distance"], f"<= {BOX_DISTANCE}", net["box_distance"] <= BOX_DISTANCE)]
    total = timing["seconds"] / 60 if timing else None
    print(f"\nthe released network on the test split ({net['n_shapes']} shapes); the whole command: "
          + (f"{total:.1f} min" if total else "not timed here (--report-only on a run this script did not start)"))
    for name, value, target, ok in checks:
        print(f"  {name:<24} {value:8.3f}   target {target:<32} {'met' if ok else 'MISSED'}")
    if net.get("concision"):
        print("  cuboids per instance / instances per cuboid: "
              + ", ".join(f"{k} {v['cuboids_per_instance']:.2f} / {v['instances_per_cuboid']:.2f}"
                          for k, v in net["concision"].items() if v))
    summary = {"category": category, "run": str(out), "wall_minutes": total, "validation": rows,
               "test": {name: value for name, value, _, _ in checks}, "targets_met": all(c[3] for c in checks)}
    return summary


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--category", required=True, choices=sorted(TARGETS))
    parser.add_argument("--budget", type=float, default=RECIPE_MINUTES,
                        help="minutes for the whole command; the first stage gets the difference to 15 (default 15)")
    parser.add_argument("--out", type=Path, help="the run folder (default runs/ttq_<category>)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="changes",
                        help="change a field of the first stage, as `cuboidlib train --set` (e.g. seed=1)")
    parser.add_argument("--report-only", action="store_true",
                        help="do not train: report on the run already in --out (e.g. runs/chair_15min)")
    parser.add_argument("--card", type=Path, help="with --report-only: the released network's card, when it is not "
                        "OUT/released.json (e.g. data_samples/checkpoints/chair_15min.json)")
    parser.add_argument("--json", type=Path, help="also write the report here")
    args = parser.parse_args(argv)
    out = (args.out or Path("runs") / f"ttq_{args.category}").resolve()
    if not args.report_only:
        train(args.category, out, args.budget, args.changes)
    summary = report(args.category, out, args.card)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
