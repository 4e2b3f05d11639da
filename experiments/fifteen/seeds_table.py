"""The runs of ``seeds.sh`` as one Markdown table, from their cards.

Each card is ``results/seeds/<category>--<name>--seed<seed>.json``. A row gives the compactness weight
lambda_1 (the second stage's; ``seeds.sh --both`` sets it in both stages), the first stage's learning rate,
any other setting in which it differs from the recipe's first stage (a first-stage lambda_1 that differs from
the second stage's among them), its steps, the seed, how far the first stage's validation mIoU still moved over its last 1000 steps, the
validation loss of the first-stage weights it kept (those the second stage starts from), and the network's test
scores. A last row per weight, learning rate and steps gives the mean over the seeds, and the mean over every pair of
seeds of the network whose first stage kept the lower validation loss: what a command would score that trained
two first stages and went on with the one of lower loss. Usage::

    python experiments/fifteen/seeds_table.py [CARD ...]
"""
import argparse
import json
from pathlib import Path
from itertools import combinations
from statistics import mean

from cuboidlib.train_config import TrainConfig
from second_stage_table import flat_config

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments" / "fifteen" / "results" / "seeds"
RECIPE = ROOT / "data_samples" / "checkpoints" / "configs" / "15min"
#: First-stage fields that the table's columns show or that seeds.sh sets in every run.
SHOWN = ("seed", "max_steps", "max_minutes", "num_threads", "lr_schedule", "lr_final", "lr", "loss.lambda_compact")
HEADER = ("| category | lambda_1 | first-stage learning rate | other first-stage change | first-stage steps | seed "
          "| first stage: validation mIoU %, last 1000 steps | first stage: kept weights' validation loss x1000 "
          "| test mIoU % | N_AC | CD x1000 | box distance | smallest part IoU % |")
RULE = "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"


def schedule(config: dict) -> str:
    """The first stage's learning rate in words: "constant 0.002" or "falls 0.002 -> 2e-05"."""
    if config["lr_schedule"] == "constant":
        return f"constant {config['lr']:g}"
    return f"falls {config['lr']:g} -> {config['lr_final']:g}"


def other_changes(config: dict, lambda_second: float) -> str:
    """The first stage's settings that differ from the recipe's beyond the table's own columns and what seeds.sh
    always sets, as "key value" ("-" for none); its lambda_1 too where it differs from the second stage's,
    ``lambda_second`` (``seeds.sh --set loss.lambda_compact=...``)."""
    recipe = flat_config(TrainConfig.load_json(RECIPE / f"{config['category']}.json").to_dict())
    ours = flat_config(TrainConfig.from_dict(config).to_dict())  # defaults filled in for cards older than a field
    changed = [f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in ours.items()
               if k not in SHOWN and v != recipe[k]]
    if ours["loss.lambda_compact"] != lambda_second:
        changed.append(f"first-stage lambda_1 {ours['loss.lambda_compact']:g}")
    return ", ".join(changed) or "-"


def scores(card: dict) -> dict:
    """The numbers of one card's row."""
    first = card["initialised_from"]
    last = first["training"]["steps"]
    late = [100 * v["miou"] for v in first["training"]["validation"] if v["step"] > last - 1000]
    kept = next(v["loss"] for v in first["training"]["validation"] if v["step"] == first["training"]["selected_step"])
    net = card["test"]["results"][0]
    worst = min(net["part_iou"], key=net["part_iou"].get)
    return {"category": first["config"]["category"], "lambda": card["config"]["loss"]["lambda_compact"],
            "lr": schedule(first["config"]),
            "other": other_changes(first["config"], card["config"]["loss"]["lambda_compact"]), "steps": last,
            "seed": first["config"]["seed"], "late": (min(late), max(late)), "kept_loss": 1000 * kept,
            "miou": 100 * net["miou"],
            "n_ac": net["n_ac"], "cd": 1000 * net["chamfer"][0]["value"], "box": net["box_distance"],
            "worst": (worst, 100 * net["part_iou"][worst])}


def row(s: dict) -> str:
    """One run's row."""
    return (f"| {s['category']} | {s['lambda']:g} | {s['lr']} | {s['other']} | {s['steps']} | {s['seed']} "
            f"| {s['late'][0]:.1f}-{s['late'][1]:.1f} | {s['kept_loss']:.2f} | {s['miou']:.1f} | {s['n_ac']:.2f} "
            f"| {s['cd']:.2f} | {s['box']:.4f} | {s['worst'][0]} {s['worst'][1]:.1f} |")


def lower_loss_of_two(runs: list[dict]) -> float:
    """The mean test mIoU, over every pair of runs, of the run whose first stage kept the lower validation loss."""
    return mean(min(pair, key=lambda r: r["kept_loss"])["miou"] for pair in combinations(runs, 2))


def mean_row(runs: list[dict]) -> str:
    """The mean over the seeds of one group of runs (:func:`_group`)."""
    choice = f" (of two by lower loss: {lower_loss_of_two(runs):.1f})" if len(runs) > 1 else ""
    first = runs[0]
    return (f"| {first['category']} | {first['lambda']:g} | {first['lr']} | {first['other']} | {first['steps']} "
            f"| mean of {len(runs)} "
            f"| {mean(r['late'][1] - r['late'][0] for r in runs):.1f} (spread) "
            f"| {mean(r['kept_loss'] for r in runs):.2f} "
            f"| **{mean(r['miou'] for r in runs):.1f}**{choice} | {mean(r['n_ac'] for r in runs):.2f} "
            f"| {mean(r['cd'] for r in runs):.2f} | {mean(r['box'] for r in runs):.4f} | |")


def _group(s: dict) -> tuple:
    """The runs averaged together: one category, compactness weight, learning rate, other change and number of
    first-stage steps (most first)."""
    return s["category"], -s["lambda"], s["lr"], s["other"], -s["steps"]


def table(cards: list[Path]) -> list[str]:
    """The table's lines: the runs of each group (:func:`_group`) by seed, then their mean."""
    runs = sorted((scores(json.loads(p.read_text())) for p in cards), key=lambda s: (*_group(s), s["seed"]))
    lines = [HEADER, RULE]
    for i, run in enumerate(runs):
        lines.append(row(run))
        if i + 1 == len(runs) or _group(runs[i + 1]) != _group(run):
            lines.append(mean_row([r for r in runs if _group(r) == _group(run)]))
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("cards", nargs="*", type=Path, help="cards (default: every card in results/seeds/)")
    print("\n".join(table(parser.parse_args().cards or sorted(RESULTS.glob("*.json")))))


if __name__ == "__main__":
    main()
