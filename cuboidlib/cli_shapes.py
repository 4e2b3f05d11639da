"""The command line's runs over shapes (``cuboidlib fit`` and ``cuboidlib abstract``): one file, or many files,
folders and glob patterns in one process.

Each shape's result is written into --out under a stem of its own (:func:`result_stems`), never one of the folder's
reserved files. A run over several shapes goes on past a shape that fails, for any reason (an unreadable file, an
unexpected error): it is reported, counted and listed in ``summary.csv``, and the exit code is 1. Every shape's
warnings and the frame it was read in are printed and kept in the summary, whose cells never start a spreadsheet
formula (:func:`csv_cell`).
"""

from __future__ import annotations

import csv
import glob
import io
import sys
import time
from pathlib import Path

from .cli_common import (BAR_DELAY, SUMMARY_FILE, UserError, Recording, bars, check_out_dir, check_shape_file,
                         record)
from .files import LOCK_FILE, MANIFEST, write_text_atomic

__all__ = ["SUMMARY_COLUMNS", "shape_files", "result_stems", "run_shapes", "warnings_of", "frame_of", "csv_cell",
           "write_summary"]

#: The columns of SUMMARY_FILE, one row per shape.
SUMMARY_COLUMNS = ("shape", "status", "result", "cuboids_used", "cuboids", "chamfer", "frame", "warning", "seconds",
                   "error")

#: The errors of a shape that say what is wrong with it; any other is reported as unexpected, with its type.
_EXPECTED = (UserError, ValueError, OSError, FloatingPointError)


def shape_files(items: list[str]) -> list[str]:
    """The input files of SHAPE arguments: files as given, folders and glob patterns expanded (sorted).

    Args:
        items: the SHAPE arguments.

    Returns:
        The files, each once, in order.
    """
    from .io import MESH_SUFFIXES, POINT_CLOUD_SUFFIXES  # imports torch: start-up time

    known = set(MESH_SUFFIXES) | set(POINT_CLOUD_SUFFIXES)
    files: list[str] = []
    for item in items:
        path = Path(item)
        if path.is_dir():
            found = sorted(str(f) for f in path.iterdir() if f.is_file() and f.suffix.lower() in known)
            if not found:
                raise UserError(f"{path}: a folder without mesh or point cloud files ({' '.join(sorted(known))})")
            files += found
        elif not path.exists() and glob.has_magic(item):
            found = sorted(f for f in glob.glob(item) if Path(f).is_file() and Path(f).suffix.lower() in known)
            if not found:
                raise UserError(f"{item}: no mesh or point cloud file matches this pattern")
            files += found
        else:
            if len(items) == 1:
                check_shape_file(item)  # one named file: its problems are the run's errors
            files.append(item)
    return list(dict.fromkeys(files))  # each file once, in order


def result_stems(paths: list[str], formats) -> list[str]:
    """A result stem for every input: its file name without suffix, changed where one of the files it names
    (``result_files``: NAME.json, NAME.<format>, NAME_segmentation.ply) is already another input's or a reserved
    file of the output folder (the manifest, the summary, the lock), so that no result writes over another file
    of the run: ``a.ply`` and ``a_segmentation.ply`` get their own names, and so does ``cuboidlib-manifest.ply``.

    Args:
        paths: the input files.
        formats: the mesh formats written.

    Returns:
        One stem per path.
    """
    from .results import result_files  # imports torch: start-up time

    stems, taken = [], {MANIFEST, SUMMARY_FILE, LOCK_FILE}
    for path in paths:
        base = stem = Path(path).stem
        k = 1
        while any(name in taken for name in result_files(stem, formats).values()):
            k += 1
            stem = f"{base}_{k}"
        taken.update(result_files(stem, formats).values())
        stems.append(stem)
    return stems


def run_shapes(args, what: str, prepare, inputs=()) -> int:
    """The handler of fit and abstract: expand SHAPE, check --out, then abstract every shape with
    ``one = prepare()`` (``one(path, progress)`` -> a result), write its files and report.

    With several shapes a failure of any kind is reported and skipped, every shape's warnings and frame are
    printed, and SUMMARY_FILE lists every shape.

    Args:
        args: the parsed arguments (shape, out, mesh_format, quiet, overwrite, normalized).
        what: the progress bar's description.
        prepare: returns the function that abstracts one shape.
        inputs: other inputs of the run (the network's checkpoint file).

    Returns:
        The exit code: 0, or 1 if any shape failed.
    """
    from tqdm import tqdm  # start-up time (a quarter of a second)

    from .results import result_files  # imports torch: start-up time

    shapes = shape_files(args.shape)
    stems = result_stems(shapes, args.mesh_format)
    names = [n for stem in stems for n in result_files(stem, args.mesh_format).values()]
    check_out_dir(args, [*args.shape, *shapes, *inputs], names)
    one = prepare()

    if len(shapes) == 1:
        start = time.perf_counter()
        with tqdm(total=2, desc=what, disable=not bars(args), leave=False, delay=BAR_DELAY) as bar:
            result = one(shapes[0], bars(args))
            bar.update(1)
            written = _save(args, result, stems[0], bar)
        _report(args, result, written, time.perf_counter() - start)
        record(args, written)
        return 0
    rows, files = [], []
    with Recording(args, files) as recording:
        for path, stem in tqdm(zip(shapes, stems), total=len(shapes), desc=what, unit="shape", disable=not bars(args),
                               delay=BAR_DELAY):
            start = time.perf_counter()
            try:
                check_shape_file(path)
                result = one(path, False)
                written = _save(args, result, stem, None)
            except Exception as exc:  # noqa: BLE001 - a shape that fails, for whatever reason, is reported and skipped
                message = " ".join(str(exc).split()) or type(exc).__name__
                if not isinstance(exc, _EXPECTED):
                    message = f"{type(exc).__name__}: {message} (unexpected)"
                message = message if path in message else f"{path}: {message}"
                if not args.quiet:
                    tqdm.write(f"cuboidlib {args.command}: skipped {message}", file=sys.stderr)
                rows.append({"shape": path, "status": "failed", "error": message,
                             "seconds": f"{time.perf_counter() - start:.2f}"})
                continue
            files += written
            found = warnings_of(result)
            for line in found:
                tqdm.write(f"warning: {line}", file=sys.stderr)
            if not args.quiet and (result.method or {}).get("up_auto"):
                tqdm.write(f"{path}: --up auto chose {frame_of(result)}")
            rows.append({"shape": path, "status": "ok", "result": Path(_written_json(written)).name,
                         "cuboids_used": result.num_existing, "cuboids": result.cuboids.num_cuboids,
                         "chamfer": f"{result.chamfer:.6g}", "frame": frame_of(result), "warning": " | ".join(found),
                         "seconds": f"{time.perf_counter() - start:.2f}"})
            recording.tick()
    files.append(write_summary(args.out, rows))
    record(args, files)
    failed = sum(r["status"] == "failed" for r in rows)
    warned = sum(bool(r.get("warning")) for r in rows)
    if not args.quiet:
        print(f"{len(rows) - failed} of {len(rows)} shapes written to {args.out}"
              + (f"; {failed} failed" if failed else "") + (f"; {warned} with warnings" if warned else "")
              + (f" (see {SUMMARY_FILE})" if failed or warned else "") + f"; summary: {files[-1]}")
    elif failed:
        print(f"cuboidlib {args.command}: {failed} of {len(rows)} shapes failed (see {files[-1]})", file=sys.stderr)
    return 1 if failed else 0


def _written_json(written: list) -> str:
    """The result JSON among the files one result wrote."""
    return next(str(f) for f in written if str(f).endswith(".json"))


def _save(args, result, stem: str | None, bar) -> list:
    """Write one result (cuboidlib.abstraction) into --out; returns the paths written."""
    if bar is not None:
        bar.set_description("writing files")
    written = result.save(args.out, stem=stem, formats=args.mesh_format, normalized=args.normalized)
    if bar is not None:
        bar.update(1)
        bar.close()  # before the summary is printed (closing again on leaving the caller's "with" is harmless)
    return list(written.values())


def warnings_of(result) -> list[str]:
    """The warnings of one result, one line each, naming the shape: the orientation check's, ``--up auto``'s when
    it could hardly tell up from down, and the network check's (:func:`cuboidlib.abstract`).

    Args:
        result: an :class:`~cuboidlib.results.Abstraction`.

    Returns:
        The lines (empty when nothing was found).
    """
    name = result.source or "the shape"
    lines = []
    check = (result.method or {}).get("up_check", {})
    if check.get("suggested"):
        up, scores = check["suggested"], check["chamfer"]
        lines.append(f"{name} looks like it is not +y up: with --up {up} the network reconstructs it "
                     f"{scores['y'] / scores[up]:.1f}x better; pass --up {up} (or --up auto), or --up y if it is "
                     "upright")
    auto = (result.method or {}).get("up_auto", {})
    if auto.get("upside_down_margin") is not None:
        from .abstraction import UPSIDE_DOWN_MARGIN  # imports torch: start-up time (already loaded here)

        if auto["upside_down_margin"] < UPSIDE_DOWN_MARGIN:
            lines.append(f"{name}: --up auto could hardly tell up from down (it kept {frame_of(result)}): check it, "
                         "and pass --up and --front if you know them")
    check = (result.method or {}).get("network_check", {})
    if check.get("warned"):
        from .network_check import NetworkVerdict, verdict_advice, verdict_reasons  # imports torch: start-up time

        verdict = NetworkVerdict.from_dict(check)
        lines.append(f"{name}: {verdict_reasons(verdict)}; {verdict_advice(verdict, command_line=True)}")
    elif check.get("unchecked"):
        lines.append(f"{name}: the network check could not run: {check['unchecked']}")
    return lines


def frame_of(result) -> str:
    """The frame a result's shape was read in, e.g. "up z, front -y" (the default: "up y, front z"), or with
    directions in the input's axes when ``--up auto`` found a frame between them: "up (0, 0.7071, 0.7071), ..."."""
    method = result.method or {}
    chosen = method.get("up_auto", {}).get("chosen") or {"up": method.get("up", "y"), "front": method.get("front", "z")}

    def named(axis) -> str:
        return axis if isinstance(axis, str) else "(" + ", ".join(f"{c:.4g}" for c in axis) + ")"

    return f"up {named(chosen['up'])}, front {named(chosen['front'])}"


#: What decided the frame ``--up auto`` chose (``method["up_auto"]["by"]``, :func:`cuboidlib.frames.choose_frame`).
_DECIDED_BY = {"axis": "the input's own axes", "ground": "the ground it stands on", "flat": "its flat area",
               "network": "the network's reconstruction"}


def _report(args, result, written: list, seconds: float) -> None:
    """The lines of a run over one shape: its warnings (stderr, even with --quiet), the frame --up auto chose, the
    cuboids used, the Chamfer distance and the files written."""
    for line in warnings_of(result):
        print(f"warning: {line}", file=sys.stderr)
    if args.quiet:
        return
    if (result.method or {}).get("up_auto"):
        record = result.method["up_auto"]
        print(f"--up auto chose {frame_of(result)} ({_DECIDED_BY.get(record['by'], record['by'])}; "
              f"{record['frames']} frames scored)")
    used, how = result.num_existing, result.chamfer_convention.describe().split(": ", 1)[1]
    print(f"{used} cuboid{'' if used == 1 else 's'} used of {result.cuboids.num_cuboids} | Chamfer distance "
          f"{result.chamfer:.4g} ({how}; on the normalised shape) | {seconds:.1f} s")
    print("wrote " + ", ".join(str(p) for p in written))


def csv_cell(value) -> str:
    """A value as a CSV cell that no spreadsheet runs as a formula: text starting with =, +, -, @, a tab or a
    carriage return gets a leading single quote (the usual defence against CSV injection).

    Args:
        value: any value; None is the empty cell.

    Returns:
        The cell's text.
    """
    text = "" if value is None else str(value)
    return "'" + text if text[:1] in ("=", "+", "-", "@", "\t", "\r") else text


def write_summary(folder, rows: list[dict]) -> Path:
    """SUMMARY_FILE in ``folder``: one row per shape (:data:`SUMMARY_COLUMNS`), every cell through :func:`csv_cell`.

    Args:
        folder: the output folder.
        rows: one dict per shape, keys among SUMMARY_COLUMNS.

    Returns:
        The file's path.
    """
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, SUMMARY_COLUMNS)
    writer.writeheader()
    writer.writerows({key: csv_cell(row.get(key)) for key in SUMMARY_COLUMNS} for row in rows)
    return write_text_atomic(Path(folder) / SUMMARY_FILE, text.getvalue())
