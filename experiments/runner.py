"""The shared machinery of the experiment scripts: one script per table (or figure) of the paper's Sec. 4.

Every script in ``experiments/`` describes its runs (which configurations, which seeds) and its
table; this module does everything else, the same way for all of them:

* **Course scale** (:func:`course_config`): what "at course scale" means, in one place. It is the
  configuration of the committed checkpoints (``data_samples/checkpoints/configs/*.json``):
  256 procedural shapes per category (:func:`cuboidlib.shapes.make_collection`, split 70/10/20 %),
  1024 points per shape, the small network (:meth:`cuboidlib.model.ModelConfig.small`) with the
  paper's M per category (airplane 20, chair 16, table 14, animal 16, Sec. 4.1), Adam with
  learning rate 2e-3, one torch thread per run, and the paper's loss weights except
  lambda_1 = 0.02 on the compactness loss in the **averaged** form of the authors' code,
  (mean_m sqrt(w_m + eps))^2 = Eq. (6) / M^2 (``LossConfig(compactness_average=True)``), and
  the existence target of the authors' code (more than 24 allocated points, 8 for animals, ``existence_min_points``);
  :func:`compactness_scale.compactness_note` prints why the literal sum of Eq. (6) collapses at this scale. The
  experiments train with batch 8 (:data:`EXPERIMENT_BATCH_SIZE`; the checkpoints: 16), which halves
  the time per step while the cuboids start to exist at the same step (near step 350 either way).
  The model is selected on the validation split (``best.pt``) and scored on the test split.
* **The 15-minute recipe's scale** (``--recipe 15min``, in the scripts whose :class:`Experiment` offers it):
  the two stages of ``data_samples/checkpoints/configs/15min/`` (1000 shapes, batch 16), the first stopped
  after :data:`FIFTEEN_MINUTE_STEPS` steps instead of 9 minutes, one thread per run (:func:`recipe_configs`);
  the second stage's selected weights are scored. Results go to ``<name>_15min.*``.
* **Quick scale** (``--quick``): a tiny network, 12 shapes, an eighth of the points (at least 32),
  2 steps, one seed: every script runs end to end in seconds (for tests; the numbers mean nothing).
* **Input noise** (:func:`cuboidlib.dataset.add_noise`, Table 4): seeded isotropic Gaussian jitter of the
  positions.
* **Running** (:func:`run_all`): independent runs go to ``--jobs`` worker processes (default 2),
  each with one torch thread, longest runs first; a run that fails is recorded with its error and
  the others go on.
* **Scoring** (:func:`score_network`): :func:`cuboidlib.evaluation.score_cuboids` on the test split
  (Chamfer distance, normal consistency, mIoU by label transfer, N_AC), optionally against the
  clean shapes (noise), a denser sampling of the same shapes (point density), with the k-means
  baseline (:func:`cuboidlib.evaluation.evaluate_baseline`), or with a nearest-cuboid segmentation
  for the variants without a segmentation branch (Table 3); per-shape fitting
  (:mod:`cuboidlib.fitting`) is scored the same way.
* **Results** (:mod:`summaries`, :func:`write_results`): ``experiments/results/<name>.json`` with the command, the
  git commit, the machine, the wall time, the settings, the config and the metrics of every run
  and the summary table (mean and spread over seeds) with the paper's numbers beside ours, and
  ``<name>.csv`` with the summary table. ``--quick`` results are written as ``<name>_quick.*``.

A script is a :class:`command_line.Experiment`; ``command_line.main(experiment)`` parses the common command line
(``--quick --steps --shapes --seeds --jobs --out --runs-dir --plan``), prints the plan with its
estimated time, runs, prints the table and writes the results.

Why one file: a run's description (:class:`Run`), how it is executed and scored, and its time estimate
are read together when a script is written; the command line is in :mod:`command_line`, the summaries and
result files in :mod:`summaries`, the data, noise and recipes in the library.
"""

from __future__ import annotations

import hashlib
import json
import math
import multiprocessing
import os
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

try:
    import fcntl  # POSIX file locks; without them (Windows) scripts sharing trainings must not run side by side
except ImportError:  # pragma: no cover
    fcntl = None

import torch

from cuboidlib.abstraction import REFINE_LR, AbstractionBatch
from cuboidlib.checkpoint import load_model
from cuboidlib.dataset import UNVERSIONED_GENERATOR, ShapeSet, load_splits
from cuboidlib.dataset import add_noise, noisy_splits
from cuboidlib.distance import nearest_surface_distance, point_to_cuboid_distance
from cuboidlib.evaluation import evaluate_baseline, predict_cuboids, score_cuboids
from cuboidlib.files import write_text_atomic
from cuboidlib.fitting import FitConfig, fit_cuboids
from cuboidlib.model import CuboidAbstractionNet
from cuboidlib.train import FINETUNE_DIR, Trainer
from cuboidlib.train_config import TrainConfig
from cuboidlib.train_config import course_config as train_course_config
from summaries import (  # noqa: F401 - the scripts use them through this module
    CD_CONVENTION,
    machine,
    mean_sd,
    paper_value,
    result_rows,
    summarize,
    text_table,
    write_results,
)

__all__ = [
    "REPO",
    "COURSE_NUM_CUBOIDS",
    "COURSE_SCALE",
    "QUICK_MODEL",
    "DATA_NOTE",
    "Scale",
    "course_config",
    "add_noise",
    "noisy_splits",
    "Run",
    "nearest_cuboid_segmentation",
    "thickness",
    "draw_abstractions",
    "score_network",
    "execute",
    "run_all",
    "estimate_seconds",
    "estimate_makespan",
    "result_rows",
    "summarize",
    "mean_sd",
    "paper_value",
    "text_table",
    "CD_CONVENTION",
    "machine",
    "write_results",
]

REPO = Path(__file__).resolve().parents[1]
RESULTS_DIR = REPO / "experiments" / "results"
RUNS_DIR = REPO / "runs" / "experiments"

#: The paper's number of cuboids M per category (Sec. 4.1); the committed checkpoints use the same.
COURSE_NUM_CUBOIDS = {"airplane": 20, "chair": 16, "table": 14, "animal": 16}

#: What "course scale" means, stated in every results file.
COURSE_SCALE = {
    "shapes_per_category": 256,
    "split": "70 % train / 10 % validation / 20 % test (seed 0); model selected on the validation loss",
    "points_per_shape": 1024,
    "model": "ModelConfig.small() (k = 16, EdgeConv 32 + 32, global 256, latent 64) with the paper's M and the "
             "affinity of Eq. (2) divided by sqrt(32), as in the authors' code",
    "optimiser": "Adam, lr 2e-3 (the paper: 6e-4, too slow for minutes of training), batch 8 (the checkpoints: "
                 "16; the paper: 32), one torch thread per run",
    "loss": "paper weights (lambda_2 0.01, lambda_3 6e-6, sigma_s 0.05) with the compactness loss in the averaged "
            "form of the authors' code, (mean_m sqrt(w_m + 0.01))^2 = Eq. (6) / M^2, and lambda_1 = 0.02 (0.001 for "
            "airplanes); the "
            "existence target of the authors' code, more than 24 points allocated (8 for animals, whose tails hold "
            "about 26 points; the paper's 5 % of the points would rule out every chair leg, about 4 % each); cuboid centres at the allocation-weighted centroid of "
            "their points, as in the authors' code",
    "same_as": "data_samples/checkpoints/configs/<category>.json (the committed checkpoints) except the number of "
               "shapes (the checkpoints: 1000) and the batch size",
}

#: Batch size of the experiment runs: half the checkpoints' 16 halves the time per step; with both, the
#: first cuboids pass the existence threshold near step 350 (column n_existing of the chair checkpoint's
#: training log, and of ``cuboidlib train --config data_samples/checkpoints/configs/chair.json --batch-size 8
#: --max-steps 600 --set max_minutes=null --out runs/batch8``), so a 600-step run ends with a trained
#: existence branch.
EXPERIMENT_BATCH_SIZE = 8

#: The tiny network of --quick runs (same structure, a step takes milliseconds).
QUICK_MODEL = dict(k=8, edge_dims=[8, 8], global_dim=16, latent_dim=8, cuboid_code_dim=8,
                   cuboid_feature_dims=[16, 16], exist_hidden_dim=8, seg_dim=8)

DATA_NOTE = (
    "Data and scale differ from the paper: ours are procedural shapes (cuboidlib.shapes) at course scale "
    "(256 shapes per category, 1024 points, the small network, a few hundred to a few thousand steps of "
    "batch 8 or 16 on a CPU); the paper trains the full network on ShapeNet (thousands of shapes, 1000 epochs "
    "of batch 32 on a GPU) and scores it on 4096 points. The paper's Chamfer convention is not documented (its "
    "numbers are scaled by an unknown factor): compare the trends between cells, not the absolute values."
)


# ----------------------------------------------------------------------------------------------
# Configurations
# ----------------------------------------------------------------------------------------------


def course_config(category: str, steps: int, **changes) -> TrainConfig:
    """The course-scale :class:`~cuboidlib.train_config.TrainConfig` of ``category`` trained for ``steps`` steps.

    The committed network's recipe (:func:`cuboidlib.train_config.course_config`, read from
    ``data_samples/checkpoints/configs/<category>.json``), so experiments and checkpoints cannot drift
    apart. The step budget replaces the file's (no time budget: runs are repeatable);
    validation (model selection) every 100 steps and at the end; one checkpoint at the end.
    ``changes`` replace fields (``model`` / ``loss`` dicts are merged, see ``TrainConfig.replace``).
    """
    if category not in COURSE_NUM_CUBOIDS:
        raise ValueError(f"category must be one of {tuple(COURSE_NUM_CUBOIDS)}, got {category!r}")
    base = train_course_config(category, max_steps=steps, max_minutes=None, checkpoint_every=steps,
                               validate_every=min(100, steps))
    return base.replace(**changes) if changes else base


#: ``--recipe 15min``: the scale of the 15-minute recipe (``data_samples/checkpoints/configs/15min/``).
FIFTEEN_MINUTES = "15min"
#: First-stage steps of a ``--recipe 15min`` run: about what the recipe's 9 minutes give on a quiet machine
#: (2367-2651 steps in the cards of ``experiments/fifteen/results/quiet/`` and ``airplane_15min.json``).
FIFTEEN_MINUTE_STEPS = 2500
#: The 15-minute recipe's number of shapes per category (its configs').
FIFTEEN_MINUTE_SHAPES = 1000
#: The 15-minute recipe that ``--recipe 15min`` trains: a copy of ``data_samples/checkpoints/configs/15min/``
#: as it was when the 15-minute ablations began, so that retrained networks cannot change runs in progress.
RECIPE_DIR = Path(__file__).with_name("recipes") / FIFTEEN_MINUTES


def recipe_configs(category: str, steps: int, **changes) -> tuple[TrainConfig, TrainConfig]:
    """The two stages of the 15-minute recipe of ``category``, with ``steps`` first-stage steps instead of 9 minutes.

    Both stages run on one thread and stop on their step counts (no time budget: runs are repeatable; a learning
    rate that falls over the recipe's minutes falls over the steps instead); the second stage keeps the recipe's
    500 steps. ``changes`` apply to both stages (``model`` / ``loss`` dicts are
    merged into each stage's own). The second stage's ``init_from`` is set where it runs (:func:`execute`).
    """
    if category not in COURSE_NUM_CUBOIDS:
        raise ValueError(f"category must be one of {tuple(COURSE_NUM_CUBOIDS)}, got {category!r}")
    folder = RECIPE_DIR
    first = TrainConfig.load_json(folder / f"{category}.json")
    schedule = "cosine" if first.lr_schedule == "cosine_minutes" else first.lr_schedule  # falls over the steps
    first = first.replace(max_steps=steps, max_minutes=None, lr_schedule=schedule, num_threads=1,
                          checkpoint_every=steps, validate_every=min(100, steps))
    second = TrainConfig.load_json(folder / "finetune" / f"{category}.json")
    second = second.replace(max_minutes=None, num_threads=1, init_from=None,
                            checkpoint_every=second.max_steps)
    return tuple(c.replace(**changes) if changes else c for c in (first, second))


@dataclass(frozen=True)
class Scale:
    """The scale of one invocation: course scale (default) or ``--quick``, with the command-line overrides.

    steps: training steps of every run (of its first stage, at the 15-minute recipe's scale); n_shapes: shapes
    per collection; seeds: training seeds; batch_size: shapes per training step (None: the course config's 16;
    quick: 4); recipe: "course" (one stage, :func:`course_config`) or "15min" (the two stages of
    ``configs/15min/``, :func:`recipe_configs`).
    """

    quick: bool
    steps: int
    n_shapes: int
    seeds: tuple[int, ...]
    batch_size: int | None = None
    recipe: str = "course"

    def points(self, n_points: int) -> int:
        """Points per shape: ``n_points`` at course scale, an eighth of it (at least 32) in quick runs."""
        return max(32, n_points // 8) if self.quick else n_points

    def _changes(self, changes: dict) -> dict:
        """``changes`` with this scale's batch size, points and (quick) tiny network filled in."""
        changes = dict(changes)
        model = dict(changes.pop("model", {}))
        if self.batch_size is not None:
            changes.setdefault("batch_size", self.batch_size)
        if self.quick:
            model = {**QUICK_MODEL, **model}
            changes.setdefault("batch_size", 4)
        changes["n_points"] = self.points(changes.get("n_points", COURSE_SCALE["points_per_shape"]))
        return {**changes, "model": model, "n_shapes": self.n_shapes}

    def config(self, category: str, seed: int = 0, **changes) -> TrainConfig:
        """:func:`course_config` at this scale (quick: the tiny network and batch 4), with ``changes``; at the
        15-minute recipe's scale, the first stage of :func:`recipe_configs`."""
        changes = self._changes(changes)
        if self.recipe == FIFTEEN_MINUTES:
            return recipe_configs(category, self.steps, seed=seed, **changes)[0]
        return course_config(category, self.steps, seed=seed, **changes)

    def finetune_config(self, category: str, seed: int = 0, **changes) -> TrainConfig | None:
        """The second stage of a run made by :meth:`config` with the same arguments: None at course scale, the
        15-minute recipe's second stage (:func:`recipe_configs`) with the same ``changes`` otherwise (quick: 2 steps)."""
        if self.recipe != FIFTEEN_MINUTES:
            return None
        changes = self._changes(changes)
        if self.quick:
            changes.setdefault("max_steps", 2)
        return recipe_configs(category, self.steps, seed=seed, **changes)[1]

    def fit_config(self, num_cuboids: int, seed: int = 0) -> FitConfig:
        """Per-shape fitting (:class:`~cuboidlib.fitting.FitConfig` defaults: 300 Adam steps, Eq. (4) + the
        averaged Eq. (6) with lambda_1 = 0.1) with M cuboids; 5 steps in quick runs."""
        return FitConfig(num_cuboids=num_cuboids, seed=seed, **({"steps": 5} if self.quick else {}))


# ----------------------------------------------------------------------------------------------
# Runs
# ----------------------------------------------------------------------------------------------

TASKS = ("train", "score", "fit")


@dataclass
class Run:
    """One independent unit of work.

    name: unique, file-system safe (its folder under the runs directory).
    key: the run's coordinates in the table, JSON values (e.g. {"lambda_1": 0.1, "seed": 0}); the
      summary averages over ``seed``.
    config: the :class:`~cuboidlib.train_config.TrainConfig` (for "fit" and "score" tasks: the data it uses).
    task: "train" (train, select on validation, score on test), "score" (score the checkpoint
      ``options["checkpoint"]``) or "fit" (per-shape fitting of every test shape, ``options["fit"]``
      a FitConfig dict).
    options: scoring options, JSON values: ``method`` (name in the table, default "network"),
      ``sigma_n`` (input noise at train and test time; also scored against the clean shapes),
      ``segmentation`` ("normal" / "nearest_surface": segment by the nearest existing cuboid under
      that distance instead of W), ``reference_points`` (also score against this many points of the
      same test shapes), ``baseline`` (also score the k-means boxes with K = round(N_AC)), ``refine``
      (also score the network's result refined by this many steps of the per-shape fit started from it),
      ``checkpoint_sha256`` (of a "score" task: the checkpoint's content, so that ``--resume`` scores a
      replaced checkpoint anew; :func:`file_sha256`).
    finetune: a "train" run's second stage (:meth:`Scale.finetune_config`), trained from the first stage's
      selected weights in the training folder's ``finetune/``; its selected weights are the ones scored.
    """

    name: str
    key: dict
    config: TrainConfig
    task: str = "train"
    options: dict = field(default_factory=dict)
    finetune: TrainConfig | None = None

    def __post_init__(self) -> None:
        if self.task not in TASKS:
            raise ValueError(f"task must be one of {TASKS}, got {self.task!r}")
        if self.finetune is not None and self.task != "train":
            raise ValueError(f"a second stage (finetune) belongs to a 'train' run, not to a {self.task!r} run")
        if not self.name or any(c in self.name for c in "/\\ "):
            raise ValueError(f"run name must be non-empty without '/', '\\' or spaces, got {self.name!r}")


def _test_shapes(config: TrainConfig, options: dict) -> tuple[ShapeSet, ShapeSet]:
    """(the test split the method sees, the clean test split)."""
    splits = load_splits(config)
    seen = noisy_splits(splits, options["sigma_n"], config.data_seed) if options.get("sigma_n") else splits
    return seen["test"], splits["test"]


def nearest_cuboid_segmentation(shapes: ShapeSet, pred: AbstractionBatch, distance: str) -> torch.Tensor:
    """(S, N) segment of every point = its nearest EXISTING cuboid under ``distance`` ("normal": Eq. (5)
    with sigma_s = 0; "nearest_surface"), the allocation of the variants without a segmentation branch
    (P2C-Dis, Chamfer-Dis of Table 3)."""
    cuboids = (pred.cuboids.centers, pred.cuboids.quaternions, pred.cuboids.half_sizes)
    if distance == "normal":
        d = point_to_cuboid_distance(shapes.points, shapes.normals, *cuboids, sigma_s=0.0)
    elif distance == "nearest_surface":
        d = nearest_surface_distance(shapes.points, *cuboids)
    else:
        raise ValueError(f"segmentation distance must be 'normal' or 'nearest_surface', got {distance!r}")
    return d.masked_fill(~pred.cuboids.exists[:, None, :], math.inf).argmin(dim=-1)


def thickness(pred: AbstractionBatch) -> float:
    """How thick the existing cuboids are for their size: the smallest of a cuboid's three half sizes over its
    largest, the median over the existing cuboids of a shape, averaged over shapes. Larger is thicker: 1 for
    cubes, near 0 for the thin stacked plates of the paper's Fig. 9. (Results written before the rename call it
    ``flatness``; :func:`summaries.result_rows` reads either name.)"""
    sizes = pred.cuboids.half_sizes.sort(dim=-1).values
    ratio = sizes[..., 0] / sizes[..., 2].clamp_min(1e-12)
    return float(torch.stack([ratio[i][pred.cuboids.exists[i]].median() if pred.cuboids.exists[i].any()
                              else ratio.new_tensor(float("nan")) for i in range(len(ratio))]).nanmean())


def _metrics(scores: dict) -> dict:
    """The flat numbers of a :func:`score_cuboids` result: cd, nc (from the points), nc_both (both ways), miou, n_ac."""
    return {"cd": scores["chamfer"][0]["value"], "nc": scores["normal_consistency"],
            "nc_both": scores["normal_consistency_both"], "miou": scores["miou"], "n_ac": scores["n_ac"]}


def score_network(model: CuboidAbstractionNet, config: TrainConfig, options: dict) -> list[dict]:
    """Score a trained network on the test split of ``config`` (see :class:`Run` for ``options``).

    Returns result dicts ``{"method", "metrics", "scores"}``: the network's, and the k-means
    baseline's with ``options["baseline"]``. The network's metrics hold cd, nc, miou, n_ac (against
    the input it saw), cd_clean / nc_clean (noise: against the clean test shapes) and cd_reference /
    nc_reference (against ``reference_points`` points of the same shapes).
    """
    test, clean = _test_shapes(config, options)
    centroids = config.loss_config.centers_from_allocation
    pred, fallback = predict_cuboids(model, test, centers_from_allocation=centroids)
    if options.get("segmentation"):
        pred.labels = nearest_cuboid_segmentation(test, pred, options["segmentation"])
    scores = score_cuboids(test, pred)
    scores.update(num_cuboids=pred.num_segments, shapes_without_existing_cuboid=fallback)
    metrics = _metrics(scores)
    metrics["thickness"] = thickness(pred)
    if options.get("sigma_n") is not None:
        scores["clean"] = score_cuboids(ShapeSet(clean.points, clean.normals, None, clean.indices), pred)
        metrics.update(cd_clean=scores["clean"]["chamfer"][0]["value"], nc_clean=scores["clean"]["normal_consistency"],
                       nc_both_clean=scores["clean"]["normal_consistency_both"])
    if options.get("reference_points"):
        ref = load_splits(config.replace(n_points=options["reference_points"]))["test"]
        scores["reference"] = score_cuboids(ShapeSet(ref.points, ref.normals, None, ref.indices), pred)
        metrics.update(cd_reference=scores["reference"]["chamfer"][0]["value"],
                       nc_reference=scores["reference"]["normal_consistency"],
                       nc_both_reference=scores["reference"]["normal_consistency_both"])
    results = [{"method": options.get("method", "network"), "metrics": metrics, "scores": scores}]
    if options.get("refine"):
        results.append(_refine_and_score(test, pred, options["refine"]))
    if options.get("baseline"):
        boxes = max(1, round(metrics["n_ac"]))
        base = evaluate_baseline(test, boxes)
        results.append({"method": "k-means boxes", "metrics": {**_metrics(base), "boxes": boxes}, "scores": base})
    return results


def _refine_and_score(test: ShapeSet, pred: AbstractionBatch, steps: int) -> dict:
    """The network's result refined by ``steps`` steps of the per-shape fit started from it (the cuboids and
    allocation of ``pred``, :func:`cuboidlib.fitting.fit_cuboids` with ``start``), scored like the network."""
    fit = fit_cuboids(test.points, test.normals, FitConfig(steps=steps, lr=REFINE_LR, normalize=False), start=pred)
    scores = score_cuboids(test, fit)
    scores.update(num_cuboids=fit.num_segments, refine_steps=steps, refine_seconds=round(fit.elapsed_s, 1),
                  segmentation_kept=float((fit.labels == pred.labels).double().mean()))
    return {"method": "network + refinement", "metrics": _metrics(scores), "scores": scores}


def draw_abstractions(records: list[dict], scale: "Scale", stem: Path, row_label: Callable[[dict], str],
                      title: str, shapes: int = 3) -> list[Path]:
    """A figure of the trained networks side by side: one row per finished run of the first seed (in the
    order of ``records``), one column per test shape (the first ``shapes`` of the test split): the points
    coloured by their segment (the run's own segmentation rule, as scored) and the existing cuboids. Each
    panel is titled ``row_label(record)`` and that shape's number of cuboids. Writes ``stem``.png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cuboidlib.viz import plot_cuboids_matplotlib_grid

    shown = [r for r in records if r["status"] == "ok" and r["key"].get("seed", 0) == scale.seeds[0]]
    if not shown:
        return []
    items, titles = [], []
    for record in shown:
        config = TrainConfig.from_dict(record["config"])
        test, _ = _test_shapes(config, record["options"])
        test = test.subset(torch.arange(min(shapes, len(test))))
        model, _ = load_model(record["checkpoint"])
        pred, _ = predict_cuboids(model, test, centers_from_allocation=config.loss_config.centers_from_allocation)
        if record["options"].get("segmentation"):
            pred.labels = nearest_cuboid_segmentation(test, pred, record["options"]["segmentation"])
        for i in range(len(test)):
            items.append((test.points[i], pred.labels[i], pred.cuboids, None, i))
            titles.append(f"{row_label(record)}\n{config.category} {int(test.indices[i])}: {int(pred.cuboids.exists[i].sum())} cuboids")
    fig = plot_cuboids_matplotlib_grid(items, titles, cols=min(shapes, len(items)), panel_size=3.0,
                                       max_points=1024, point_size=2.0)
    fig.suptitle(title + (" (QUICK run: meaningless)" if scale.quick else ""), fontsize=10,
                 y=1 + 0.3 / fig.get_figheight())  # above the panels' two-line titles; the saved figure grows to fit
    path = stem.with_suffix(".png")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return [path]


def _fit_and_score(config: TrainConfig, options: dict) -> list[dict]:
    """Per-shape fitting (:func:`cuboidlib.fitting.fit_cuboids`) of every test shape, scored like the network."""
    test, _ = _test_shapes(config, options)
    fit_config = FitConfig(**options["fit"])
    fit = fit_cuboids(test.points, test.normals, fit_config)
    scores = score_cuboids(test, fit)
    scores.update(num_cuboids=fit.num_segments, fit_seconds=round(fit.elapsed_s, 1),
                  converged=int(fit.converged.sum()))
    return [{"method": options.get("method", "per-shape fitting"), "metrics": _metrics(scores), "scores": scores}]


#: TrainConfig fields added after trainings were first shared; left out of :func:`training_key` while they keep
#: their defaults (``generator_version``: 1, what a config without it means), so that the trainings made before
#: them keep their keys.
KEY_NEUTRAL_FIELDS = ("temperature_start", "temperature_steps", "selection", "generator_version")
#: The same for fields of the model section.
KEY_NEUTRAL_MODEL_FIELDS = ("input_normals",)


def _without_neutral_defaults(config: dict) -> dict:
    """A config dict without the :data:`KEY_NEUTRAL_FIELDS` (and :data:`KEY_NEUTRAL_MODEL_FIELDS` of its
    model section) that are absent or at their defaults."""
    defaults = {**TrainConfig().to_dict(), "generator_version": UNVERSIONED_GENERATOR}  # a config without it: 1
    out = {k: v for k, v in config.items() if k not in KEY_NEUTRAL_FIELDS or v != defaults[k]}
    if isinstance(out.get("model"), dict):
        model_defaults = defaults["model"]
        out["model"] = {k: v for k, v in out["model"].items()
                        if k not in KEY_NEUTRAL_MODEL_FIELDS or v != model_defaults[k]}
    return out


def training_key(run: Run) -> str:
    """What a "train" run's weights depend on, as a short hash: its configuration and its input noise.

    Two runs with the same key train the same network (training is deterministic), so one training serves
    both; they may still differ in how they are scored (``options``)."""
    identity = [_without_neutral_defaults(run.config.to_dict()), run.options.get("sigma_n") or 0.0]
    if run.finetune is not None:  # absent for one-stage runs, so that their keys stay as they were
        identity.append(_without_neutral_defaults(run.finetune.to_dict()))
    identity = json.dumps(identity, sort_keys=True)
    return hashlib.sha256(identity.encode()).hexdigest()[:16]


#: The folder of the trainings, one per :func:`training_key`: inside the invocation's folder, or with ``--resume``
#: directly in ``--runs-dir``, shared by every script.
TRAINED_DIR = "trained"
#: Each finished training leaves its summary here, in its training folder, so that it is never repeated.
TRAINING_FILE = "training.json"


#: What a first stage's summary says (:func:`_train`), also in the summary of a two-stage training.
FIRST_STAGE_FIELDS = ("steps", "best_step", "stopped", "best_val_loss", "seconds")


def _train(run: Run, train_dir: Path, store: Path | None = None) -> dict:
    """Train ``run`` in ``train_dir``, or read back the training finished there earlier; its summary.

    With ``store``, the folder of shared trainings that holds ``train_dir``, a two-stage run's first stage is
    the training of that first stage alone, ``store / training_key(first stage)``: second stages that start
    from the same first stage share it, across scripts and invocations (``first_stage_reused`` in the summary).
    A training folder that already holds its own first stage (one begun before first stages were shared)
    finishes there.

    A lock file keeps two processes (two scripts run side by side) from training in one folder at once: the
    second waits, then reads the first one's training back."""
    first_stage = None
    if (store is not None and run.finetune is not None and not (train_dir / TRAINING_FILE).is_file()
            and not (train_dir / "last.pt").is_file()):
        first = replace(run, finetune=None)
        first_dir = store / training_key(first)
        first_stage = (first_dir, _train(first, first_dir))
    train_dir.mkdir(parents=True, exist_ok=True)
    with open(train_dir / ".lock", "w") as lock:
        if fcntl is not None:
            fcntl.flock(lock, fcntl.LOCK_EX)
        return _train_locked(run, train_dir, first_stage)


def _train_locked(run: Run, train_dir: Path, first_stage: tuple[Path, dict] | None) -> dict:
    done = train_dir / TRAINING_FILE
    if done.is_file():
        return {**json.loads(done.read_text()), "reused": True}
    splits = load_splits(run.config)
    if run.options.get("sigma_n"):
        splits = noisy_splits(splits, run.options["sigma_n"], run.config.data_seed)
    # an interrupted earlier attempt continues from its last checkpoint; the trainer refuses it if the
    # configuration differs
    second_dir = train_dir / FINETUNE_DIR
    second_begun = run.finetune is not None and (second_dir / "last.pt").is_file()
    summary, first_dir = {}, train_dir
    if first_stage is not None:
        first_dir, first_summary = first_stage
        summary = {k: first_summary[k] for k in FIRST_STAGE_FIELDS}
        summary["first_stage_reused"] = bool(first_summary.get("reused"))
    elif not second_begun:
        resume = (train_dir / "last.pt").is_file()
        trained = Trainer(run.config, train_dir, quiet=True, splits=splits, resume=resume).run()
        summary = {"steps": trained.step, "best_step": trained.best_step, "stopped": trained.stopped,
                   "best_val_loss": trained.best_val, "seconds": round(trained.seconds, 1)}
    if run.finetune is not None:
        second = run.finetune.replace(init_from=str(first_dir / "best.pt"))
        tuned = Trainer(second, second_dir, quiet=True, splits=splits, resume=second_begun).run()
        summary.update(finetune_steps=tuned.step, finetune_best_step=tuned.best_step,
                       finetune_best_val_loss=tuned.best_val, finetune_seconds=round(tuned.seconds, 1))
    summary["trained_by"] = run.name
    write_text_atomic(done, json.dumps(summary))
    return summary


def _selected_weights(run: Run, train_dir: Path) -> Path:
    """The checkpoint a "train" run scores: its (last) stage's selected weights."""
    return train_dir / (FINETUNE_DIR if run.finetune is not None else "") / "best.pt"


def execute(run: Run, run_dir: str | os.PathLike, trained_dir: str | os.PathLike | None = None) -> dict:
    """Do one :class:`Run` in this process with one torch thread; return its record (JSON types).

    A "train" run trains in ``trained_dir / training_key(run)`` when ``trained_dir`` is given (a training
    finished there by any run with the same key is read back, not repeated; a two-stage run's first stage is a
    training of its own there, :func:`_train`), else in ``run_dir``.
    Never raises for a failing run: the record then has ``status`` "failed" and the ``error``.
    """
    start, cpu_start = time.perf_counter(), time.process_time()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    record = {"name": run.name, "key": run.key, "task": run.task, "options": run.options,
              "config": run.config.to_dict(), "run_dir": str(run_dir)}
    if run.finetune is not None:
        record["finetune_config"] = run.finetune.to_dict()
    try:
        if run.task == "fit":
            record["results"] = _fit_and_score(run.config, run.options)
        else:
            if run.task == "train":
                store = Path(trained_dir) if trained_dir is not None else None
                train_dir = store / training_key(run) if store is not None else Path(run_dir)
                record["training"] = _train(run, train_dir, store)
                checkpoint = _selected_weights(run, train_dir)
            else:
                checkpoint = Path(run.options["checkpoint"])
            record["checkpoint"] = str(checkpoint)
            model, _ = load_model(checkpoint)
            record["results"] = score_network(model, run.config, run.options)
        record["status"] = "ok"
    except Exception as exc:  # noqa: BLE001 - recorded; the other runs go on
        record.update(status="failed", error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc())
    finally:
        torch.set_num_threads(threads)
    record["seconds"] = round(time.perf_counter() - start, 1)
    record["cpu_seconds"] = round(time.process_time() - cpu_start, 1)  # = wall time on a quiet machine (1 thread)
    if record["status"] == "ok":
        _write_record(Path(run_dir), record)
    return record


#: Each finished run leaves its record here, in its run folder, so that ``--resume`` can skip it.
RECORD_FILE = "record.json"


def _write_record(run_dir: Path, record: dict) -> None:
    write_text_atomic(run_dir / RECORD_FILE, json.dumps(record))  # an interrupted write leaves no half record


def file_sha256(path: str | os.PathLike) -> str:
    """The SHA-256 of a file's bytes (hex), e.g. of a checkpoint that a "score" run reads."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def finished_record(run: Run, run_dir: Path) -> dict | None:
    """The record a finished earlier attempt of ``run`` left in ``run_dir``, or None (none, failed, or made
    with another configuration or options; a record made before a :data:`KEY_NEUTRAL_FIELDS` field existed
    matches a run that keeps it at its default)."""
    try:
        record = json.loads((run_dir / RECORD_FILE).read_text())
    except (OSError, ValueError):
        return None
    same = (record.get("status") == "ok" and record.get("name") == run.name and record.get("task") == run.task
            and _without_neutral_defaults(record.get("config") or {}) == _without_neutral_defaults(run.config.to_dict())
            and json.loads(json.dumps(run.options)) == record.get("options")
            and (None if run.finetune is None else _without_neutral_defaults(run.finetune.to_dict()))
            == (None if record.get("finetune_config") is None else _without_neutral_defaults(record["finetune_config"])))
    return record if same else None


# ----------------------------------------------------------------------------------------------
# Time estimates (one torch thread, small network, batch 16)
# ----------------------------------------------------------------------------------------------

#: Seconds per training step of the small network (M = 16, batch 16, one thread, Eq. (5) loss) by points
#: per shape, measured as CPU time of a single process (wall time on a quiet machine).
STEP_SECONDS = {256: 0.124, 1024: 0.552, 4096: 3.78}
#: Extra cost of the Chamfer-Dis loss (sampling 1024 points on the cuboids, bidirectional Chamfer).
CHAMFER_FACTOR = 1.4
#: Seconds per run outside the steps: start-up, data, validations, checkpoints, scoring the test split.
RUN_OVERHEAD = 25.0
#: Per-shape fitting: seconds per shape and per Adam step at 1024 points and M = 16 (one thread).
FIT_SECONDS = 0.0028


def _step_seconds(n_points: int) -> float:
    """Log-log interpolation (and extrapolation) of :data:`STEP_SECONDS`."""
    xs = sorted(STEP_SECONDS)
    lx = math.log(n_points)
    i = 0 if n_points <= xs[1] else 1
    x0, x1 = xs[i], xs[i + 1]
    t = (lx - math.log(x0)) / (math.log(x1) - math.log(x0))
    return math.exp((1 - t) * math.log(STEP_SECONDS[x0]) + t * math.log(STEP_SECONDS[x1]))


def estimate_seconds(run: Run) -> float:
    """Estimated wall time of ``run`` on a quiet machine (one thread; see :data:`STEP_SECONDS`)."""
    c = run.config
    m = c.model_config.num_cuboids
    if run.task == "fit":
        shapes = round(c.n_shapes * c.split_fractions[2])
        steps = run.options["fit"].get("steps", FitConfig().steps)
        fit_m = run.options["fit"].get("num_cuboids", 16)
        return RUN_OVERHEAD + FIT_SECONDS * shapes * steps * (c.n_points / 1024) * (fit_m / 16)
    if run.task == "score":
        return RUN_OVERHEAD
    step = _step_seconds(c.n_points) * (c.batch_size / 16) * (1 + 0.01 * (m - 16))
    if c.loss_config.distance == "chamfer":
        step *= CHAMFER_FACTOR
    steps = c.max_steps if c.max_steps is not None else c.epochs * 100
    if run.finetune is not None:
        steps += run.finetune.max_steps
    return RUN_OVERHEAD * max(1.0, c.n_points / 1024) + steps * step


def estimate_makespan(runs: Sequence[Run], jobs: int) -> float:
    """Estimated wall time of :func:`run_all`: longest runs first, each to the least loaded worker."""
    loads = [0.0] * max(1, jobs)
    for t in sorted((estimate_seconds(r) for r in runs), reverse=True):
        loads[loads.index(min(loads))] += t
    return max(loads)


def run_all(runs: Sequence[Run], runs_dir: str | os.PathLike, jobs: int = 2,
            report: Callable[[str], None] = print, trained_dir: str | os.PathLike | None = None) -> list[dict]:
    """Do every run, ``jobs`` at a time in separate processes (``jobs = 1``: in this process), longest
    first; returns the records in the order of ``runs``. ``report`` gets one line per finished run.

    ``trained_dir``: the trainings go there, one folder per :func:`training_key`, and a training finished
    there earlier is read back. Runs that share a key then train once: the first of them trains, the
    others wait for it and only score."""
    names = [r.name for r in runs]
    if len(set(names)) != len(names):
        raise ValueError("run names must be unique")
    runs_dir = Path(runs_dir)
    records: list[dict | None] = [None] * len(runs)

    def done(i: int, record: dict) -> None:
        records[i] = record
        finished = sum(r is not None for r in records)
        report(f"[{finished}/{len(runs)}] {_describe(record)}")

    for i, run in enumerate(runs):  # finished by an earlier, interrupted invocation (--resume)
        earlier = finished_record(run, runs_dir / run.name)
        if earlier is not None:
            earlier["reused"] = True
            done(i, earlier)
    order = sorted((i for i in range(len(runs)) if records[i] is None), key=lambda i: -estimate_seconds(runs[i]))
    waves: list[list[int]] = [order]
    if trained_dir is not None:  # a training shared by several runs: its first run trains, the others wait
        first: dict[str, int] = {}
        for i in order:
            if runs[i].task == "train":
                first.setdefault(_key(runs[i]), i)
        waves = [[i for i in order if first.get(_key(runs[i]), i) == i],
                 [i for i in order if first.get(_key(runs[i]), i) != i]]

    if jobs == 1:
        for wave in waves:
            for i in wave:
                done(i, execute(runs[i], runs_dir / runs[i].name, trained_dir))
        return records
    # Children inherit these before importing torch: one OpenMP / MKL thread each.
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    context = multiprocessing.get_context("spawn")  # no fork of a process whose torch threads are running
    for wave in waves:
        _run_wave(runs, wave, runs_dir, jobs, trained_dir, context, done)
    return records


def _key(run: Run) -> str | None:
    return training_key(run) if run.task == "train" else None


def _run_wave(runs: Sequence[Run], wave: list[int], runs_dir: Path, jobs: int, trained_dir, context,
              done: Callable[[int, dict], None]) -> None:
    """The runs ``wave`` (indices into ``runs``), ``jobs`` at a time in worker processes."""
    if not wave:
        return
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool:
        futures = {pool.submit(execute, runs[i], runs_dir / runs[i].name, trained_dir): i for i in wave}
        for future in as_completed(futures):
            i = futures[future]
            try:
                record = future.result()
            except Exception as exc:  # noqa: BLE001 - a worker process died
                record = {"name": runs[i].name, "key": runs[i].key, "task": runs[i].task, "options": runs[i].options,
                          "config": runs[i].config.to_dict(), "status": "failed",
                          "error": f"worker process failed: {type(exc).__name__}: {exc}"}
            done(i, record)


def _describe(record: dict) -> str:
    """One line about a finished run."""
    key = ", ".join(f"{k} {v}" for k, v in record["key"].items())
    if record["status"] != "ok":
        return f"{record['name']} ({key}): FAILED: {record['error']}"
    parts = []
    for result in record["results"]:
        m = result["metrics"]
        miou = "-" if m["miou"] is None else f"{100 * m['miou']:.1f}"
        parts.append(f"{result['method']}: CD {m['cd']:.5f}, mIoU {miou}, N_AC {m['n_ac']:.2f}")
    steps = f"{record['training']['steps']} steps, " if "training" in record else ""
    return f"{record['name']} ({key}): " + "; ".join(parts) + f" ({steps}{record['seconds']:.0f} s)"
