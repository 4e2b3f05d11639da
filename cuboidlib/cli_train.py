"""The command line's network commands: ``cuboidlib samples`` (procedural shapes), ``cuboidlib train`` (a network,
its second stage and its release) and ``cuboidlib evaluate`` (a network's scores on a test split or a data folder).

Each is an ``add_*_command`` (its options, registered by :func:`cuboidlib.cli.build_parser`) and a ``_cmd_*``
handler, under the rules of :mod:`cuboidlib.cli`.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import tempfile
from pathlib import Path

from .cli_common import (UserError, check_input_folder, check_outputs, check_sizes, growth_type, hold_folder,
                         load_network, part_names_type, resolved_model, threads_type)
from .files import write_text_atomic
from .shapes import GENERATOR_VERSION, GENERATOR_VERSIONS

__all__ = ["add_samples_command", "add_train_command", "add_evaluate_command", "resume_note"]


def add_samples_command(sub) -> None:
    p = sub.add_parser(
        "samples",
        help="regenerate the sample shapes (meshes, labelled point clouds, figure) of data_samples/",
        description="Write a few procedural shapes per category (chair, table, airplane, animal) as PLY "
        "meshes and as PLY point clouds with normals and part labels, an index.csv and samples.png.",
    )
    p.add_argument("--out", default="data_samples", help="output folder (default: data_samples)")
    p.add_argument("--per-category", type=int, default=3, help="shapes per category (default: 3)")
    p.add_argument("--points", type=int, default=2048, help="points per point cloud (default: 2048)")
    p.add_argument("--seed", type=int, default=0, help="collection seed (default: 0)")
    p.add_argument("--no-figure", action="store_true", help="do not draw samples.png")
    p.add_argument("--generator-version", type=int, choices=GENERATOR_VERSIONS, default=GENERATOR_VERSION,
                   help=f"procedural generator (default: {GENERATOR_VERSION}, the newest; the committed data_samples/ are version 1's, "
                   "their figure samples.png; another version's figure is samples_v<version>.png)")
    p.add_argument("--categories", type=part_names_type, default=None, metavar="NAMES",
                   help="comma-separated categories (default: chair,table,airplane,animal)")
    p.add_argument("--figure-only", action="store_true", help="draw the figure only, write no sample files")
    p.add_argument("--force", action="store_true",
                   help="replace sample files that are already there (default: refuse, naming them; the committed "
                   "data_samples/ are the course's inputs)")
    p.set_defaults(func=_cmd_samples)


def _cmd_samples(args) -> int:
    from ._checks import MAX_SEED, MAX_SHAPE_POINTS, MAX_SHAPES  # imports torch: start-up time
    from .sample_files import data_sample_files, write_data_samples  # imports torch: start-up time
    from .shapes import CATEGORIES  # imports torch: start-up time

    if args.per_category < 1 or args.points < 1 or args.seed < 0:
        raise UserError("--per-category and --points must be positive and --seed non-negative")
    check_sizes(("--per-category", args.per_category, MAX_SHAPES, 1), ("--points", args.points, MAX_SHAPE_POINTS, 1),
                ("--seed", args.seed, MAX_SEED, 0))
    if args.categories and not set(args.categories) <= set(CATEGORIES):
        raise UserError(f"--categories: expected some of {','.join(CATEGORIES)}, got {','.join(args.categories)}")
    if args.figure_only and args.no_figure:
        raise UserError("--figure-only and --no-figure leave nothing to write: give one")
    chosen = dict(version=args.generator_version, figure_only=args.figure_only,
                  **({"categories": args.categories} if args.categories else {}))
    files = data_sample_files(args.out, args.per_category, figure=not args.no_figure, **chosen)
    check_outputs([("--out", args.out), *(("--out", f) for f in files)])
    present = [str(f) for f in files if os.path.lexists(f)]
    if present and not args.force:
        raise UserError(f"--out {args.out}: already holds {len(present)} of the sample files ({', '.join(present[:3])}"
                        f"{', ...' if len(present) > 3 else ''}); choose another folder, or replace them (--force)")
    hold_folder(args, args.out)
    written = write_data_samples(args.out, args.per_category, args.points, args.seed, figure=not args.no_figure,
                                 **chosen)
    print(f"wrote {len(written)} files to {args.out}")
    return 0


def add_train_command(sub) -> None:
    p = sub.add_parser(
        "train",
        help="train the network (Adam, lr 6e-4, batch 32 by default) with checkpoints and resume",
        description="Train the cuboid abstraction network (Sec. 3.4.5). Settings come from the defaults "
        "(the paper's), then --config FILE (a JSON object with any TrainConfig fields; 'model' and 'loss' may "
        "be partial), then the flags below, then --set. Writes OUT/config.json, OUT/last.pt (full state, "
        "for --resume), OUT/best.pt (the lowest validation loss, or the last weights with selection=last) and "
        "OUT/log.csv. --resume continues OUT/last.pt exactly (only budget and bookkeeping fields may change). "
        "Under torchrun the same command trains with DistributedDataParallel: "
        "torchrun --nproc_per_node=2 -m cuboidlib train --config cfg.json --out DIR",
    )
    p.add_argument("--config", help="JSON config file (TrainConfig fields)")
    p.add_argument("--out", required=True, help="run folder (last.pt, best.pt, config.json, log.csv)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last.pt")
    p.add_argument("--max-minutes", type=float, help="time budget: stop cleanly and checkpoint after this long "
                   "(with --resume: in all, counting the earlier sessions of the run)")
    p.add_argument("--max-steps", type=int, help="stop after this many optimiser steps in total")
    p.add_argument("--epochs", type=int, help="epochs (paper: 1000)")
    p.add_argument("--category", help="procedural category: chair, table, airplane or animal")
    p.add_argument("--shapes", type=int, dest="n_shapes", help="shapes in the procedural collection")
    p.add_argument("--points", type=int, dest="n_points", help="points per shape (paper: 4096)")
    p.add_argument("--data-dir", help="train on this folder instead of a procedural collection: a ShapeNet-part root "
                   "(with --category chair, table or airplane), the authors' data layout (<category>_train.npy ...) or "
                   "any folder of point-cloud / mesh files")
    p.add_argument("--data-seed", type=int, help="seed of the collection")
    p.add_argument("--generator-version", type=int, choices=GENERATOR_VERSIONS,
                   help=f"procedural generator (default: the newest, {GENERATOR_VERSION}; a --config file without generator_version: 1, "
                   "the shapes of the chair, table and animal networks)")
    p.add_argument("--split", type=float, nargs=3, dest="split_fractions", metavar=("TRAIN", "VAL", "TEST"),
                   help="split fractions (default 0.7 0.1 0.2)")
    p.add_argument("--split-seed", type=int, help="seed of the train/validation/test split")
    p.add_argument("--model-size", choices=("paper", "small"),
                   help="replace the model section by the paper's sizes or ModelConfig.small()")
    p.add_argument("--num-cuboids", type=int, help="M, cuboids per shape (paper: 16 for chairs)")
    p.add_argument("--loss-preset", choices=("paper", "authors_code"),
                   help="replace the loss section by the paper's settings or the authors' code choices")
    p.add_argument("--lr", type=float, help="Adam learning rate (paper: 6e-4)")
    p.add_argument("--batch-size", type=int, help="shapes per step, over all processes (paper: 32)")
    p.add_argument("--checkpoint-every", type=int, help="write last.pt every this many steps")
    p.add_argument("--validate-every", type=int, help="validation loss (and best.pt) every this many steps")
    p.add_argument("--seed", type=int, help="seed of the weights, data order and sampling")
    p.add_argument("--device", help="auto (CUDA when available), cpu or cuda[:i]")
    p.add_argument("--threads", type=threads_type, dest="num_threads",
                   help="torch threads of the training process: a number, or auto (the default: every core that "
                   "other processes leave free, followed as the load changes)")
    p.add_argument("--compiled-kernels", action=argparse.BooleanOptionalAction, default=None,
                   help="the CPU hot spots in C++ (cuboidlib.kernels: the same results, faster). Default: used "
                   "wherever a C++ compiler can build them (once per machine); --no-compiled-kernels turns them off")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="any other field, VALUE in JSON, e.g. --set loss.lambda_compact=0.2 --set model.k=16")
    p.add_argument("--print-config", action="store_true", help="print the resulting config and exit")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no messages")
    p.add_argument("--finetune", metavar="FILE",
                   help="then a second stage in the same command: train FILE's config (TrainConfig fields, as "
                   "--config) from OUT/best.pt into OUT/finetune, on the first stage's shapes (the data fields FILE "
                   "leaves out are the first stage's, those it sets must agree); the data and device flags "
                   "(--category, --shapes, --points, --data-dir, --data-seed, --split, --split-seed, --device, "
                   "--threads, --compiled-kernels) apply to both stages, the other flags and --set to the first; "
                   "--release releases the second; --resume continues the stage that was interrupted. The committed "
                   "networks: --config configs/<category>.json --finetune configs/finetune/<category>.json")
    p.add_argument("--release", metavar="FILE.pt",
                   help="after training, copy best.pt (weights and config only) to FILE.pt, score it on the test "
                   "split with the baseline and write the card FILE.json (command, config, training time, metrics)")
    p.set_defaults(func=_cmd_train)


def _train_config_from_args(args):
    """Defaults (or the resumed run's config) < --config file < flags < --set."""
    from .checkpoint import load_checkpoint  # imports torch: start-up time
    from .config import read_config_file  # imports torch: start-up time
    from .dataset import UNVERSIONED_GENERATOR  # imports torch: start-up time
    from .losses import LossConfig  # imports torch: start-up time
    from .model import ModelConfig  # imports torch: start-up time
    from .train_config import TrainConfig  # imports torch: start-up time

    last = Path(args.out) / "last.pt"
    data = load_checkpoint(last)["config"] if args.resume and last.is_file() else TrainConfig().to_dict()

    def merge(update: dict) -> None:
        for key, value in update.items():
            if key in ("model", "loss") and isinstance(value, dict):
                data[key] = {**data[key], **value}
            else:
                data[key] = value

    if args.config:
        file = read_config_file(args.config)
        merge({"generator_version": UNVERSIONED_GENERATOR, **file})  # a file written before the field: version 1
    if args.model_size:
        data["model"] = (ModelConfig.small() if args.model_size == "small" else ModelConfig()).to_dict()
    if args.loss_preset:
        data["loss"] = (LossConfig.authors_code() if args.loss_preset == "authors_code" else LossConfig()).to_dict()
    flags = {k: getattr(args, k) for k in ("max_minutes", "max_steps", "epochs", "category", "n_shapes", "n_points",
                                           "data_dir", "data_seed", "generator_version", "split_fractions",
                                           "split_seed", "lr",
                                           "batch_size", "checkpoint_every", "validate_every", "seed", "device",
                                           "num_threads", "compiled_kernels")}
    merge({k: v for k, v in flags.items() if v is not None})
    if data.get("num_threads") is None:
        data["num_threads"] = "auto"  # the command line follows the free cores unless told otherwise
    if args.num_cuboids is not None:
        data["model"] = {**data["model"], "num_cuboids": args.num_cuboids}
    for item in args.set:
        key, sep, raw = item.partition("=")
        if not sep:
            raise UserError(f"--set expects KEY=VALUE, got {item!r}")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw  # a bare string, e.g. --set loss.distance=chamfer
        except RecursionError:
            raise UserError(f"--set {key}: the value is nested too deeply to read") from None
        section, dot, name = key.partition(".")
        if dot and section in ("model", "loss"):
            data[section] = {**data[section], name: value}
        else:
            data[key] = value
    return TrainConfig.from_dict(data)


def _finetune_config_from_args(args, first):
    """The second stage's config: --finetune FILE, the data fields it leaves out taken from the first stage, then
    the data and device flags, which apply to both stages (:func:`cuboidlib.train.train_then_finetune` then checks
    that both stages select the same shapes)."""
    from .config import read_config_file  # imports torch: start-up time
    from .dataset import DATA_FIELDS  # imports torch: start-up time
    from .train_config import TrainConfig  # imports torch: start-up time

    file = read_config_file(args.finetune)
    inherited = {key: first.to_dict()[key] for key in DATA_FIELDS if key not in file}
    both = (*DATA_FIELDS, "device", "num_threads", "compiled_kernels")
    given = {key: getattr(args, key) for key in both if getattr(args, key) is not None}
    return TrainConfig.from_dict({**file, **inherited, **given})


def _check_writable_file(path: str, option: str) -> None:
    """Refuse, before any work, an output file that could not be written at the end."""
    file = Path(path)
    try:  # the folder is made now, and a file written and removed in it
        file.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=file.parent, prefix=".write-test-"):
            pass
    except OSError as exc:
        raise UserError(f"{option} {path}: cannot write there ({exc.strerror or exc})") from exc


def _check_train_outputs(args, config, finetune) -> None:
    """The one rule for train's outputs: the run folder's files (and the second stage's), --release and its card
    are none of the inputs (--config, --finetune, the data folder, init_from) and no two are one file."""
    from .release import card_path  # imports torch: start-up time
    from .train import FINETUNE_DIR, RUN_FILES  # imports torch: start-up time

    if args.release and Path(args.release).suffix != ".pt":
        raise UserError(f"--release {args.release}: the file must end in .pt")
    out = Path(args.out)
    runs = [out, *([out / FINETUNE_DIR] if finetune is not None else [])]
    writes = [("--out", out), *((f"the run's {name} in --out", run / name) for run in runs for name in RUN_FILES)]
    if args.release:
        writes += [("--release", Path(args.release)), ("the card of --release", card_path(args.release))]
    check_outputs(writes, [args.config, args.finetune, config.data_dir, config.init_from])


def _cmd_train(args) -> int:
    from ._checks import MAX_THREADS  # imports torch: start-up time
    from .train import Distributed, Trainer, TrainingDiverged, train_then_finetune  # imports torch: start-up time

    check_sizes(("--threads", args.num_threads if isinstance(args.num_threads, int) else None, MAX_THREADS, 1))
    config = _train_config_from_args(args)
    finetune = _finetune_config_from_args(args, config) if args.finetune else None
    _check_train_outputs(args, config, finetune)
    if args.release:
        _check_writable_file(args.release, "--release")
    if args.print_config:
        print(json.dumps(config.to_dict(), indent=2))
        return 0
    hold_folder(args, args.out)
    processes = Distributed()  # this process's rank and the number of processes (torchrun's variables)
    try:
        if finetune is None:
            results = [Trainer(config, args.out, resume=args.resume, quiet=args.quiet).run()]
        else:
            results = train_then_finetune(config, finetune, args.out, resume=args.resume, quiet=args.quiet)
    except TrainingDiverged as exc:
        print(f"cuboidlib train: {exc}", file=sys.stderr)
        return 3
    for result in results:
        if result is not None and not args.quiet and processes.is_main:
            print(f"{result.stopped}: step {result.step} (epoch {result.epoch}); best validation loss "
                  f"{result.best_val:.5f} at step {result.best_step}; files in {result.out_dir}")
    if args.release and processes.is_main:
        from .release import card_path, publish_run  # imports torch: start-up time (only with --release)

        n = processes.world_size
        launcher = ["torchrun", f"--nproc_per_node={n}", "-m", "cuboidlib"] if n > 1 else ["cuboidlib"]
        command = shlex.join([*launcher, *(args.argv if args.argv is not None else sys.argv[1:])])
        card = publish_run(results[-1].out_dir, args.release, command, started=args.started)
        if not args.quiet:
            print(card["test"]["table"])
            print(f"released {args.release} and {card_path(args.release)}")
    return 0


def add_evaluate_command(sub) -> None:
    p = sub.add_parser(
        "evaluate",
        help="score a checkpoint on its test split: Chamfer distance, normal consistency, mIoU, N_AC",
        description="Run a checkpoint's network on a split of the data it was trained with (by default the "
        "test split, which training never uses), or on every shape of another data folder (--data-dir), and print Chamfer distance (convention stated under the "
        "table), normal consistency, mIoU by the paper's label transfer (labels from a seeded 20 %% of the "
        "split, scored on the other 80 %%) and the average number of existing cuboids N_AC. --baseline adds "
        "the k-means + oriented-box baseline scored the same way.",
    )
    p.add_argument("checkpoint", help="a checkpoint file, a 'cuboidlib train' run folder (its best.pt) or the "
                   "name of a committed checkpoint (e.g. chair)")
    p.add_argument("--split", choices=("train", "val", "test", "all"),
                   help="split to score (default: test of the checkpoint's own data, every shape of a --data-dir; "
                   "all: every shape of the data)")
    p.add_argument("--data-dir", metavar="DIR",
                   help="score on this data instead of the checkpoint's own: a ShapeNet-part root, the authors' data "
                   "layout or a folder of mesh / point cloud files (labels score the mIoU when the files have them); "
                   "every shape of it unless --split is given")
    p.add_argument("--category", help="the category to read from --data-dir (default: the checkpoint's)")
    p.add_argument("--generator-version", type=int, choices=GENERATOR_VERSIONS,
                   help="score on the shapes of this procedural generator (default: the checkpoint's, from its config; "
                   "a config without generator_version: 1)")
    p.add_argument("--part-names", type=part_names_type, metavar="NAMES",
                   help="comma-separated names of the data's part labels (default: the category's, "
                   "cuboidlib.shapes.PART_NAMES, for files whose labels have no names)")
    p.add_argument("--baseline", action="store_true", help="also score the k-means + oriented-box baseline")
    p.add_argument("--merge", type=growth_type, nargs="?", const=0.25, metavar="GROWTH",
                   help="also score the network's cuboids after merging the pieces of one part: two segments merge "
                   "when the box around both is at most GROWTH larger than their two boxes (default 0.25; "
                   "cuboidlib.merging)")
    p.add_argument("--baseline-boxes", type=int,
                   help="boxes per shape for the baseline, the same for every shape (default: as many as the "
                   "network's existing cuboids of that shape)")
    p.add_argument("--json", metavar="OUT", help="also write the results as JSON to OUT")
    p.add_argument("--chamfer-norm", action="append", choices=("squared_l2", "l2", "l1"),
                   help="Chamfer distance norm, repeat for several columns (default: squared_l2)")
    p.add_argument("--chamfer-directions", choices=("sum", "mean"), default="sum",
                   help="combine the two directions by their sum (default) or mean")
    p.add_argument("--chamfer-scale", type=float, default=1.0, help="factor applied to the Chamfer distance")
    p.add_argument("--samples", type=int, default=4096, help="points sampled on the cuboids (default: 4096)")
    p.add_argument("--label-fraction", type=float, default=0.2,
                   help="fraction of the split whose labels name the cuboids (default: 0.2)")
    p.add_argument("--seed", type=int, default=0, help="seed of the surface samples and label-transfer shapes")
    p.add_argument("--batch-size", type=int, default=32, help="shapes per forward pass")
    p.add_argument("--device", default="auto", help="auto (CUDA when available), cpu or cuda[:i]")
    p.set_defaults(func=_cmd_evaluate)


def _cmd_evaluate(args) -> int:
    from ._checks import MAX_CUBOIDS, MAX_SEED, MAX_SHAPE_POINTS, MAX_SHAPES  # imports torch: start-up time
    from .dataset import load_shapes, split_indices  # imports torch: start-up time
    from .evaluation import (evaluate_baseline, evaluate_model, format_table,  # imports torch: start-up time
                             predict_cuboids)
    from .metrics import ChamferConvention  # imports torch: start-up time
    from .release import card_path  # imports torch: start-up time
    from .shapes import PART_NAMES  # imports torch: start-up time
    from .train_config import TrainConfig  # imports torch: start-up time

    check_sizes(("--samples", args.samples, MAX_SHAPE_POINTS, 1), ("--batch-size", args.batch_size, MAX_SHAPES, 1),
                ("--baseline-boxes", args.baseline_boxes, MAX_CUBOIDS, 1), ("--seed", args.seed, MAX_SEED, 0))
    checkpoint = resolved_model(args.checkpoint)
    if args.data_dir is not None:
        check_input_folder(args.data_dir)
    if args.json:
        check_outputs([("--json", Path(args.json))], [checkpoint, card_path(checkpoint), args.data_dir])
    model, state, _ = load_network(args.checkpoint, args.device)
    config = TrainConfig.from_dict(state["config"])
    if args.data_dir is not None and args.generator_version is not None:
        raise UserError("--generator-version chooses procedural shapes; --data-dir reads files instead: give one")
    if args.generator_version is not None:
        config = config.replace(generator_version=args.generator_version)
    if args.data_dir is not None:
        config = config.replace(data_dir=args.data_dir, category=args.category or config.category)
    elif config.data_dir is not None:  # a folder written in a file is never read unasked
        raise UserError(f"{args.checkpoint}: was trained on the data folder {config.data_dir}; to score it there, "
                        f"name the folder: --data-dir {shlex.quote(config.data_dir)} (a checkpoint never chooses "
                        "which folder is read)")
    split = args.split or ("all" if args.data_dir is not None else "test")
    every = load_shapes(config)
    shapes = every if split == "all" else every.subset(
        split_indices(len(every), config.split_fractions, config.split_seed)[split])
    if shapes.labels is not None and (args.part_names or shapes.part_names is None):
        names = args.part_names or PART_NAMES.get(config.category, ())
        where = "--part-names" if args.part_names else (f"the {config.category} part names (cuboidlib.shapes."
                                                        "PART_NAMES; --part-names names the data's labels)")
        shapes = shapes.with_part_names(names, where)
    conventions = [ChamferConvention(norm, args.chamfer_directions, args.chamfer_scale, args.samples)
                   for norm in (args.chamfer_norm or ["squared_l2"])]
    options = dict(label_transfer_fraction=args.label_fraction, conventions=conventions, seed=args.seed)
    step = state.get("step")
    centroids = config.loss_config.centers_from_allocation  # cuboids where the losses put them in training
    name = f"network (step {step}{', centroid centres' if centroids else ''})"
    results = [evaluate_model(model, shapes, batch_size=args.batch_size, name=name,
                              centers_from_allocation=centroids, **options)]
    if args.merge is not None:
        results.append(evaluate_model(model, shapes, batch_size=args.batch_size, centers_from_allocation=centroids,
                                      name=f"{name}, merged ({args.merge:g})", merge_growth=args.merge, **options))
    if args.baseline:  # as many boxes as the network's existing cuboids, shape by shape
        boxes = args.baseline_boxes or predict_cuboids(model, shapes, args.batch_size,
                                                       centroids)[0].num_existing().tolist()
        results.append(evaluate_baseline(shapes, boxes, **options))
    data = f", data folder {config.data_dir}" if config.data_dir else f", generator version {config.generator_version}"
    scope = (f"every shape ({len(shapes)} shapes" if split == "all" else
             f"{split} split ({len(shapes)} of {len(every)} shapes{'; --split all scores every one' if config.data_dir else ''}")
    print(format_table(results, f"{args.checkpoint}: {config.category}{data}, {scope}, {config.n_points} points each)"))
    if args.json:
        out = {"checkpoint": str(args.checkpoint), "split": split, "config": config.to_dict(), "results": results,
               "generator_version": None if config.data_dir else config.generator_version}
        write_text_atomic(args.json, json.dumps(out, indent=2) + "\n")
    return 0


# ----------------------------------------------------------------------------------------------
# Abstraction of one shape (fit, abstract), applications (generate, interpolate) and the viewer
# ----------------------------------------------------------------------------------------------


def resume_note(args) -> str:
    """For an interrupted train: the step from which --resume continues (that of OUT/last.pt), or that none can."""
    if args.command != "train":
        return ""
    last = Path(args.out) / "last.pt"
    try:
        from .checkpoint import load_checkpoint  # imports torch: start-up time (already imported by train)

        step = load_checkpoint(last)["step"]
    except (OSError, ValueError, KeyError, ImportError):
        return f"; no checkpoint was written in {args.out} yet, so --resume has nothing to continue"
    return f"; --resume continues from step {step} ({last}), the last checkpoint"
