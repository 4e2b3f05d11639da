"""Are the animals' short tails among the points that their cuboids fit worst?

A cuboid that no shape uses could be restarted at the points that the other cuboids fit worst. That would give
the short tails a cuboid only if the short tails are among those points. For each network, on the scored test
animals with a short tail, the script ranks each animal's points by the distance that the first stage trains
on, sum_m W_nm d(p_n, C_m) (Eq. 4 with the distance of Eq. 5, without the sample along the normal), and reports
what share of the K worst-fitted points each part holds, and what share of the tail's points are among them.
A short tail holds about 1.3 % of an animal's points. Usage::

    python experiments/fifteen/worst_fitted.py [CHECKPOINT ...] [--k 8 16 32] [--out results/worst_fitted.json]

Without checkpoints it reads the two seed-0 first stages kept in ``results/first_stage/`` (a constant rate with
lambda_1 = 0.02, and a falling rate with lambda_1 = 0.01), whose networks give no short tail a cuboid, and the
recipe's 15-minute animal. It prints a Markdown table and writes its rows to ``--out``.
"""
import argparse
from pathlib import Path

import torch

from cuboidlib.checkpoint import load_checkpoint, load_model
from cuboidlib.dataset import load_splits
from cuboidlib.distance import point_to_cuboid_distance
from cuboidlib.evaluation import label_transfer_split, predict_cuboids
from cuboidlib.shapes import make_collection
from cuboidlib.train_config import TrainConfig
from tail_cuboids import shown_path, write_rows

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments" / "fifteen" / "results"
PARTS = ("body", "leg", "head", "tail")  # the animals' part labels, in their order
DEFAULT = (RESULTS / "first_stage" / "animal.pt", RESULTS / "first_stage" / "animal_lambda001_seed0.pt",
           RESULTS / "second500" / "animal_15min.pt")


def worst_fitted(checkpoint: Path, ks: list[int]) -> list[dict]:
    """For one animal network and each K: each part's share of the K worst-fitted points of the short-tailed
    scored test animals, and the share of their tail points that are among those points."""
    model, _ = load_model(checkpoint)
    config = TrainConfig.from_dict(load_checkpoint(checkpoint)["config"])
    if config.category != "animal":
        raise SystemExit(f"{checkpoint}: an animal network expected, got a {config.category} network")
    test = load_splits(config)["test"]
    _, scored = label_transfer_split(len(test))  # the animals the cards score
    collection = make_collection(config.category, config.n_shapes, config.n_points, config.data_seed,
                                 version=config.generator_version)
    short = torch.tensor(["short-tail" in str(collection.structures[i]) for i in test.indices[scored].tolist()])
    chosen = scored[short]
    pred, _ = predict_cuboids(model, test, centers_from_allocation=config.loss_config.centers_from_allocation)
    c = pred.cuboids
    d = point_to_cuboid_distance(test.points[chosen], test.normals[chosen], c.centers[chosen], c.quaternions[chosen],
                                 c.half_sizes[chosen], sigma_s=0.0)
    residual = (pred.W[chosen] * d).sum(dim=-1)  # (S, N)
    labels = test.labels[chosen]
    tail = labels == PARTS.index("tail")
    rows = []
    for k in ks:
        among = torch.zeros_like(tail).scatter_(1, residual.topk(k, dim=1).indices, True)
        shares = {f"{part}_share_of_worst_percent": 100 * float((among & (labels == i)).sum() / among.sum())
                  for i, part in enumerate(PARTS)}
        rows.append({"k": k, "animals": int(len(chosen)), **shares,
                     "tail_points_among_worst_percent": 100 * float((among & tail).sum() / tail.sum()),
                     "tail_share_of_all_percent": 100 * float(tail.float().mean())})
    return rows


def table(rows: list[dict]) -> list[str]:
    """The Markdown table of the rows that main() writes."""
    lines = ["| network | K | short-tailed test animals | the K worst-fitted points: body / leg / head / tail % "
             "| tail points among them % | tail among all points % |", "| --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        parts = " / ".join(f"{r[f'{part}_share_of_worst_percent']:.1f}" for part in PARTS)
        lines.append(f"| `{r['network']}` | {r['k']} | {r['animals']} | {parts} | "
                     f"{r['tail_points_among_worst_percent']:.1f} | {r['tail_share_of_all_percent']:.1f} |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="*", type=Path, default=list(DEFAULT))
    parser.add_argument("--k", type=int, nargs="+", default=[8, 16, 32])
    parser.add_argument("--out", type=Path, default=RESULTS / "worst_fitted.json")
    args = parser.parse_args()
    rows = []
    for path in args.checkpoints:
        rows += [{"network": shown_path(path), **r} for r in worst_fitted(path, args.k)]
    print("\n".join(table(rows)))
    write_rows(args.out, "worst_fitted.py", rows)


if __name__ == "__main__":
    main()
