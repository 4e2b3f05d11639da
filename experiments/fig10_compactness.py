"""Fig. 10 of the paper: abstractions under different compactness weights lambda_1 (Sec. 4.3).

The paper's caption, in our words: the same shapes abstracted by networks trained with different weights of
the compactness loss, with the number of cuboids beside each; the structure stays consistent within the
category, and a suitable weight gives concise, accurately structured abstractions.

The runs are Table 5's chair configurations for the first seed (``table5_compactness.LAMBDAS``, the averaged
compactness) at today's course scale, scored the same way; the figure shows the first three test chairs per
weight, each titled with its number of cuboids.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import command_line
import runner
import table5_compactness as table5

PAPER = {"source": "Fig. 10 of Yang & Chen, SIGGRAPH 2021 (a figure; the numbers are Table 5's)"}


def build_runs(scale: runner.Scale, args: argparse.Namespace) -> list[runner.Run]:
    return table5.build_runs(scale, argparse.Namespace(with_sum_form=False))


def report(records: list[dict], scale: runner.Scale, args: argparse.Namespace) -> tuple[list[dict], str]:
    summary, text = table5.report(records, scale, args)
    return summary, text.replace("Table 5: weight", "Fig. 10 (Table 5's runs): weight", 1)


def draw(records: list[dict], scale: runner.Scale, args: argparse.Namespace, stem: Path) -> list[Path]:
    return runner.draw_abstractions(records, scale, stem, lambda r: f"lambda_1 = {r['key']['lambda_1']:g}",
                                    "Fig. 10: chairs abstracted by networks trained with four compactness weights")


EXPERIMENT = command_line.Experiment(
    name="fig10_compactness",
    title="Fig. 10: chairs abstracted with lambda_1 in {0, 0.05, 0.1, 0.2}, the number of cuboids beside each",
    description=__doc__,
    paper=PAPER,
    default_steps=600,
    default_seeds=1,
    build_runs=build_runs,
    report=report,
    finish=draw,
)

if __name__ == "__main__":
    raise SystemExit(command_line.main(EXPERIMENT))
