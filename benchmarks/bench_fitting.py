"""Time per-shape fitting (cuboidlib.fitting.fit_cuboids) on the committed sample point clouds.

Every point cloud in data_samples/points/ (2048 points with normals, three per category) is fitted
with the default FitConfig (M = 16 slots, 300 Adam steps, the normal-aware distance of Eq. 5 and the
averaged compactness) after one untimed warm-up fit. Prints each shape's time and number of
cuboids, then the median, for each requested thread count.

Example::

    python benchmarks/bench_fitting.py --threads 1 2
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

from cuboidlib.fitting import FitConfig, fit_cuboids
from cuboidlib.io import read_point_cloud

SAMPLES = Path(__file__).resolve().parent.parent / "data_samples" / "points"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[torch.get_num_threads()],
                        help="torch thread counts to compare (default: torch's current setting)")
    parser.add_argument("--steps", type=int, default=FitConfig().steps, help="Adam steps per fit (default: 300)")
    args = parser.parse_args()
    clouds = {p.stem: read_point_cloud(p) for p in sorted(SAMPLES.glob("*.ply"))}
    if not clouds:
        raise SystemExit(f"no point clouds in {SAMPLES}")
    config = FitConfig(steps=args.steps)
    print(f"fit_cuboids, FitConfig(steps={config.steps}, num_cuboids={config.num_cuboids}), "
          f"{len(clouds)} shapes from {SAMPLES}")
    for threads in args.threads:
        torch.set_num_threads(threads)
        first = next(iter(clouds.values()))
        fit_cuboids(torch.as_tensor(first.points), torch.as_tensor(first.normals), config)  # warm-up
        times = []
        for name, cloud in clouds.items():
            start = time.perf_counter()
            result = fit_cuboids(torch.as_tensor(cloud.points), torch.as_tensor(cloud.normals), config)
            times.append(time.perf_counter() - start)
            print(f"  threads {threads}  {name:<12} {len(cloud.points)} points  {times[-1]:6.2f} s  "
                  f"{int(result.num_existing()[0])} cuboids")
        print(f"threads {threads}: median {statistics.median(times):.2f} s per shape "
              f"(min {min(times):.2f}, max {max(times):.2f})")


if __name__ == "__main__":
    main()
