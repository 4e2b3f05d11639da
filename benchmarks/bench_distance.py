"""Time forward + backward of the point-to-cuboid distances (cuboidlib.distance).

Prints the median (and fastest) time of one forward + backward pass, with gradients flowing to the
cuboid parameters as in training, for each distance variant and problem size. Example::

    python benchmarks/bench_distance.py
    python benchmarks/bench_distance.py --sizes 32x4096x16 --variants p2c nearest --repeats 11

Timings are only meaningful on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from cuboidlib.distance import chamfer_distance_to_cuboids, nearest_surface_distance, point_to_cuboid_distance
from cuboidlib.rotations import random_quaternions

VARIANTS = {
    "p2c": ("point_to_cuboid_distance, sigma_s=0.05", lambda x: point_to_cuboid_distance(*x["p2c"], sigma_s=0.05)),
    "p2c-sigma0": ("point_to_cuboid_distance, sigma_s=0", lambda x: point_to_cuboid_distance(*x["p2c"], sigma_s=0.0)),
    "p2c-novalidate": (
        "point_to_cuboid_distance, validate=False",
        lambda x: point_to_cuboid_distance(*x["p2c"], sigma_s=0.05, validate=False),
    ),
    "nearest": ("nearest_surface_distance", lambda x: nearest_surface_distance(*x["nearest"])),
    "chamfer": ("chamfer_distance_to_cuboids, n_samples=N", lambda x: chamfer_distance_to_cuboids(*x["nearest"])),
}


def parse_size(text: str) -> tuple[int, int, int]:
    try:
        b, n, m = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"size must look like BxNxM (e.g. 32x1024x16), got {text!r}") from exc
    return b, n, m


def make_inputs(b: int, n: int, m: int, dtype: torch.dtype, seed: int) -> dict:
    """Random points with unit normals and random cuboids whose parameters require gradients."""
    g = torch.Generator().manual_seed(seed)
    points = torch.randn(b, n, 3, generator=g, dtype=dtype) * 0.5
    normals = torch.nn.functional.normalize(torch.randn(b, n, 3, generator=g, dtype=dtype), dim=-1)
    centers = (torch.randn(b, m, 3, generator=g, dtype=dtype) * 0.3).requires_grad_(True)
    quaternions = random_quaternions(b, m, generator=g, dtype=dtype).requires_grad_(True)
    half_sizes = (0.05 + 0.3 * torch.rand(b, m, 3, generator=g, dtype=dtype)).requires_grad_(True)
    return {
        "p2c": (points, normals, centers, quaternions, half_sizes),
        "nearest": (points, centers, quaternions, half_sizes),
        "params": (centers, quaternions, half_sizes),
    }


def time_forward_backward(fn, inputs: dict, warmup: int, repeats: int) -> list[float]:
    times = []
    for i in range(warmup + repeats):
        for p in inputs["params"]:
            p.grad = None
        start = time.perf_counter()
        fn(inputs).mean().backward()
        if i >= warmup:
            times.append(time.perf_counter() - start)
    return times


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", type=parse_size, default=[(32, 1024, 16), (32, 4096, 16)],
                        help="problem sizes BxNxM (default: 32x1024x16 32x4096x16)")
    parser.add_argument("--variants", nargs="+", choices=sorted(VARIANTS), default=["p2c", "p2c-sigma0", "nearest"],
                        help="which distances to time (chamfer is much slower; add it explicitly)")
    parser.add_argument("--repeats", type=int, default=7, help="timed repetitions (median reported)")
    parser.add_argument("--warmup", type=int, default=2, help="untimed repetitions first")
    parser.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (default: torch's choice)")
    parser.add_argument("--dtype", choices=["float32", "float64"], default="float32")
    args = parser.parse_args(argv)
    if args.repeats < 1 or args.warmup < 0:
        parser.error("--repeats must be >= 1 and --warmup >= 0")
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    dtype = getattr(torch, args.dtype)

    print(f"torch {torch.__version__}, {torch.get_num_threads()} thread(s), {args.dtype}, "
          f"forward + backward to the cuboid parameters, median of {args.repeats} after {args.warmup} warm-up")
    header = f"{'variant':<42} {'B':>4} {'N':>6} {'M':>4} {'pairs':>9} {'median ms':>10} {'min ms':>8}"
    print(header)
    print("-" * len(header))
    for b, n, m in args.sizes:
        inputs = make_inputs(b, n, m, dtype, seed=0)
        for name in args.variants:
            label, fn = VARIANTS[name]
            times = time_forward_backward(fn, inputs, args.warmup, args.repeats)
            print(f"{label:<42} {b:>4} {n:>6} {m:>4} {b * n * m:>9} "
                  f"{1000 * statistics.median(times):>10.1f} {1000 * min(times):>8.1f}")


if __name__ == "__main__":
    main()
