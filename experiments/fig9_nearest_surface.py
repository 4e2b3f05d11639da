"""Fig. 9 of the paper: the degenerate cuboids of the nearest-surface distance (Sec. 4.3).

The paper's caption, in our words: trained to minimise the distance from each point to the nearest cuboid
surface, without looking at the normals, the network covers a shape with thin cuboids stacked in one
direction, which reconstruct the points but not the structure. Eq. (5), which pairs each point with the
face whose normal matches its own, does not.

The runs are Table 4's chair configurations without noise (``table4_distance``) at today's course scale: the "Distance" column (the
nearest-surface distance) and Eq. (5) with the course's sigma_s = 0.05. Besides Table 4's metrics the
table reports the thickness of the cuboids (``runner.thickness``: the smallest half size over the largest,
median over a shape's cuboids; 1 for cubes, near 0 for plates). The figure shows the first three test chairs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import command_line
import runner
import table4_distance as table4

PAPER = {"source": "Fig. 9 of Yang & Chen, SIGGRAPH 2021 (a figure; the numbers are Table 4's)"}
SHOWN = (("Distance", 0.0), ("Normal", 0.05))


def build_runs(scale: runner.Scale, args: argparse.Namespace) -> list[runner.Run]:
    return [r for r in table4.build_runs(scale, args)
            if r.key["sigma_n"] == 0.0 and (r.key["distance"], r.key["sigma_s"]) in SHOWN]


def report(records: list[dict], scale: runner.Scale, args: argparse.Namespace) -> tuple[list[dict], str]:
    metrics = ("thickness", "cd", "nc_both", "nc", "miou", "n_ac")
    summary = runner.summarize(runner.result_rows(records), ("distance", "sigma_s"), metrics)
    rows = [[r["distance"], f"{r['sigma_s']:.3f}", runner.mean_sd(r, "thickness", 1, 3), runner.mean_sd(r, "cd", 1000),
             runner.mean_sd(r, "nc_both"), runner.mean_sd(r, "nc"), runner.mean_sd(r, "miou", 100, 1),
             runner.mean_sd(r, "n_ac", 1, 2)] for r in summary]
    headers = ["distance", "sigma_s", "thickness", "CD x1000", "NC", "NC from points", "mIoU %", "N_AC"]
    return summary, "\n".join([
        "Fig. 9: the nearest-surface distance against Eq. (5) (chairs, no noise)", runner.text_table(headers, rows),
        runner.CD_CONVENTION,
        "thickness: smallest over largest half size of a cuboid, median over a shape's existing cuboids, mean over "
        "the test shapes (1 = cubes, near 0 = plates). NC: normal consistency both ways; 'from points' alone.",
        f"The paper: {PAPER['source']}.",
    ])


def draw(records: list[dict], scale: runner.Scale, args: argparse.Namespace, stem: Path) -> list[Path]:
    label = {"Distance": "nearest surface", "Normal": "Eq. (5)"}
    return runner.draw_abstractions(records, scale, stem, lambda r: label[r["key"]["distance"]],
                                    "Fig. 9: chairs trained with the nearest-surface distance (top) and with Eq. (5)")


EXPERIMENT = command_line.Experiment(
    name="fig9_nearest_surface",
    title="Fig. 9: the cuboids of the nearest-surface distance against Eq. (5) on chairs (figure, thickness)",
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
