"""The second-stage runs of ``second_stage.sh`` as one Markdown table, from their cards.

Each card is ``results/second_stage/<first stage>--<name>.json``; a row names the first stage, the settings in
which the run's second stage differs from the recipe's (``configs/15min/finetune/<category>.json``), then its test
scores. Usage::

    python experiments/fifteen/second_stage_table.py [CARD ...]
"""
import argparse
import json
from pathlib import Path

from cuboidlib.train_config import TrainConfig

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments" / "fifteen" / "results" / "second_stage"
HEADER = "| first stage | second stage | test mIoU % | N_AC | CD x1000 | smallest part IoU % | cuboids per instance |"
RULE = "| --- | --- | --- | --- | --- | --- | --- |"
#: Fields that differ in every run without changing what it learns: where it starts, its threads and time limit.
PLUMBING = ("init_from", "num_threads", "max_minutes")


def flat_config(config: dict, prefix: str = "") -> dict:
    """A config dict with its model and loss sections flattened to "model.k", "loss.lambda_compact", ..."""
    out = {}
    for key, value in config.items():
        out.update(flat_config(value, f"{prefix}{key}.") if isinstance(value, dict) else {prefix + key: value})
    return out


def changed_settings(config: dict) -> str:
    """The fields of a second stage's config that differ from the recipe's, or "the recipe"."""
    recipe = TrainConfig.load_json(ROOT / "data_samples" / "checkpoints" / "configs" / "15min" / "finetune"
                                   / f"{config['category']}.json").to_dict()
    mine, theirs = flat_config(config), flat_config(recipe)
    shown = [f"{key.split('.')[-1]} {mine[key]:g}" if isinstance(mine[key], float) else
             f"{key.split('.')[-1]} {mine[key]}" for key in sorted(mine)
             if key not in PLUMBING and mine[key] != theirs.get(key)]
    return ", ".join(shown) or "the recipe"


def row(card_path: Path) -> str:
    """One card's row: first stage, changed settings, test mIoU, N_AC, Chamfer distance, weakest part, concision."""
    card = json.loads(card_path.read_text())
    net = card["test"]["results"][0]
    first = card_path.stem.split("--")[0]
    worst = min(net["part_iou"], key=net["part_iou"].get)
    pieces = ", ".join(f"{part} {v['cuboids_per_instance']:.2f}" for part, v in net["concision"].items()
                       if part in ("back", "leg", "tail"))
    return (f"| {first} | {changed_settings(card['config'])} | {100 * net['miou']:.1f} | {net['n_ac']:.1f} "
            f"| {1000 * net['chamfer'][0]['value']:.2f} | {worst} {100 * net['part_iou'][worst]:.1f} | {pieces} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("cards", nargs="*", type=Path, help="cards (default: every card in results/second_stage/)")
    cards = parser.parse_args().cards or sorted(RESULTS.glob("*.json"))
    print(HEADER)
    print(RULE)
    for card in cards:
        print(row(card))


if __name__ == "__main__":
    main()
