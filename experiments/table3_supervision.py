"""Table 3 of the paper: the role of the segmentation branch (Sec. 4.3, "Role of the segmentation module").

Three ways to supervise the cuboids, each trained on chairs, tables and airplanes:

* **P2C-Dis**: no segmentation branch; every point is allocated to its nearest cuboid under the
  point-to-cuboid distance of Eq. (5) (``LossConfig(allocation="nearest_cuboid")``);
* **Chamfer-Dis**: no segmentation branch; the bidirectional Chamfer distance between the points
  and samples on the cuboids is the reconstruction loss, as in most earlier methods
  (``LossConfig(distance="chamfer")``);
* **P2C-Seg**: the paper's method, Eq. (4) with the allocation W of the segmentation branch.

"For a fair comparison" the paper trains all three with the reconstruction loss only; here that
means lambda_1 = 0 (no compactness loss, ``--lambda-compact`` changes it), while the existence and
KL terms stay so that the existence head learns which cuboids are used (only existing cuboids are
scored). Scores: Chamfer distance and mIoU on the test split; the variants without a segmentation
branch segment every point by its nearest existing cuboid under their own distance, as the paper
does for its Fig. 8.

The cuboids' positions: the course's recipe places each cuboid at the centroid of the points the segmentation
branch allocates to it (``centers_from_allocation``, the authors' code). P2C-Dis and Chamfer-Dis replace that
allocation in their reconstruction loss, but under the recipe the branch still places their cuboids, so it
still trains through their positions. ``--predicted-positions`` gives these two variants the predicted
translation t_m instead, so that they use no segmentation branch at all (the paper's variants); P2C-Seg keeps
the recipe's positions. ``--variants`` trains a subset of the three.
"""

from __future__ import annotations

import argparse

import command_line
import runner

CATEGORIES = ("chair", "table", "airplane")
#: name -> LossConfig changes (on top of the course-scale loss) and the segmentation used for mIoU.
VARIANTS = {
    "P2C-Dis": ({"allocation": "nearest_cuboid"}, "normal"),
    "Chamfer-Dis": ({"distance": "chamfer"}, "nearest_surface"),
    "P2C-Seg": ({}, None),
}
#: Table 3 of Yang & Chen (2021): Chamfer distance (their convention) per category and variant.
PAPER = {
    "source": "Table 3 of Yang & Chen, SIGGRAPH 2021 (Chamfer distance, convention not documented)",
    "cd": {
        "airplane": {"P2C-Dis": 4.836, "Chamfer-Dis": 0.286, "P2C-Seg": 0.237},
        "chair": {"P2C-Dis": 3.356, "Chamfer-Dis": 0.834, "P2C-Seg": 0.436},
        "table": {"P2C-Dis": 3.335, "Chamfer-Dis": 0.992, "P2C-Seg": 0.846},
    },
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--categories", type=command_line.categories_option(CATEGORIES), default=CATEGORIES,
                   help="comma-separated subset of chair,table,airplane (default: all three)")
    p.add_argument("--lambda-compact", type=float, default=0.0,
                   help="lambda_1 of all three variants (default 0: the paper trains them with L_recons only)")
    p.add_argument("--variants", type=command_line.categories_option(tuple(VARIANTS)), default=tuple(VARIANTS),
                   help="comma-separated subset of P2C-Dis,Chamfer-Dis,P2C-Seg (default: all three)")
    p.add_argument("--predicted-positions", action="store_true",
                   help="P2C-Dis and Chamfer-Dis place their cuboids at the predicted translations t_m, not at the "
                        "centroids of the segmentation branch's allocation (the recipe's), so that no segmentation "
                        "branch shapes them")


def build_runs(scale: runner.Scale, args: argparse.Namespace) -> list[runner.Run]:
    if not args.lambda_compact >= 0:
        raise ValueError(f"--lambda-compact must be a non-negative number, got {args.lambda_compact}")
    runs = []
    for category in args.categories:
        for variant in args.variants:
            loss, segmentation = VARIANTS[variant]
            if args.predicted_positions and segmentation is not None:  # a variant without a segmentation branch
                loss = {**loss, "centers_from_allocation": False}
            for seed in scale.seeds:
                changes = {"loss": {**loss, "lambda_compact": args.lambda_compact}}
                config = scale.config(category, seed, **changes)
                options = {"method": variant} if segmentation is None else {"method": variant,
                                                                              "segmentation": segmentation}
                runs.append(runner.Run(f"{category}_{variant}_seed{seed}",
                                       {"category": category, "variant": variant, "seed": seed}, config,
                                       options=options, finetune=scale.finetune_config(category, seed, **changes)))
    return runs


def report(records: list[dict], scale: runner.Scale, args: argparse.Namespace) -> tuple[list[dict], str]:
    summary = runner.summarize(runner.result_rows(records), ("category", "variant"), ("cd", "miou", "n_ac"))
    rows = []
    for row in summary:
        row["paper_cd"] = PAPER["cd"][row["category"]][row["variant"]]
        rows.append([row["category"], row["variant"], runner.mean_sd(row, "cd", 1000), runner.paper_value(row["paper_cd"]),
                     runner.mean_sd(row, "miou", 100, 1), runner.mean_sd(row, "n_ac", 1, 2)])
    table = runner.text_table(["category", "variant", "CD x1000 (ours)", "CD (paper)", "mIoU % (ours)", "N_AC (ours)"],
                              rows)
    return summary, "\n".join(["Table 3: supervision of the cuboids (P2C-Dis, Chamfer-Dis, P2C-Seg)", table,
                               runner.CD_CONVENTION, f"Paper numbers: {PAPER['source']}; the paper gives no mIoU here."])


def notes(scale: runner.Scale, args: argparse.Namespace) -> list[str]:
    return [f"All variants: lambda_1 = {args.lambda_compact} (the paper: L_recons only), existence and KL terms kept. "
            "P2C-Dis and Chamfer-Dis segment each point by its nearest existing cuboid (P2C-Dis: Eq. (5) with "
            "sigma_s = 0; Chamfer-Dis: nearest surface), P2C-Seg by its segmentation branch."]


EXPERIMENT = command_line.Experiment(
    name="table3_supervision",
    title="Table 3: P2C-Dis vs Chamfer-Dis vs P2C-Seg on chair, table, airplane (Chamfer distance, mIoU)",
    description=__doc__,
    paper=PAPER,
    default_steps=600,
    default_seeds=1,
    build_runs=build_runs,
    report=report,
    add_arguments=add_arguments,
    notes=notes,
    recipes=("course", runner.FIFTEEN_MINUTES),
)

if __name__ == "__main__":
    raise SystemExit(command_line.main(EXPERIMENT))
