"""Table 5 of the paper: the weight lambda_1 of the compactness loss (Sec. 4.3, "Compactness loss").

Chairs trained with lambda_1 in {0, 0.05, 0.1, 0.2}, everything else at course scale, several
seeds (mean and spread). Scores on the test split: N_AC (average number of existing cuboids),
Chamfer distance and mIoU by label transfer. The paper's trend: as lambda_1 grows, fewer cuboids
are used and the Chamfer distance grows; at 0.2 structure is lost (CD and mIoU worsen).

The compactness loss has the averaged form of the course scale (Eq. (6) / M^2, as in the authors'
code), so the effective weight on Eq. (6) as printed is lambda_1 / 256 for M = 16.
``--with-sum-form`` adds a run of lambda_1 = 0.1 on Eq. (6) exactly as printed (a sum over
cuboids) per seed, to see the collapse the printed note explains.

``--recipe 15min`` trains every cell with the two stages of the 15-minute recipe instead (1000 shapes, batch 16,
2500 + 500 steps, lambda_1 changed in both stages) and writes ``table5_compactness_15min.*``.
"""

from __future__ import annotations

import argparse

import command_line
import runner

LAMBDAS = (0.0, 0.05, 0.1, 0.2)
#: Table 5 of Yang & Chen (2021), chairs.
PAPER = {
    "source": "Table 5 of Yang & Chen, SIGGRAPH 2021 (chairs; Chamfer distance in an undocumented convention)",
    "n_ac": {0.0: 15.486, 0.05: 11.144, 0.1: 9.753, 0.2: 5.544},
    "cd": {0.0: 0.381, 0.05: 0.385, 0.1: 0.399, 0.2: 1.452},
    "miou": {0.0: 81.2, 0.05: 82.1, 0.1: 82.0, 0.2: 72.5},
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--with-sum-form", action="store_true",
                   help="also train lambda_1 = 0.1 with Eq. (6) as printed (sum over cuboids), one run per seed")


def build_runs(scale: runner.Scale, args: argparse.Namespace) -> list[runner.Run]:
    variants = [(lam, "averaged") for lam in LAMBDAS] + ([(0.1, "sum")] if args.with_sum_form else [])
    runs = []
    for lam, form in variants:
        for seed in scale.seeds:
            loss = {"lambda_compact": lam, "compactness_average": form == "averaged"}
            runs.append(runner.Run(f"lambda{lam:g}_{form}_seed{seed}", {"lambda_1": lam, "form": form, "seed": seed},
                                   scale.config("chair", seed, loss=loss),
                                   finetune=scale.finetune_config("chair", seed, loss=loss)))
    return runs


def report(records: list[dict], scale: runner.Scale, args: argparse.Namespace) -> tuple[list[dict], str]:
    summary = runner.summarize(runner.result_rows(records), ("lambda_1", "form"), ("n_ac", "cd", "miou", "nc"))
    rows = []
    for row in summary:
        paper = row["form"] == "averaged"
        for metric, column in (("n_ac", "paper_n_ac"), ("cd", "paper_cd"), ("miou", "paper_miou_percent")):
            row[column] = PAPER[metric][row["lambda_1"]] if paper else None
        rows.append([f"{row['lambda_1']:.2f}", row["form"], runner.mean_sd(row, "n_ac", 1, 2),
                     runner.paper_value(row["paper_n_ac"]), runner.mean_sd(row, "cd", 1000),
                     runner.paper_value(row["paper_cd"]), runner.mean_sd(row, "miou", 100, 1),
                     runner.paper_value(row["paper_miou_percent"], 1), ", ".join(map(str, row["seeds"]))])
    headers = ["lambda_1", "compactness", "N_AC (ours)", "N_AC (paper)", "CD x1000 (ours)", "CD (paper)",
               "mIoU % (ours)", "mIoU (paper)", "seeds"]
    return summary, "\n".join([
        "Table 5: weight lambda_1 of the compactness loss (chairs, M = 16)", runner.text_table(headers, rows),
        runner.CD_CONVENTION,
        "compactness: averaged = (mean_m sqrt(w_m + 0.01))^2 = Eq. (6) / M^2 (the course scale, the authors' code); "
        "sum = Eq. (6) as printed.",
        f"Paper numbers: {PAPER['source']}.",
    ])


EXPERIMENT = command_line.Experiment(
    name="table5_compactness",
    title="Table 5: compactness weight lambda_1 in {0, 0.05, 0.1, 0.2} (chairs; N_AC, Chamfer distance, mIoU)",
    description=__doc__,
    paper={"source": PAPER["source"], **{k: {str(lam): v for lam, v in PAPER[k].items()} for k in ("n_ac", "cd", "miou")}},
    default_steps=600,
    default_seeds=3,
    build_runs=build_runs,
    report=report,
    add_arguments=add_arguments,
    recipes=("course", runner.FIFTEEN_MINUTES),
)

if __name__ == "__main__":
    raise SystemExit(command_line.main(EXPERIMENT))
