"""Tables 1 and 2 of the paper at course scale: reconstruction (Chamfer distance) and co-segmentation (mIoU).

For each of the four categories (airplane, chair, table, animal), three methods on the same test
split:

* **network**: the full method, trained at course scale (or, with ``--checkpoints DIR``, the
  released checkpoints ``DIR/<category>.pt`` scored without training);
* **k-means boxes**: the non-learned baseline (:func:`cuboidlib.evaluation.evaluate_baseline`):
  k-means on positions and normals, one oriented bounding box per cluster, with K = the network's
  N_AC rounded;
* **per-shape fitting**: :func:`cuboidlib.fitting.fit_cuboids` on every test shape (the paper's
  losses minimised over free cuboids and a free allocation, M of the category, 300 Adam steps);
* **network + refinement** (``--refine STEPS``, default 100): the per-shape fit started from the
  network's cuboids and allocation (``fit_cuboids(start=...)``, as ``cuboidlib abstract --refine``),
  which keeps the network's cuboid slots and so its part correspondence.

All three are scored the same way (:func:`cuboidlib.evaluation.score_cuboids`): Chamfer distance,
normal consistency, mIoU by the paper's label transfer (Sec. 4.2), N_AC. The per-shape methods
number their cuboids independently in every shape, so the label transfer (which gives each cuboid
INDEX one part label) cannot work for them: that is what co-segmentation adds. The paper compares
with other learned methods (VP, HA, SQ, BAE-Net, BSP-Net), which are not reimplemented here; their
numbers are printed for reference.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from cuboidlib.checkpoint import load_checkpoint
from cuboidlib.train_config import TrainConfig

import command_line
import runner

CATEGORIES = ("airplane", "chair", "table", "animal")
#: Tables 1 (Chamfer distance) and 2 (mIoU, %) of Yang & Chen (2021).
PAPER = {
    "source": "Tables 1 (Chamfer distance, convention not documented) and 2 (mIoU %) of Yang & Chen, SIGGRAPH 2021",
    "cd": {"VP": {"airplane": 0.725, "chair": 1.006, "table": 1.525, "animal": 1.896},
           "HA": {"airplane": 0.713, "chair": 1.109, "table": 1.449, "animal": 0.575},
           "Ours": {"airplane": 0.329, "chair": 0.399, "table": 0.848, "animal": 0.350}},
    "miou": {"VP": {"airplane": 37.6, "chair": 64.7, "table": 62.1},
             "SQ": {"airplane": 48.9, "chair": 65.6, "table": 77.7},
             "HA": {"airplane": 55.6, "chair": 80.4, "table": 67.4},
             "BAE-Net": {"airplane": 61.1, "chair": 65.5, "table": 87.0},
             "BSP-Net": {"airplane": 74.5, "chair": 82.1, "table": 90.3},
             "Ours": {"airplane": 64.2, "chair": 82.0, "table": 89.2}},
}
METHODS = ("network", "network + refinement", "k-means boxes", "per-shape fitting")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--categories", type=command_line.categories_option(CATEGORIES), default=CATEGORIES,
                   help="comma-separated subset of airplane,chair,table,animal (default: all four)")
    p.add_argument("--checkpoints", metavar="DIR",
                   help="score the released checkpoints DIR/<category>.pt (e.g. data_samples/checkpoints) instead "
                        "of training; their data settings are used")
    p.add_argument("--refine", type=int, default=100, metavar="STEPS",
                   help="also score the network refined by STEPS steps of the per-shape fit (default 100; 0: not)")
    p.add_argument("--without-fitting", action="store_true",
                   help="leave out per-shape fitting (the slowest method: a few seconds for every test shape)")


def build_runs(scale: runner.Scale, args: argparse.Namespace) -> list[runner.Run]:
    if args.checkpoints and len(scale.seeds) > 1:
        raise ValueError("--checkpoints scores one released network per category; it takes no --seeds")
    runs = []
    refine = (5 if scale.quick else args.refine) if args.refine else 0
    for category in args.categories:
        for seed in scale.seeds:
            key = {"category": category, "seed": seed}
            if args.checkpoints:
                path = Path(args.checkpoints) / f"{category}.pt"
                if not path.is_file():
                    raise FileNotFoundError(f"{path}: no such checkpoint (--checkpoints needs DIR/<category>.pt)")
                config = TrainConfig.from_dict(load_checkpoint(path)["config"])
                if config.category != category:
                    raise ValueError(f"{path} was trained on {config.category!r}, not {category!r}")
                runs.append(runner.Run(f"{category}_network_seed{seed}", key, config, task="score",
                                       options={"checkpoint": str(path), "checkpoint_sha256": runner.file_sha256(path),
                                                "baseline": True, "refine": refine}))
            else:
                config = scale.config(category, seed)
                runs.append(runner.Run(f"{category}_network_seed{seed}", key, config,
                                       options={"baseline": True, "refine": refine}))
            if args.without_fitting:
                continue
            fit = scale.fit_config(config.model_config.num_cuboids, seed)
            runs.append(runner.Run(f"{category}_fitting_seed{seed}", key, config, task="fit",
                                   options={"fit": dataclasses.asdict(fit), "method": "per-shape fitting"}))
    return runs


def report(records: list[dict], scale: runner.Scale, args: argparse.Namespace) -> tuple[list[dict], str]:
    summary = runner.summarize(runner.result_rows(records), ("category", "method"), ("cd", "miou", "nc", "n_ac"))
    rows = []
    for row in summary:
        ours = row["method"] == "network"
        row["paper_cd"] = PAPER["cd"]["Ours"][row["category"]] if ours else None
        row["paper_miou_percent"] = PAPER["miou"]["Ours"].get(row["category"]) if ours else None
        rows.append([row["category"], row["method"], runner.mean_sd(row, "cd", 1000), runner.paper_value(row["paper_cd"]),
                     runner.mean_sd(row, "miou", 100, 1), runner.paper_value(row["paper_miou_percent"], 1),
                     runner.mean_sd(row, "nc"), runner.mean_sd(row, "n_ac", 1, 2)])
    headers = ["category", "method", "CD x1000 (ours)", "CD (paper's net)", "mIoU % (ours)", "mIoU (paper's net)",
               "NC", "N_AC"]
    others = [[name, *(runner.paper_value(PAPER["cd"].get(name, {}).get(c)) for c in CATEGORIES),
               *(runner.paper_value(PAPER["miou"].get(name, {}).get(c), 1) for c in CATEGORIES[:3])]
              for name in ("VP", "HA", "SQ", "BAE-Net", "BSP-Net", "Ours")]
    paper_headers = ["paper", *(f"CD {c}" for c in CATEGORIES), *(f"mIoU {c}" for c in CATEGORIES[:3])]
    source = "released checkpoints in " + args.checkpoints if args.checkpoints else "trained at course scale"
    return summary, "\n".join([
        f"Tables 1-2: the network ({source}) vs the k-means boxes and per-shape fitting",
        runner.text_table(headers, rows), runner.CD_CONVENTION,
        "mIoU: label transfer of Sec. 4.2 (part labels of each cuboid index from 20 % of the test split, scored on "
        "the other 80 %). The per-shape methods number cuboids independently per shape, so this transfer cannot "
        "work for them. NC: normal consistency (1 = perfect).",
        "", f"The paper's numbers for all its methods ({PAPER['source']}):", runner.text_table(paper_headers, others),
    ])


def notes(scale: runner.Scale, args: argparse.Namespace) -> list[str]:
    lines = ["k-means boxes: K = the network's N_AC rounded, per category; per-shape fitting: M of the category, "
             "cuboidlib.fitting.FitConfig defaults (300 Adam steps, averaged compactness with lambda_1 = 0.1)."]
    if args.checkpoints:
        lines.append(f"network: the released checkpoints in {args.checkpoints}, trained with their own settings (each "
                     "run's config); the training settings above do not apply to them.")
    return lines


EXPERIMENT = command_line.Experiment(
    name="table1_2_comparison",
    title="Tables 1-2 at course scale: network vs k-means boxes vs per-shape fitting on four categories "
          "(Chamfer distance, mIoU)",
    description=__doc__,
    paper=PAPER,
    default_steps=1800,
    default_seeds=1,
    build_runs=build_runs,
    report=report,
    add_arguments=add_arguments,
    notes=notes,
)

if __name__ == "__main__":
    raise SystemExit(command_line.main(EXPERIMENT))
