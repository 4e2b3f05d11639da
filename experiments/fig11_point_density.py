"""Fig. 11 of the paper: robustness to sparse point clouds (Sec. 4.3).

Three networks trained on chairs with 256, 1024 and 4096 points per shape (the same shapes,
sampled more or less densely), everything else at course scale. Writes a figure with the
abstraction (points coloured by segment, existing cuboids) and the segmentation of the same test
shape by the three networks side by side, and scores every network on its own test inputs and on
the 4096-point sampling of the same test shapes (so the three Chamfer distances compare the same
reference). The paper shows only the figure; it reports no numbers.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cuboidlib.dataset import split_indices

import command_line
import runner

DENSITIES = (256, 1024, 4096)
PAPER = {"source": "Fig. 11 of Yang & Chen, SIGGRAPH 2021 (chairs with 256, 1024, 4096 points; a figure, no numbers)"}


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}")
    return value


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--shape", type=_non_negative_int, default=0,
                   help="which test shape the figure shows (index in the test split, default 0)")


def build_runs(scale: runner.Scale, args: argparse.Namespace) -> list[runner.Run]:
    reference = scale.points(max(DENSITIES))
    runs = []
    for n in DENSITIES:
        for seed in scale.seeds:
            config = scale.config("chair", seed, n_points=n)
            runs.append(runner.Run(f"points{config.n_points}_seed{seed}", {"points": config.n_points, "seed": seed},
                                   config, options={"reference_points": reference}))
    n_test = len(split_indices(scale.n_shapes, runs[0].config.split_fractions, runs[0].config.split_seed)["test"])
    if args.shape >= n_test:
        raise ValueError(f"--shape {args.shape} is out of range: the test split has {n_test} shapes")
    return runs


def report(records: list[dict], scale: runner.Scale, args: argparse.Namespace) -> tuple[list[dict], str]:
    metrics = ("cd", "cd_reference", "nc", "nc_reference", "miou", "n_ac")
    summary = runner.summarize(runner.result_rows(records), ("points",), metrics)
    reference = scale.points(max(DENSITIES))
    rows = [[str(r["points"]), runner.mean_sd(r, "cd", 1000), runner.mean_sd(r, "cd_reference", 1000),
             runner.mean_sd(r, "nc"), runner.mean_sd(r, "nc_reference"), runner.mean_sd(r, "miou", 100, 1),
             runner.mean_sd(r, "n_ac", 1, 2)] for r in summary]
    headers = ["points", "CD x1000 own input", f"CD x1000 vs {reference}", "NC own input", f"NC vs {reference}",
               "mIoU %", "N_AC"]
    return summary, "\n".join([
        "Fig. 11: training with different numbers of points (chairs)", runner.text_table(headers, rows),
        runner.CD_CONVENTION,
        f"own input: against the test points at the density the network was trained with; vs {reference}: against "
        f"{reference} points of the same test shapes (each density is normalised by its own bounding box, which "
        "differs from the densest one's by well under 1 %).",
        f"The paper: {PAPER['source']}.",
    ])


def draw(records: list[dict], scale: runner.Scale, args: argparse.Namespace, stem: Path) -> list[Path]:
    """The figure: for each density (first seed), the abstraction and the segmentation of one test shape."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import torch

    from cuboidlib.applications import abstract_shapes
    from cuboidlib.checkpoint import load_model
    from cuboidlib.dataset import load_splits
    from cuboidlib.train_config import TrainConfig
    from cuboidlib.viz import plot_cuboids_matplotlib

    shown = [r for r in records if r["status"] == "ok" and r["key"]["seed"] == scale.seeds[0]]
    if not shown:
        return []
    fig = plt.figure(figsize=(3.0 * len(shown), 6.2))
    index = None
    for col, record in enumerate(shown):
        config = TrainConfig.from_dict(record["config"])
        test = load_splits(config)["test"]
        model, _ = load_model(record["checkpoint"])
        out = abstract_shapes(model, test.points[args.shape:args.shape + 1],  # cuboids where the losses put them
                              centers_from_allocation=config.loss_config.centers_from_allocation)
        points, labels, index = test.points[args.shape], out.labels[0], int(test.indices[args.shape])
        used = int(out.cuboids.exists[0].sum())
        for row, boxes in enumerate((True, False)):
            ax = fig.add_subplot(2, len(shown), row * len(shown) + col + 1, projection="3d", proj_type="ortho")
            exists = out.cuboids.exists[0] if boxes else torch.zeros_like(out.cuboids.exists[0])
            title = f"{config.n_points} points: {used} cuboids" if boxes else "segmentation"
            plot_cuboids_matplotlib(ax, points, labels, out.cuboids, exists, index=0, max_points=config.n_points,
                                    point_size=4.0 if config.n_points <= 256 else 2.0, title=title)
    fig.suptitle(f"Chair {index} of the collection (test shape {args.shape}): trained with {', '.join(str(r['key']['points']) for r in shown)} "
                 "points" + (" (QUICK run: meaningless)" if scale.quick else ""), fontsize=10)
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.9, wspace=0, hspace=0.1)
    path = stem.with_suffix(".png")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]


EXPERIMENT = command_line.Experiment(
    name="fig11_point_density",
    title="Fig. 11: chairs trained with 256, 1024 and 4096 points (figure of one test shape, metrics)",
    description=__doc__,
    paper=PAPER,
    default_steps=600,
    default_seeds=1,
    build_runs=build_runs,
    report=report,
    add_arguments=add_arguments,
    finish=draw,
)

if __name__ == "__main__":
    raise SystemExit(command_line.main(EXPERIMENT))
