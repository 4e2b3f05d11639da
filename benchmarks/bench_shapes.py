"""Speed of the procedural collections and accuracy of normal estimation on them.

Prints, per category:
* the time to generate a collection of ``--shapes`` shapes of ``--points`` points (no cache),
  in shapes per second, and how its shapes spread over the coarse structures;
* for ``--normal-shapes`` shapes, the error of :func:`cuboidlib.normals.estimate_normals` against
  the exact normals: median and mean unoriented angle (PCA quality), the share of points whose
  estimated normal points inwards (flip rate, orientation quality), the flip rate among points
  whose line is within 30 degrees (where the sign is meaningful), and the time per shape.

Usage: ``python benchmarks/bench_shapes.py [--shapes 1000] [--points 2048] [--normal-shapes 20]``.
The target is under 60 s for 1000 shapes of 2048 points of one category. Timings depend on the
machine's load; run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from cuboidlib.normals import estimate_normals, normal_errors
from cuboidlib.shapes import CATEGORIES, STRUCTURES, make_collection


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", type=int, default=1000)
    parser.add_argument("--points", type=int, default=2048)
    parser.add_argument("--normal-shapes", type=int, default=20)
    parser.add_argument("--threads", type=int, default=1, help="torch threads for normal estimation")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    print(f"Generation: {args.shapes} shapes x {args.points} points per category (cache off)")
    print(f"{'category':<10}{'seconds':>9}{'shapes/s':>10}  coarse structures (count)")
    total = 0.0
    collections = {}
    for category in CATEGORIES:
        t0 = time.perf_counter()
        coll = make_collection(category, args.shapes, args.points, seed=0, use_cache=False)
        dt = time.perf_counter() - t0
        total += dt
        collections[category] = coll
        counts = np.bincount(coll.structure_ids, minlength=len(STRUCTURES[category]))
        spread = ", ".join(f"{name} {c}" for name, c in zip(STRUCTURES[category], counts))
        print(f"{category:<10}{dt:9.1f}{args.shapes / dt:10.1f}  {spread}")
    print(f"{'all four':<10}{total:9.1f}{4 * args.shapes / total:10.1f}")

    print(f"\nNormal estimation (PCA k=16 + visibility orientation) on {args.normal_shapes} shapes "
          f"x {args.points} points per category")
    print(f"{'category':<10}{'median deg':>11}{'mean deg':>10}{'flipped %':>10}{'flipped % (<30 deg)':>21}{'s/shape':>9}")
    for category in CATEGORIES:
        coll = collections[category]
        angles, flips, dt = [], [], 0.0
        for i in range(min(args.normal_shapes, len(coll))):
            t0 = time.perf_counter()
            est = estimate_normals(coll.points[i])
            dt += time.perf_counter() - t0
            a, f = normal_errors(est, coll.normals[i])
            angles.append(a)
            flips.append(f)
        a, f = np.concatenate(angles), np.concatenate(flips)
        good = a < 30
        print(f"{category:<10}{np.median(a):11.1f}{a.mean():10.1f}{100 * f.mean():10.1f}"
              f"{100 * f[good].mean():21.1f}{dt / len(angles):9.2f}")


if __name__ == "__main__":
    main()
