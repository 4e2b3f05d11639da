"""Table 6 of the paper: the number of cuboids M (Sec. 4.3, "Choice of the cuboid number M").

Chairs, tables and airplanes trained with M in {8, 12, 16, 20, 24}, every other setting fixed at
course scale. Scores on the test split: Chamfer distance and N_AC (average number of existing
cuboids). The paper's trend: the Chamfer distance falls and N_AC grows as M grows.

Note on the compactness form: the course scale uses the averaged form (Eq. (6) / M^2, as the
authors' code), whose effective weight on Eq. (6) is lambda_1 / M^2, so at a fixed lambda_1 it
also weakens as M grows (with the course's lambda_1 = 0.02: 0.02 / 64 at M = 8, 0.02 / 576 at M = 24).
"""

from __future__ import annotations

import argparse

import command_line
import runner

CATEGORIES = ("chair", "table", "airplane")
NUM_CUBOIDS = (8, 12, 16, 20, 24)
#: Table 6 of Yang & Chen (2021): CD and N_AC per category and M.
PAPER = {
    "source": "Table 6 of Yang & Chen, SIGGRAPH 2021 (Chamfer distance in an undocumented convention)",
    "cd": {"airplane": (0.849, 0.484, 0.394, 0.329, 0.285), "chair": (1.381, 0.501, 0.399, 0.385, 0.366),
           "table": (1.170, 1.062, 0.826, 0.776, 0.657)},
    "n_ac": {"airplane": (4.171, 5.663, 9.801, 11.801, 13.720), "chair": (5.976, 7.150, 9.753, 10.130, 12.158),
             "table": (5.636, 7.328, 8.524, 9.747, 12.573)},
    "M": NUM_CUBOIDS,
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--categories", type=command_line.categories_option(CATEGORIES), default=CATEGORIES,
                   help="comma-separated subset of chair,table,airplane (default: all three)")


def build_runs(scale: runner.Scale, args: argparse.Namespace) -> list[runner.Run]:
    runs = []
    for category in args.categories:
        for m in NUM_CUBOIDS:
            for seed in scale.seeds:
                runs.append(runner.Run(f"{category}_M{m}_seed{seed}", {"category": category, "M": m, "seed": seed},
                                       scale.config(category, seed, model={"num_cuboids": m}),
                                       finetune=scale.finetune_config(category, seed, model={"num_cuboids": m})))
    return runs


def report(records: list[dict], scale: runner.Scale, args: argparse.Namespace) -> tuple[list[dict], str]:
    summary = runner.summarize(runner.result_rows(records), ("category", "M"), ("cd", "n_ac", "miou", "nc"))
    rows = []
    for row in summary:
        i = NUM_CUBOIDS.index(row["M"])
        row["paper_cd"], row["paper_n_ac"] = PAPER["cd"][row["category"]][i], PAPER["n_ac"][row["category"]][i]
        rows.append([row["category"], str(row["M"]), runner.mean_sd(row, "cd", 1000), runner.paper_value(row["paper_cd"]),
                     runner.mean_sd(row, "n_ac", 1, 2), runner.paper_value(row["paper_n_ac"])])
    headers = ["category", "M", "CD x1000 (ours)", "CD (paper)", "N_AC (ours)", "N_AC (paper)"]
    return summary, "\n".join([
        "Table 6: maximum number of cuboids M", runner.text_table(headers, rows), runner.CD_CONVENTION,
        f"Paper numbers: {PAPER['source']}.",
    ])


def notes(scale: runner.Scale, args: argparse.Namespace) -> list[str]:
    lams = {c: scale.config(c).loss_config.lambda_compact for c in args.categories}
    each = ", ".join(f"{lam:g} ({c})" for c, lam in lams.items())
    return [f"lambda_1 on the averaged compactness, the same for every M: {each}. Its effective weight on Eq. (6) "
            "is lambda_1 / M^2, so a larger M also means a weaker push towards few cuboids."]


EXPERIMENT = command_line.Experiment(
    name="table6_num_cuboids",
    title="Table 6: number of cuboids M in {8, 12, 16, 20, 24} on chair, table, airplane (Chamfer distance, N_AC)",
    description=__doc__,
    paper={"source": PAPER["source"], "M": list(NUM_CUBOIDS), "cd": PAPER["cd"], "n_ac": PAPER["n_ac"]},
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
