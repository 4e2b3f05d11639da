"""Training throughput of the course network (shapes per second), quiet and with a competing process.

A learner's laptop always has a browser and Jupyter running, so what matters is not only the speed of a
step on an idle machine but how much of it survives one busy process beside it. This script trains the
network of a committed course config (default: the chair's, ``data_samples/checkpoints/configs/chair.json``:
small model, batch 16, 1024 points) on random shapes and reports shapes per second for each layout:

* ``1x1``: one process, one thread;
* ``1x2``: one process, two threads (torch's intra-op parallelism);
* ``2x1``: two processes of one thread each, DistributedDataParallel over gloo (what
  ``torchrun --nproc_per_node=2 -m cuboidlib train`` does), each process half of the batch;
* ``auto``: one process whose thread count follows the cores that other processes leave free
  (:class:`cuboidlib.runs.CoreShare`, what ``cuboidlib train`` does by default). It warms up for at
  least 5 s, so that the count has settled.

Every layout uses the compiled kernels where they build, as a learner gets them; ``--python-code``
measures the PyTorch code alone (``CUBOIDLIB_COMPILED_KERNELS=0``).

``--busy`` repeats each layout with one extra process that spins on a core for the whole measurement.
``--env NAME=VALUE`` sets a variable for the training processes, for example the OpenMP runtime's
``OMP_WAIT_POLICY=PASSIVE`` (threads sleep instead of spinning while they wait) or ``GOMP_SPINCOUNT``.
Every layout runs in fresh subprocesses; the median over ``--repeats`` steps after ``--warmup`` is reported.

Example::

    python benchmarks/bench_training.py --layouts 1x1 1x2 2x1 --busy
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _variable(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name or not value:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE with both parts non-empty, got {text!r}")
    return name, value


def worker(spec: dict) -> None:
    """One process of a layout: train ``warmup + repeats`` steps and print the step times as JSON (rank 0)."""
    import torch
    import torch.nn.functional as F

    from cuboidlib.losses import total_loss
    from cuboidlib.model import CuboidAbstractionNet
    from cuboidlib.train_config import TrainConfig

    from cuboidlib.runs import CoreShare

    share = CoreShare() if spec["threads"] == "auto" else None
    if share is None:
        torch.set_num_threads(spec["threads"])
    world, rank = spec["world"], spec["rank"]
    if world > 1:
        import torch.distributed as dist

        dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{spec['port']}", rank=rank, world_size=world)
    config = TrainConfig.load_json(spec["config"])
    torch.manual_seed(0)
    model = CuboidAbstractionNet(config.model_config).train()
    net = model
    if world > 1:
        from torch.nn.parallel import DistributedDataParallel

        net = DistributedDataParallel(model)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    gen = torch.Generator().manual_seed(rank)
    per_process = config.batch_size // world
    normals = F.normalize(torch.randn(per_process, config.n_points, 3, generator=gen), dim=-1)
    points = 0.4 * normals
    loss_config = config.loss_config
    times = []
    began = time.perf_counter()
    warmup = spec["warmup"]
    i = 0
    while i < warmup + spec["repeats"]:
        if share is not None and i == warmup - 1 and time.perf_counter() - began < 5.0:
            warmup += 1  # the thread count settles within a few seconds
        if world > 1:
            dist.barrier()
        start = time.perf_counter()
        out = net(points)
        loss = total_loss(out, points, normals, loss_config, generator=gen).total
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        if world > 1:
            dist.barrier()
        if share is not None:
            share.step()
        if i >= warmup:
            times.append(time.perf_counter() - start)
        i += 1
    if rank == 0:
        print(json.dumps({"times": times, "batch": config.batch_size}))
    if world > 1:
        dist.destroy_process_group()


def run_layout(layout: str, busy: bool, args) -> dict:
    processes, threads = (1, "auto") if layout == "auto" else (int(x) for x in layout.split("x"))
    port = _free_port()
    spinner = None
    if busy:
        spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        procs = []
        for rank in range(processes):
            spec = {"threads": threads, "world": processes, "rank": rank, "port": port, "config": str(args.config),
                    "warmup": args.warmup, "repeats": args.repeats}
            env = {**os.environ, **({"CUBOIDLIB_COMPILED_KERNELS": "0"} if args.python_code else {}), **args.env}
            procs.append(subprocess.Popen([sys.executable, __file__, "--worker", json.dumps(spec)],
                                          stdout=subprocess.PIPE, text=True, cwd=ROOT, env=env))
        outputs = [p.communicate()[0] for p in procs]
        if any(p.returncode for p in procs):
            raise RuntimeError(f"layout {layout}: a worker failed")
    finally:
        if spinner is not None:
            spinner.kill()
            spinner.wait()
    result = json.loads(outputs[0].strip().splitlines()[-1])
    median = statistics.median(result["times"])
    return {"layout": layout, "busy": busy, "step_s": median, "shapes_per_s": result["batch"] / median}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=ROOT / "data_samples/checkpoints/configs/chair.json",
                        help="a course training config (model, batch size, points)")
    parser.add_argument("--layouts", nargs="+", default=["auto", "1x1", "1x2", "2x1"],
                        help="PROCESSESxTHREADS layouts, or auto, to measure (default: auto 1x1 1x2 2x1)")
    parser.add_argument("--python-code", action="store_true", help="without the compiled kernels")
    parser.add_argument("--busy", action="store_true", help="also measure each layout beside one busy process")
    parser.add_argument("--env", type=_variable, action="append", default=[], metavar="NAME=VALUE",
                        help="an environment variable for the training processes (repeatable), e.g. OMP_WAIT_POLICY=PASSIVE")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    args.env = dict(args.env)
    if args.worker:
        worker(json.loads(args.worker))
        return 0
    print(f"config {args.config.name}, {os.cpu_count()} CPUs, {'PyTorch code' if args.python_code else 'default kernels'};"
          f" median of {args.repeats} steps after {args.warmup}"
          + "".join(f"; {name}={value}" for name, value in args.env.items()))
    print(f"{'layout':>8} {'competing':>10} {'step (s)':>9} {'shapes/s':>9} {'vs quiet':>9}")
    quiet: dict[str, float] = {}
    for layout in args.layouts:
        for busy in ([False, True] if args.busy else [False]):
            r = run_layout(layout, busy, args)
            if not busy:
                quiet[layout] = r["step_s"]
            slow = f"{r['step_s'] / quiet[layout]:.2f}x" if layout in quiet else "-"
            print(f"{layout:>8} {'1 busy' if busy else 'none':>10} {r['step_s']:9.3f} {r['shapes_per_s']:9.1f} "
                  f"{slow:>9}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
