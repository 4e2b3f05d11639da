"""Seconds of ``cuboidlib.abstract`` and ``fit_cuboids`` on one shape: the orientation choices, and threads.

In one process, after a first call (the network loaded once into the file cache), the median of ``--repeats``
calls of ``abstract(MESH, model)`` with ``up="y"``, with the default orientation check (``up=None``) and with
``up="auto"``, and the ratios of the last two to the first. Then the same shape with one and with two torch
threads forced, against the default (``abstract`` and a one-shape fit choose one thread themselves), for
``abstract`` with a network and for the per-shape fit. ``--busy`` repeats the thread comparison beside one
process that spins on a core, as a browser or a second notebook would.

Example::

    python benchmarks/bench_abstract.py
    python benchmarks/bench_abstract.py --busy --repeats 5
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing as mp
import statistics
import time
import warnings
from pathlib import Path

import torch

import cuboidlib.abstraction as pipeline
import cuboidlib.fitting as fitting
from cuboidlib.fitting import FitConfig
from cuboidlib.io import load_point_cloud

ROOT = Path(__file__).resolve().parents[1]


def _median_seconds(call, repeats: int) -> float:
    call()  # first call: caches, the network, the compiled kernels
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _spin() -> None:
    while True:
        pass


@contextlib.contextmanager
def _threads_forced(count: int | None):
    """count threads for the whole call (None: the library's own choice)."""
    if count is None:
        yield
        return
    saved = torch.get_num_threads()
    chosen = (pipeline.torch_threads, fitting.torch_threads)
    pipeline.torch_threads = fitting.torch_threads = lambda _: contextlib.nullcontext()
    torch.set_num_threads(count)
    try:
        yield
    finally:
        pipeline.torch_threads, fitting.torch_threads = chosen
        torch.set_num_threads(saved)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", default=str(ROOT / "data_samples" / "meshes" / "chair_0.ply"))
    parser.add_argument("--model", default="chair")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--fit-steps", type=int, default=300, help="steps of the per-shape fit (default 300)")
    parser.add_argument("--busy", action="store_true", help="also time the threads beside one spinning process")
    args = parser.parse_args()
    warnings.simplefilter("ignore")

    print(f"abstract({Path(args.mesh).name}, {args.model!r}): median of {args.repeats} calls after a first one")
    base = None
    for up in ("y", None, "auto"):
        seconds = _median_seconds(lambda: pipeline.abstract(args.mesh, args.model, up=up), args.repeats)
        base = base or seconds
        print(f"  up={up!r:7s} {seconds:6.3f} s  ({seconds / base:.1f}x up='y')")

    cloud = load_point_cloud(args.mesh, 2048, seed=0)
    tasks = {
        "abstract, network, up='y'": lambda: pipeline.abstract(args.mesh, args.model, up="y"),
        f"fit_cuboids, one shape, {args.fit_steps} steps":
            lambda: fitting.fit_cuboids(cloud.points, cloud.normals, FitConfig(steps=args.fit_steps)),
    }
    loads = [False, True] if args.busy else [False]
    for busy in loads:
        spinner = mp.Process(target=_spin, daemon=True) if busy else None
        if spinner:
            spinner.start()
        try:
            print(f"threads, {'beside one busy process' if busy else 'quiet'} (torch default: {torch.get_num_threads()})")
            for name, call in tasks.items():
                row = []
                for count in (1, 2, None):
                    with _threads_forced(count):
                        row.append(_median_seconds(call, max(1, args.repeats // 2)))
                print(f"  {name:36s} 1 thread {row[0]:6.3f} s, 2 threads {row[1]:6.3f} s, default {row[2]:6.3f} s")
        finally:
            if spinner:
                spinner.terminate()


if __name__ == "__main__":
    main()
