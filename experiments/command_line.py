"""The command line shared by every experiment script: an :class:`Experiment` and :func:`main`.

A script describes its runs and its table as an :class:`Experiment`; ``main(experiment)`` parses the common
options (``--quick --recipe --steps --shapes --seeds --batch-size --jobs --out --runs-dir --resume --plan``),
prints the plan with its estimated time, runs it with :func:`runner.run_all`, prints the table and writes the
results (:func:`summaries.write_results`). What a scale means, how a run is executed and scored, and the time
estimates are in :mod:`runner`.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Sequence

from cuboidlib.cli_common import positive_int
from cuboidlib.dataset import split_indices
from cuboidlib.release import git_commit
from cuboidlib.train_config import TrainConfig
from runner import (
    COURSE_SCALE,
    DATA_NOTE,
    EXPERIMENT_BATCH_SIZE,
    FIFTEEN_MINUTE_SHAPES,
    FIFTEEN_MINUTE_STEPS,
    FIFTEEN_MINUTES,
    REPO,
    RESULTS_DIR,
    RUNS_DIR,
    TRAINED_DIR,
    Run,
    Scale,
    estimate_makespan,
    estimate_seconds,
    finished_record,
    run_all,
)
from compactness_scale import compactness_note
from summaries import machine, write_results

__all__ = ["categories_option", "float_list_option", "Experiment", "scale_from_args", "main"]

class _Parser(argparse.ArgumentParser):
    """Usage errors as one line (plus where to find help), exit code 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def categories_option(allowed: Sequence[str]):
    """An argparse type for a comma-separated list of categories out of ``allowed``."""

    def parse(text: str) -> tuple[str, ...]:
        chosen = tuple(dict.fromkeys(c.strip() for c in text.split(",") if c.strip()))
        bad = [c for c in chosen if c not in allowed]
        if bad or not chosen:
            raise argparse.ArgumentTypeError(f"expected a comma-separated list of {', '.join(allowed)}, got {text!r}")
        return chosen

    return parse


def float_list_option(allowed: Sequence[float]):
    """An argparse type for a comma-separated list of numbers out of ``allowed``."""

    def parse(text: str) -> tuple[float, ...]:
        try:
            chosen = tuple(dict.fromkeys(float(c) for c in text.split(",") if c.strip()))
        except ValueError:
            chosen = ()
        bad = [c for c in chosen if c not in allowed]
        if bad or not chosen:
            raise argparse.ArgumentTypeError(
                f"expected a comma-separated list of {', '.join(map(str, allowed))}, got {text!r}")
        return chosen

    return parse


@dataclass
class Experiment:
    """One script: a table (or figure) of the paper.

    name: the file stem, also the results name. title: one line. paper: the paper's numbers as
    typed from the .tex (with the table they come from). default_steps / default_seeds: the full
    run's settings, chosen so that it finishes within 45 minutes on a quiet 2-core machine with two
    jobs. build_runs(scale, args) -> runs. report(records, scale, args) -> (summary rows, printed
    text). add_arguments(parser): script options. notes(scale, args) -> extra lines for the output.
    finish(records, scale, args, out_stem) -> extra files written (e.g. a figure) and their paths.
    recipes: the scales its runs can take (``--recipe``; build_runs passes :meth:`Scale.finetune_config` to
    each run where the scale has a second stage).
    """

    name: str
    title: str
    description: str
    paper: dict
    default_steps: int
    default_seeds: int
    build_runs: Callable[[Scale, argparse.Namespace], list[Run]]
    report: Callable[[list[dict], Scale, argparse.Namespace], tuple[list[dict], str]]
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None
    notes: Callable[[Scale, argparse.Namespace], list[str]] | None = None
    finish: Callable[[list[dict], Scale, argparse.Namespace, Path], list[Path]] | None = None
    compactness_category: str = "chair"
    recipes: tuple[str, ...] = ("course",)

    def parser(self) -> argparse.ArgumentParser:
        p = _Parser(prog=f"{self.name}.py", description=self.description,
                    formatter_class=argparse.RawDescriptionHelpFormatter,
                    epilog=f"Writes experiments/results/{self.name}.json (command, git commit, machine, wall time, "
                           f"settings, every run's config and metrics, the table) and {self.name}.csv (the table); "
                           f"--quick writes {self.name}_quick.*. Course scale: {COURSE_SCALE['shapes_per_category']} "
                           f"shapes, {COURSE_SCALE['points_per_shape']} points, ModelConfig.small(), batch {EXPERIMENT_BATCH_SIZE}, "
                           "averaged compactness (see experiments/runner.py).")
        p.add_argument("--quick", action="store_true",
                       help="tiny network, 12 shapes, 1/8 of the points, 2 steps, 1 seed: runs in seconds, "
                            "numbers meaningless (for tests)")
        p.add_argument("--steps", type=positive_int,
                       help=f"training steps per run (default {self.default_steps}; quick: 2)")
        p.add_argument("--shapes", type=positive_int,
                       help=f"shapes per collection (default {COURSE_SCALE['shapes_per_category']}; quick: 12)")
        p.add_argument("--seeds", type=positive_int,
                       help=f"training seeds 0..N-1 per configuration (default {self.default_seeds}; quick: 1)")
        p.add_argument("--batch-size", type=positive_int,
                       help=f"shapes per training step (default {EXPERIMENT_BATCH_SIZE}; the checkpoints: 16; quick: 4); the "
                            "time per step is proportional to it")
        p.add_argument("--jobs", type=positive_int, default=2,
                       help="runs at a time, each in its own process with one torch thread (default 2)")
        p.add_argument("--out", default=str(RESULTS_DIR), help="folder of the results (default experiments/results)")
        p.add_argument("--runs-dir", default=str(RUNS_DIR),
                       help="folder of the training runs (checkpoints, logs; default runs/experiments)")
        p.add_argument("--resume", action="store_true",
                       help="continue the newest earlier invocation in --runs-dir: runs it finished (same configuration) "
                            "are read back, not trained again, so an interrupted full run loses at most the runs in "
                            "progress; and every training that any script finished in --runs-dir/trained with the same "
                            "configuration is read back (the scripts share the runs they have in common)")
        p.add_argument("--plan", action="store_true", help="print the runs and the estimated time, run nothing")
        if FIFTEEN_MINUTES in self.recipes:
            p.add_argument("--recipe", choices=self.recipes, default="course",
                           help="course: one stage at course scale (the default); 15min: the two stages of the "
                                f"15-minute recipe (data_samples/checkpoints/configs/15min/: {FIFTEEN_MINUTE_SHAPES} "
                                f"shapes, batch 16, --steps first-stage steps, default {FIFTEEN_MINUTE_STEPS}, then its "
                                "500-step second stage), one thread per run; results as <name>_15min.*")
        if self.add_arguments is not None:
            self.add_arguments(p)
        return p


def scale_from_args(args: argparse.Namespace, experiment: Experiment) -> Scale:
    recipe = getattr(args, "recipe", "course")
    fifteen = recipe == FIFTEEN_MINUTES
    steps = args.steps or (2 if args.quick else FIFTEEN_MINUTE_STEPS if fifteen else experiment.default_steps)
    shapes = args.shapes or (12 if args.quick else FIFTEEN_MINUTE_SHAPES if fifteen
                             else COURSE_SCALE["shapes_per_category"])
    seeds = args.seeds or (1 if args.quick else experiment.default_seeds)
    batch = args.batch_size or (None if args.quick or fifteen else EXPERIMENT_BATCH_SIZE)
    return Scale(quick=args.quick, steps=steps, n_shapes=shapes, seeds=tuple(range(seeds)), batch_size=batch,
                 recipe=recipe)


def _stem_suffix(scale: Scale) -> str:
    """What the results' and runs' names add to the experiment's: ``_15min`` for the recipe, ``_quick``."""
    return ("_" + FIFTEEN_MINUTES if scale.recipe == FIFTEEN_MINUTES else "") + ("_quick" if scale.quick else "")


def _scale_words(scale: Scale) -> str:
    if scale.quick:
        return "Quick scale: the tiny network of runner.QUICK_MODEL."
    if scale.recipe == FIFTEEN_MINUTES:
        return ("The 15-minute recipe's scale (data_samples/checkpoints/configs/15min/): its two stages, the first "
                "stopped on steps instead of 9 minutes, one thread per run.")
    return ("Course scale (runner.COURSE_SCALE): " + "; ".join(f"{k.replace('_', ' ')}: {v}" for k, v in
                                                              COURSE_SCALE.items() if k != "split") + ".")


def _check_runs(runs: Sequence[Run]) -> None:
    """Refuse settings that cannot work before anything runs (one readable message)."""
    if not runs:
        raise ValueError("nothing to run")
    for run in runs:
        c = run.config
        sizes = {k: len(v) for k, v in split_indices(c.n_shapes, c.split_fractions, c.split_seed).items()}
        if run.task == "train" and sizes["train"] < c.batch_size:
            raise ValueError(f"--shapes {c.n_shapes} leaves {sizes['train']} training shapes, fewer than the batch "
                             f"size {c.batch_size}; use more shapes")
        if sizes["test"] < 2:
            raise ValueError(f"--shapes {c.n_shapes} leaves {sizes['test']} test shape(s); the label transfer "
                             "needs at least 2")


def _print_plan(experiment: Experiment, runs: list, scale, args, estimate: float) -> None:
    print(f"{experiment.title}")
    trains = any(run.task == "train" for run in runs)
    words = ("QUICK: tiny network, numbers meaningless" if scale.quick else
             "the 15-minute recipe's scale" if scale.recipe == FIFTEEN_MINUTES else "course scale")
    second = runs[0].finetune.max_steps if runs[0].finetune is not None else 0
    print(f"{len(runs)} run{'' if len(runs) == 1 else 's'} ({words}), "
          + (f"{scale.steps}{f' + {second}' if second else ''} training steps each, "
             f"{scale.n_shapes} shapes per collection, " if trains else "no training, ")
          + f"seeds {list(scale.seeds)}, {args.jobs} at a time"
          + ("" if scale.quick else f"; estimated wall time on a quiet 2-core machine: {estimate / 60:.1f} min"),
          flush=True)


def _notes(experiment: Experiment, first: TrainConfig, scale, args) -> list[str]:
    """The notes printed under the table and stored in the results: settings, data, the experiment's own."""
    sizes = {k: len(v) for k, v in split_indices(first.n_shapes, first.split_fractions, first.split_seed).items()}
    second = scale.finetune_config(first.category)
    steps = f"{scale.steps} + {second.max_steps} (second stage)" if second is not None else f"{scale.steps}"
    notes = [f"Settings: {steps} training steps of batch {first.batch_size} per run (the paper: 1000 epochs of "
             f"batch 32), {scale.n_shapes} shapes per collection ({sizes['train']} train / {sizes['val']} validation "
             f"/ {sizes['test']} test), {first.n_points} points per shape unless the table varies it, seeds "
             f"{list(scale.seeds)}, model selected on the validation loss. " + _scale_words(scale), DATA_NOTE]
    if scale.quick:
        notes.insert(0, "QUICK RUN: tiny network, 12 shapes, 2 steps; the numbers test the machinery and mean nothing.")
    notes += experiment.notes(scale, args) if experiment.notes else []
    if not scale.quick:
        notes.append(compactness_note(experiment.compactness_category))
    return notes


def _invocation_dir(experiment: Experiment, scale: Scale, args: argparse.Namespace, runs: Sequence[Run],
                    started: datetime) -> Path:
    """The folder of this invocation's runs: a new time-stamped one, or with ``--resume`` the newest earlier one."""
    invocations = Path(args.runs_dir) / (experiment.name + _stem_suffix(scale).replace("_quick", ""))
    runs_dir = invocations / started.strftime("%Y%m%d-%H%M%S-%f")
    if args.resume:
        earlier = sorted(p for p in invocations.glob("*-*-*") if p.is_dir())
        if earlier:
            runs_dir = earlier[-1]
            reused = sum(finished_record(r, runs_dir / r.name) is not None for r in runs)
            print(f"resuming {runs_dir}: {reused} of {len(runs)} runs already finished")
        else:
            print(f"--resume: no earlier invocation in {invocations}; starting a new one")
    return runs_dir


def main(experiment: Experiment, argv: Sequence[str] | None = None) -> int:
    """Parse the command line, print the plan, run, print the table, write the results. Exit code:
    0, 1 if some run failed (the results are still written), 2 for bad arguments."""
    parser = experiment.parser()
    args = parser.parse_args(argv)
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        scale = scale_from_args(args, experiment)
        runs = experiment.build_runs(scale, args)
        _check_runs(runs)
    except (ValueError, FileNotFoundError) as exc:
        parser.exit(2, f"{parser.prog}: error: {exc}\n")
    estimate = estimate_makespan(runs, args.jobs)
    _print_plan(experiment, runs, scale, args, estimate)
    if args.plan:
        for run in runs:
            print(f"  {run.name}: {run.task}" + ("" if scale.quick else f", ~{estimate_seconds(run) / 60:.1f} min"))
        return 0
    stem = Path(args.out) / (experiment.name + _stem_suffix(scale))
    started = datetime.now(timezone.utc)
    runs_dir = _invocation_dir(experiment, scale, args, runs, started)
    # --resume: every training finished in --runs-dir (by any script) with the same configuration is read back
    trained_dir = Path(args.runs_dir) / TRAINED_DIR if args.resume else runs_dir / TRAINED_DIR
    info = machine()
    start = time.perf_counter()
    records = run_all(runs, runs_dir, args.jobs, trained_dir=trained_dir)
    wall = time.perf_counter() - start
    summary, table = experiment.report(records, scale, args)
    first = runs[0].config
    notes = _notes(experiment, first, scale, args)
    failed = [r for r in records if r["status"] != "ok"]
    text = "\n".join([table, "", *notes, f"Wall time {wall / 60:.1f} min for {len(runs)} runs, {args.jobs} at a time."])
    if failed:
        text += "\n" + "\n".join(f"FAILED {r['name']}: {r['error']}" for r in failed)
    extra = []
    if experiment.finish is not None:
        try:
            extra = experiment.finish(records, scale, args, stem)
        except Exception as exc:  # noqa: BLE001 - the results are written all the same
            text += f"\nFAILED to write the extra files: {type(exc).__name__}: {exc}"
            failed.append({"name": "finish", "error": str(exc)})
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    payload = {
        "experiment": experiment.name,
        "title": experiment.title,
        "command": shlex.join(["python", f"experiments/{experiment.name}.py", *argv]),
        "git_commit": git_commit(REPO),
        "machine": {**info, "load_average_at_end": None if load is None else [round(x, 2) for x in load],
                    "jobs": args.jobs},
        "started": started.isoformat(timespec="seconds"),
        "wall_seconds": round(wall, 1),
        "estimated_seconds": round(estimate, 1),
        "settings": {"quick": scale.quick, "recipe": scale.recipe, "steps": scale.steps,
                     "finetune_steps": None if runs[0].finetune is None else runs[0].finetune.max_steps,
                     "shapes": scale.n_shapes, "seeds": list(scale.seeds),
                     "batch_size": first.batch_size,
                     "jobs": args.jobs, "runs_dir": str(runs_dir),
                     "reused_runs": sum(bool(r.get("reused")) for r in records),
                     "reused_trainings": sum(bool(r.get("training", {}).get("reused")) for r in records
                                             if not r.get("reused"))},
        "course_scale": COURSE_SCALE,
        "paper": experiment.paper,
        "summary": summary,
        "table": text,
        "notes": notes,
        "failed": [r["name"] for r in failed],
        "files": [str(p) for p in extra],
        "runs": records,
    }
    json_path, csv_path = write_results(stem, payload, summary)
    print()
    print(text)
    print("wrote " + ", ".join(str(p) for p in [json_path, csv_path, *extra]))
    return 1 if failed else 0
