"""Time the whole course as a learner runs it: every lesson top to bottom in a fresh kernel.

Each notebook in notebooks/ (the lessons and the optional appendices 04b and 09b; not the solutions) is executed from a fresh Python kernel (nbclient, the engine of
``jupyter nbconvert --execute``) in its own folder, as the learner opens it. The committed files
are not touched: the executed copies are discarded. Prints each lesson's wall time, then the total.
Lesson 04 leaves its training run in ``notebooks/runs/lesson04_chair/`` and the appendix 04b reads it back,
as for a learner who runs the lessons in order; a ``notebooks/runs/`` left by an earlier execution would
make lesson 04 read its run back too, so the benchmark refuses to start while it exists (move it away, or
time a second pass with ``--reuse-runs``). The procedural shapes are generated into a fresh, temporary cache
(``CUBOIDLIB_CACHE``), as on a first pass; ``--warm-cache`` uses your cache instead.

Example::

    python benchmarks/bench_course.py                 # all lessons
    python benchmarks/bench_course.py --lessons 01 06  # the lessons whose names start with 01 or 06
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lessons", nargs="+", metavar="PREFIX",
                        help="only the notebooks whose names start with these prefixes (default: all)")
    parser.add_argument("--timeout", type=int, default=900, help="seconds allowed per cell (default 900)")
    parser.add_argument("--reuse-runs", action="store_true",
                        help="time the course with the training runs an earlier execution left in notebooks/runs/")
    parser.add_argument("--warm-cache", action="store_true",
                        help="use your shape cache (CUBOIDLIB_CACHE or ~/.cache/cuboidlib) instead of an empty one")
    args = parser.parse_args()
    runs = NOTEBOOKS / "runs"
    if runs.exists() and not args.reuse_runs:
        raise SystemExit(f"{runs} holds the training runs of an earlier execution, which the lessons would read back "
                         "instead of training; move it away to time a first pass, or pass --reuse-runs")
    paths = sorted(NOTEBOOKS.glob("[0-9][0-9]*_*.ipynb"))  # the lessons and the appendices, not solutions/
    if args.lessons:
        paths = [p for p in paths if p.name.startswith(tuple(args.lessons))]
    if not paths:
        raise SystemExit(f"no lesson matches {args.lessons} in {NOTEBOOKS}")
    cache = None if args.warm_cache else tempfile.TemporaryDirectory(prefix="bench_course_cache_")
    if cache is not None:
        os.environ["CUBOIDLIB_CACHE"] = cache.name  # the kernels inherit it
    print(f"{len(paths)} lessons, each from a fresh kernel; {os.cpu_count()} CPUs; "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}; shape cache "
          f"{'yours' if cache is None else 'empty at the start'}")
    total = 0.0
    for path in paths:
        nb = nbformat.read(path, as_version=4)
        client = NotebookClient(nb, timeout=args.timeout, kernel_name="python3",
                                resources={"metadata": {"path": str(NOTEBOOKS)}})
        start = time.perf_counter()
        client.execute()
        seconds = time.perf_counter() - start
        total += seconds
        print(f"  {path.name:<36} {seconds:6.1f} s")
    print(f"whole course: {total / 60:.1f} min ({total:.0f} s)")


if __name__ == "__main__":
    main()
