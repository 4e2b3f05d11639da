"""Fig. 8 of the paper: what the three supervision variants of Table 3 allocate (Sec. 4.3).

The paper's caption, in our words: the cuboids and the segmentation of chairs by networks trained with
P2C-Dis (each point goes to its nearest cuboid under Eq. (5)), Chamfer-Dis (the Chamfer distance between
the points and the cuboid surfaces) and P2C-Seg (the paper's segmentation branch). Only P2C-Seg's cuboids
follow the parts; the nearest-cuboid variants cut the shape wherever the cuboids happen to lie.

The runs are Table 3's chair configurations (``table3_supervision.VARIANTS``, lambda_1 = 0 as the paper trains
them) at today's course scale, scored the same way; the figure shows the first three test chairs of each network, the variants without a
segmentation branch segmented by their nearest existing cuboid, as the paper does.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import command_line
import runner
import table3_supervision as table3

PAPER = {"source": "Fig. 8 of Yang & Chen, SIGGRAPH 2021 (a figure; the numbers are Table 3's)"}


def build_runs(scale: runner.Scale, args: argparse.Namespace) -> list[runner.Run]:
    return table3.build_runs(scale, table3.EXPERIMENT.parser().parse_args(["--categories", "chair"]))  # its defaults


def report(records: list[dict], scale: runner.Scale, args: argparse.Namespace) -> tuple[list[dict], str]:
    summary, text = table3.report(records, scale, args)
    return summary, text.replace("Table 3: supervision", "Fig. 8 (Table 3's chair rows): supervision", 1)


def draw(records: list[dict], scale: runner.Scale, args: argparse.Namespace, stem: Path) -> list[Path]:
    return runner.draw_abstractions(records, scale, stem, lambda r: r["key"]["variant"],
                                    "Fig. 8: chairs abstracted and segmented by the three supervision variants")


EXPERIMENT = command_line.Experiment(
    name="fig8_supervision",
    title="Fig. 8: the allocations of P2C-Dis, Chamfer-Dis and P2C-Seg on chairs (figure, Table 3's metrics)",
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
