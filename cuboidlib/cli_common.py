"""What the command line's subcommands share: the user's-error type, progress bars, the inputs they read, and the one
rule for what a command writes.

The rule, for every command that writes (:func:`check_outputs`): before any work, no file the command will write or
remove may be one of its inputs or lie inside an input folder, and no two of its outputs may be one file (its
results, its reserved files, a card beside a checkpoint); paths are compared resolved (links followed). Only then is
the output folder held (:func:`hold_folder`) and prepared. The handlers import the library inside, as marked: it
imports torch (seconds), which --help, --version and usage errors do without.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from pathlib import Path

from .files import (LOCK_FILE, MANIFEST, MESH_FORMATS, check_distinct_outputs, check_outputs_spare_inputs,
                     output_lock)

__all__ = ["UserError", "BAR_DELAY", "SUMMARY_FILE", "bars", "check_sizes", "check_outputs", "hold_folder",
           "check_out_dir", "record", "Recording", "check_input", "check_input_folder", "check_shape_file",
           "load_shape", "model_points", "resolved_model", "load_network", "threads_type", "int_at_least", "positive_int",
           "non_negative_int", "threshold_type", "growth_type", "mesh_formats_type", "part_names_type"]


class UserError(Exception):
    """An error caused by the user's input: printed as one line, exit code 2."""


#: Progress bars appear only when a step takes longer than this many seconds.
BAR_DELAY = 0.5

#: The table of a run over several shapes, written into --out (a reserved file of an output folder, with the
#: manifest and the lock).
SUMMARY_FILE = "summary.csv"


def bars(args) -> bool:
    """Progress bars only for a person watching: not with --quiet, not into a redirected log."""
    return not args.quiet and sys.stderr.isatty()


def check_sizes(*sizes) -> None:
    """Every size and seed option against its limit (cuboidlib._checks), before any work.

    Args:
        *sizes: (option, value, limit, minimum) tuples, a value of None skipped; the limit
            ``cuboidlib._checks.MAX_SEED`` checks a seed (from 0).

    Raises:
        UserError: naming the option, the value and the limit.
    """
    from ._checks import MAX_SEED, check_seed, check_size  # imports torch: start-up time (the handlers' library)

    for option, value, limit, minimum in sizes:
        if value is None or not isinstance(value, int):  # None: not given; a library default is checked there
            continue
        try:
            if limit is MAX_SEED:
                check_seed(value, option)
            else:
                check_size(value, option, limit, minimum=minimum)
        except ValueError as exc:
            raise UserError(str(exc)) from exc


def check_outputs(writes, inputs=(), removes=()) -> None:
    """The one rule for every command that writes, checked before any work.

    Args:
        writes: (label, path) pairs: every file or folder the command will write, named as the user knows it
            (e.g. "--out", "--release", "the card of --release").
        inputs: the files and folders it reads (those that do not exist are left out).
        removes: files it will remove first (``--overwrite``: the earlier run's).

    Raises:
        ValueError: an output is an input or lies inside an input folder, or two outputs are one file.
    """
    present = [i for i in inputs if i is not None and os.path.lexists(i)]
    for label, path in writes:
        check_outputs_spare_inputs([path], present, label)
    check_outputs_spare_inputs(list(removes), present, "--overwrite would remove")
    check_distinct_outputs(writes)


def hold_folder(args, folder) -> None:
    """Hold ``folder`` for the rest of the command (:func:`cuboidlib.files.output_lock`): a second run writing into
    it meanwhile is refused. Under torchrun only rank 0 holds it. Call it after :func:`check_outputs`."""
    if os.environ.get("RANK", "0") != "0":
        return
    try:
        args.held.enter_context(output_lock(folder))
    except ValueError as exc:
        raise UserError(f"--out {exc}") from exc


def check_out_dir(args, inputs=(), names=()) -> None:
    """The output folder of fit, abstract, generate and interpolate: check, hold, then prepare it.

    The files this run would write (``names`` in --out, the manifest and the summary) and those --overwrite would
    remove are checked against ``inputs`` and each other (:func:`check_outputs`); then the folder is held, and an
    earlier run's results in it are refused unless --overwrite (then removed).
    """
    from .export import prepare_output_folder, read_manifest  # imports torch: start-up time

    out = Path(args.out)
    writes = [("--out", out), *(("--out", out / n) for n in names), ("the run's manifest --out", out / MANIFEST),
              ("the run's summary --out", out / SUMMARY_FILE), ("the run's lock --out", out / LOCK_FILE)]
    manifest = read_manifest(out) if args.overwrite and out.is_dir() else None
    removes = [out / n for n in (manifest or {}).get("files", [])]
    check_outputs(writes, inputs, removes)
    hold_folder(args, out)
    try:
        prepare_output_folder(args.out, args.overwrite)
    except ValueError as exc:
        raise UserError(f"--out {exc}" if not str(exc).startswith("--out") else str(exc)) from exc


def record(args, files, complete: bool = True) -> None:
    """Write the output folder's manifest: the files this run wrote, and whether it completed."""
    from .export import write_manifest  # imports torch: start-up time

    argv = sys.argv[1:] if args.argv is None else args.argv
    write_manifest(args.out, files, "cuboidlib " + shlex.join(argv), complete)


class Recording:
    """While a command writes many files: the manifest every few seconds (not after every file, which grows as
    N^2) and when the run is interrupted, with what it wrote so far. ``files`` is the list the command extends."""

    def __init__(self, args, files: list):
        self.args, self.files, self.last = args, files, time.perf_counter()

    def tick(self) -> None:
        if time.perf_counter() - self.last > 2.0:
            record(self.args, self.files, complete=False)
            self.last = time.perf_counter()

    def __enter__(self) -> "Recording":
        return self

    def __exit__(self, error_type, error, trace) -> bool:
        if error_type is not None:  # an interrupted run says so
            record(self.args, self.files, complete=False)
        return False


def check_input_folder(path: str) -> None:
    """Fail fast on a data folder that does not exist."""
    if not Path(path).is_dir():
        raise UserError(f"{path}: no such data folder")


def check_input(path: str) -> None:
    """Fail fast (before the shape is read) on a missing input file."""
    file = Path(path)
    if not file.exists():
        raise FileNotFoundError(f"{file}: no such file")
    if file.is_dir():
        raise UserError(f"{file}: is a folder; give a mesh or point cloud file")


def check_shape_file(path: str) -> None:
    """Fail fast (before the shape is read) on a missing input or one of an unknown type."""
    from .io import MESH_SUFFIXES, POINT_CLOUD_SUFFIXES  # imports torch: start-up time

    check_input(path)
    file = Path(path)
    if file.suffix.lower() not in set(MESH_SUFFIXES) | set(POINT_CLOUD_SUFFIXES):
        raise UserError(f"{file}: unsupported file type {file.suffix or '(no suffix)'!r}; expected a mesh "
                        f"({' '.join(MESH_SUFFIXES)}) or a point cloud ({' '.join(POINT_CLOUD_SUFFIXES)})")


def load_shape(path: str, n_points: int, seed: int):
    """A mesh (sampled with n_points) or a point cloud (subsampled to at most n_points), normalised."""
    from .io import load_point_cloud  # imports torch: start-up time

    check_shape_file(path)
    return load_point_cloud(path, n_points, seed, fewer_ok=True)


def model_points(state: dict) -> int:
    """Points per shape the checkpoint's network was trained with (2048 if it does not say)."""
    value = state.get("config", {}).get("n_points")
    return value if isinstance(value, int) and value > 0 else 2048


def resolved_model(name_or_path: str) -> Path:
    """The checkpoint file a --model or CHECKPOINT argument names (an input of the command), before it is loaded."""
    from .applications import resolve_checkpoint  # imports torch: start-up time

    return resolve_checkpoint(name_or_path)


# ------------------------------------------------------------------ argument types and the network argument


def threads_type(value: str):
    """--threads: "auto" or a positive integer."""
    if value == "auto":
        return value
    try:
        number = int(value)
    except ValueError:
        number = 0
    if number < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number of threads or auto, got {value!r}")
    return number


def int_at_least(minimum: int):
    """An argparse type: an integer >= minimum (0 or 1), with a one-line message otherwise."""
    rule = "a positive integer" if minimum == 1 else "a non-negative integer"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = minimum - 1
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected {rule}, got {text!r}")
        return value

    return parse


positive_int = int_at_least(1)
non_negative_int = int_at_least(0)


def threshold_type(text: str) -> float:
    """An argparse type: a number in [0, 1) (an existence threshold)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1), got {text!r}") from None
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1), got {text!r}")
    return value


def growth_type(text: str) -> float:
    """An argparse type: the largest growth of :func:`cuboidlib.merging.merge_split_cuboids`, a number >= 0."""
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def mesh_formats_type(text: str) -> tuple[str, ...]:
    """An argparse type: comma-separated mesh formats, each one of ``MESH_FORMATS``, without repeats."""
    chosen = tuple(f.strip().lower().lstrip(".") for f in text.split(","))
    unknown = [f for f in chosen if f not in MESH_FORMATS]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown mesh format {unknown[0]!r}; expected a comma-separated "
                                         f"list of {', '.join(MESH_FORMATS)}")
    return tuple(dict.fromkeys(chosen))


def part_names_type(text: str) -> tuple[str, ...]:
    """An argparse type: comma-separated non-empty part names."""
    names = tuple(n.strip() for n in text.split(","))
    if not all(names):
        raise argparse.ArgumentTypeError(f"expected comma-separated non-empty names, got {text!r}")
    return names


def load_network(checkpoint: str, device: str):
    """(model, checkpoint state, path) of a checkpoint file, run folder or committed name, on ``device``."""
    from .applications import load_trained_model  # imports torch: start-up time
    from .config import resolve_device  # imports torch: start-up time

    return load_trained_model(checkpoint, resolve_device(device))
