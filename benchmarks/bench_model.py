"""Time one training step of CuboidAbstractionNet on the CPU and measure its peak memory.

A step is: forward, loss, backward, Adam update. Every configuration (points per cloud x variant)
runs in a fresh Python subprocess, so that its peak resident memory (ru_maxrss) is its own.
After ``--warmup`` steps, the median of ``--repeats`` steps is reported.

The loss is the training loss, cuboidlib.losses.total_loss with the paper's settings (LossConfig():
reconstruction with the sampled point-to-cuboid distance, compactness, existence and KL terms,
Eq. (4)-(9)). The inputs are random points on a sphere with their normals (the timing does not
depend on the shapes).

Variants (all give the same results): ``default`` is what a learner gets without asking (the fast layers,
with the compiled kernels of :mod:`cuboidlib.kernels` wherever a C++ compiler can build them); ``fast`` the
fast layers on the PyTorch code alone (``CUBOIDLIB_COMPILED_KERNELS=0``); ``compiled`` the fast layers with
the kernels required; ``readable`` the readable layers (``fast=False``). The default run compares
``default``, ``fast`` and ``readable``. ``--profile`` prints a torch.profiler table of one step per
configuration.

``--floor`` times, beside each step, the work that every implementation of this step has to do: the
kNN graphs of the EdgeConv layers (pairwise distances and the top-k selection,
``cuboidlib.neighbors.knn_indices``; the authors' code also selects with ``torch.topk``) and the
matrix products, chunk by chunk as ``FastEdgeConv`` runs them: the per-edge layer's forward product
and the two products of its gradient (with respect to its input and to its weights) in each EdgeConv,
and the global feature's linear layer. Everything else in a step is elementwise work, gathers,
scatters and small layers, which a fused kernel could fold into the products' memory traffic. The sum
is a lower bound for the step of any implementation that builds the graphs with ``torch.topk`` and
computes the layers with matrix products. (``FastEdgeConv`` does one product more per chunk than the
bound counts: its backward pass recomputes the forward product instead of storing (B, N, k, C)
tensors.)

Example::

    python benchmarks/bench_model.py --batch 32 --points 1024 4096 --repeats 7
    python benchmarks/bench_model.py --points 1024 --variant fast readable --floor
    python benchmarks/bench_model.py --points 1024 --variant default fast readable --repeats 7
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time

import torch
import torch.nn.functional as F

from cuboidlib import kernels
from cuboidlib.losses import LossConfig, total_loss
from cuboidlib.edgeconv_fast import FastEdgeConv
from cuboidlib.model import CuboidAbstractionNet, ModelConfig
from cuboidlib.neighbors import knn_indices


def _setup(spec: dict) -> ModelConfig:
    """Set the worker's threads and return the configuration's ModelConfig."""
    if spec["threads"]:
        torch.set_num_threads(spec["threads"])
    if spec["config"] == "paper":
        return ModelConfig(num_cuboids=spec["cuboids"])
    return ModelConfig.small(num_cuboids=spec["cuboids"])


def _in_subprocess(spec: dict) -> tuple[dict | None, subprocess.CompletedProcess]:
    """Run one worker in a fresh Python process: (its figures, or None if it failed; the process)."""
    proc = subprocess.run([sys.executable, __file__, "--worker", json.dumps(spec)], capture_output=True, text=True)
    return (json.loads(proc.stdout.strip().splitlines()[-1]) if proc.returncode == 0 else None), proc


def run_worker(spec: dict) -> dict:
    """One configuration: build the model, warm up, time ``repeats`` steps; returns the figures."""
    config = _setup(spec)
    torch.manual_seed(0)
    if spec["variant"] == "compiled":
        kernels.enable()
    elif spec["variant"] != "default":  # the Python code; "default" is what a learner gets (kernels where they build)
        kernels.disable()
    model = CuboidAbstractionNet(config, fast=spec["variant"] != "readable").train()
    if spec["edges_per_chunk"]:
        for module in model.modules():
            if isinstance(module, FastEdgeConv):
                module.edges_per_chunk = spec["edges_per_chunk"]
    optimizer = torch.optim.Adam(model.parameters(), lr=6e-4)
    gen = torch.Generator().manual_seed(0)
    normals = F.normalize(torch.randn(spec["batch"], spec["points"], 3, generator=gen), dim=-1)
    points = 0.8 * normals
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss

    def step() -> tuple[float, float]:
        start, start_cpu = time.perf_counter(), time.process_time()
        optimizer.zero_grad(set_to_none=True)
        out = model(points)
        loss = total_loss(out, points, normals, LossConfig(), generator=gen).total
        loss.backward()
        optimizer.step()
        return time.perf_counter() - start, time.process_time() - start_cpu

    for _ in range(spec["warmup"]):
        step()
    times, cpu_times = zip(*(step() for _ in range(spec["repeats"])))
    result = {
        "median_s": statistics.median(times),
        "min_s": min(times),
        "cpu_s": statistics.median(cpu_times),
        "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "setup_mib": rss_before / 1024,
        "parameters": sum(p.numel() for p in model.parameters()),
        "threads": torch.get_num_threads(),
    }
    if spec["profile"]:
        from torch.profiler import ProfilerActivity, profile

        with profile(activities=[ProfilerActivity.CPU]) as prof:
            step()
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=25), file=sys.stderr)
    return result


def floor_worker(spec: dict) -> dict:
    """Median seconds of the kNN graphs and of the matrix products of one step (see ``--floor``)."""
    config = _setup(spec)
    batch, n, k = spec["batch"], spec["points"], config.k
    gen = torch.Generator().manual_seed(0)
    # the graph of the first layer is that of the 3-D points, each later one that of the previous features
    graph_inputs = [torch.randn(batch, n, 3, generator=gen)]
    graph_inputs += [torch.randn(batch, n, c, generator=gen) for c in config.edge_dims[:-1]]
    rows = FastEdgeConv(3, 8, k, edges_per_chunk=spec["edges_per_chunk"])._chunk_rows(torch.device("cpu"))
    chunks = []  # (edge values of one chunk, second-layer weights, how many such chunks a layer has)
    for width in config.edge_dims:
        full, rest = divmod(batch * n, rows)
        W2 = torch.randn(width, width, generator=gen)
        chunks += [(torch.randn(s * k, width, generator=gen), W2, count)
                   for s, count in ((rows, full), (rest, 1)) if s and count]
    f = torch.randn(batch, n, config.point_feature_dim, generator=gen)
    W = torch.randn(config.global_dim, config.point_feature_dim, generator=gen)

    def graphs() -> None:
        for x in graph_inputs:
            knn_indices(x, k)

    def edge_products() -> None:
        for v, W2, count in chunks:
            for _ in range(count):
                gh = v @ W2.T  # forward: h = W2 v on every edge of the chunk (gh: its gradient's stand-in)
                gh @ W2  # gradient with respect to v
                W2.clone().addmm_(gh.T, v)  # gradient with respect to W2

    def global_products() -> None:
        for b in range(batch):
            W @ f[b].T  # the global feature's linear layer on every point (its max over points)

    parts = {"kNN graphs": graphs, "EdgeConv products": edge_products, "global feature products": global_products}
    result = {}
    for name, work in parts.items():
        for _ in range(spec["warmup"]):
            work()
        times = []
        for _ in range(spec["repeats"]):
            start = time.perf_counter()
            work()
            times.append(time.perf_counter() - start)
        result[name] = statistics.median(times)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--points", type=int, nargs="+", default=[1024, 4096])
    parser.add_argument("--cuboids", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=7, help="timed steps per configuration (median reported)")
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--variant", nargs="+", choices=["default", "fast", "compiled", "readable"],
                        default=["default", "fast", "readable"])
    parser.add_argument("--config", choices=["paper", "small"], default="paper", help="ModelConfig() or .small()")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    parser.add_argument("--edges-per-chunk", type=int, default=0, help="EdgeConv chunk size (0: the default)")
    parser.add_argument("--profile", action="store_true", help="print a torch.profiler table per configuration")
    parser.add_argument("--floor", action="store_true",
                        help="also time the kNN graphs and the matrix products of a step alone (a lower bound)")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args.worker:
        spec = json.loads(args.worker)
        print(json.dumps(floor_worker(spec) if spec.get("floor_only") else run_worker(spec)))
        return 0

    print(f"CuboidAbstractionNet training step (forward + loss + backward + Adam), {args.config} config, CPU")
    print("loss: cuboidlib.losses.total_loss with the paper's LossConfig() (Eq. (4)-(9))")
    print(f"batch {args.batch}, M = {args.cuboids}, median of {args.repeats} steps after {args.warmup} warm-up")
    print("median/min s: elapsed time per step; cpu s: CPU time per step summed over threads")
    print(
        f"{'points':>7} {'variant':>10} {'median s':>9} {'min s':>7} {'cpu s':>7} {'peak MiB':>9} {'params':>10} "
        f"{'threads':>7}"
    )
    failed = False
    for n in args.points:
        for variant in args.variant:
            spec = dict(
                batch=args.batch,
                points=n,
                cuboids=args.cuboids,
                repeats=args.repeats,
                warmup=args.warmup,
                variant=variant,
                config=args.config,
                threads=args.threads,
                edges_per_chunk=args.edges_per_chunk,
                profile=args.profile,
            )
            r, proc = _in_subprocess(spec)
            if args.profile:
                print(proc.stderr)
            if r is None:
                failed = True
                print(f"{n:>7} {variant:>10}   failed: {proc.stderr.strip().splitlines()[-1:]}")
                continue
            print(
                f"{n:>7} {variant:>10} {r['median_s']:>9.3f} {r['min_s']:>7.3f} {r['cpu_s']:>7.3f} "
                f"{r['peak_mib']:>9.0f} {r['parameters']:>10,} {r['threads']:>7}"
            )
        if args.floor:
            parts, proc = _in_subprocess(dict(spec, floor_only=True))
            if parts is None:
                failed = True
                print(f"{n:>7} {'floor':>10}   failed: {proc.stderr.strip().splitlines()[-1:]}")
                continue
            for name, seconds in parts.items():
                print(f"{n:>7} {'floor':>10} {seconds:>9.3f}   {name}")
            print(f"{n:>7} {'floor':>10} {sum(parts.values()):>9.3f}   sum: a lower bound for the step")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
