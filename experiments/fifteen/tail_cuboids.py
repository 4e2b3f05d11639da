"""Which animals' tails get a cuboid of their own: the tail's recall, split by short and long tails.

The procedural animals have a short or a long tail (their structure string says which). On the test split, for
each network, the script counts the test animals of each kind and the share of their tail points that the label
transfer of the cards (20 % of the shapes labelled, seed 0) names "tail", and how many of those animals have a
cuboid named "tail" at all. A short tail that shares a cuboid with the rump is named "body", and the tail's IoU
falls with it. Usage::

    python experiments/fifteen/tail_cuboids.py [CHECKPOINT ...] [--out results/tail_cuboids.json]

Without checkpoints it reads the committed animal network and the two 15-minute animal networks kept in
``results/`` (the recipe's, seed 0, and seed 1). It prints a Markdown table and writes its rows to ``--out``.
"""
import argparse
import json
import os
import sys
from pathlib import Path

import torch

from cuboidlib.checkpoint import load_checkpoint, load_model
from cuboidlib.dataset import load_splits
from cuboidlib.evaluation import label_transfer_split, predict_cuboids, segmentation_scores
from cuboidlib.shapes import make_collection
from cuboidlib.train_config import TrainConfig

ROOT = Path(__file__).resolve().parents[2]
DEFAULT = (ROOT / "data_samples" / "checkpoints" / "animal.pt",
           ROOT / "experiments" / "fifteen" / "results" / "second500" / "animal_15min.pt",
           ROOT / "experiments" / "fifteen" / "results" / "consistency0" / "animal_seed1_15min.pt")


def tail_recall(checkpoint: Path) -> dict:
    """For one animal network: per tail kind, the scored test animals, those with a cuboid named tail, and the
    share of their tail points named tail; and the tail's IoU."""
    model, _ = load_model(checkpoint)
    config = TrainConfig.from_dict(load_checkpoint(checkpoint)["config"])
    if config.category != "animal":
        raise SystemExit(f"{checkpoint}: an animal network expected, got a {config.category} network")
    test = load_splits(config)["test"]
    pred, _ = predict_cuboids(model, test, centers_from_allocation=config.loss_config.centers_from_allocation)
    scores = segmentation_scores(test, pred)  # the cards' label transfer
    names = scores["label_transfer"]["confusion"]["parts"]
    cuboid_part = torch.tensor(scores["label_transfer"]["cuboid_labels"])
    _, scored = label_transfer_split(len(test))
    collection = make_collection(config.category, config.n_shapes, config.n_points, config.data_seed,
                                 version=config.generator_version)
    short = torch.tensor(["short-tail" in str(collection.structures[i]) for i in test.indices[scored].tolist()])
    tail = names.index("tail")
    named = cuboid_part[pred.labels[scored]]  # (S, N) the part each point is named
    is_tail = test.labels[scored] == tail
    out = {"tail IoU %": 100 * scores["part_iou"]["tail"]}
    for kind, chosen in (("short", short), ("long", ~short)):
        points = is_tail & chosen[:, None]
        with_cuboid = ((named == tail) & chosen[:, None]).any(dim=1).sum()
        out[kind] = (int(chosen.sum()), int(with_cuboid), 100 * float((named[points] == tail).float().mean()),
                     float(is_tail[chosen].sum(dim=1).float().mean()))
    return out


def table(rows: list[dict]) -> list[str]:
    """The Markdown table of the rows that main() writes."""
    lines = ["| network | tail kind | test animals scored | with a cuboid named tail | tail points per animal "
             "| tail points named tail % | tail IoU % |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| `{r['network']}` | {r['kind']} | {r['animals']} | {r['with_tail_cuboid']} | "
                     f"{r['tail_points']:.1f} | {r['named_tail_percent']:.1f} | {r['tail_iou_percent']:.1f} |")
    return lines


def shown_path(path: Path) -> str:
    """A checkpoint's path as the tables show it: relative to the repository where it lies inside."""
    return str(path.resolve().relative_to(ROOT) if path.resolve().is_relative_to(ROOT) else path)


def write_rows(out: Path, script: str, rows: list[dict]) -> None:
    """Write the rows and the command line that made them to ``out`` (atomically)."""
    tmp = out.with_suffix(".tmp")
    command = " ".join(["python", f"experiments/fifteen/{script}", *sys.argv[1:]])
    tmp.write_text(json.dumps({"command": command, "rows": rows}, indent=1) + "\n")
    os.replace(tmp, out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="*", type=Path, default=list(DEFAULT))
    parser.add_argument("--out", type=Path, default=ROOT / "experiments" / "fifteen" / "results" / "tail_cuboids.json")
    args = parser.parse_args()
    rows = []
    for path in args.checkpoints:
        r = tail_recall(path)
        for kind in ("short", "long"):
            n, with_cuboid, recall, size = r[kind]
            rows.append({"network": shown_path(path), "kind": kind, "animals": n, "with_tail_cuboid": with_cuboid,
                         "tail_points": size, "named_tail_percent": recall, "tail_iou_percent": r["tail IoU %"]})
    print("\n".join(table(rows)))
    write_rows(args.out, "tail_cuboids.py", rows)


if __name__ == "__main__":
    main()
