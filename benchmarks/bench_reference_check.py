"""The threshold of ``abstract``'s network check (:data:`cuboidlib.abstraction.REFERENCE_RATIO`), measured.

For every committed network and the first ``--per-split`` shapes of each category's test split
(:func:`cuboidlib.train.course_config` + :func:`cuboidlib.dataset.load_splits`), ``abstract(points, net,
up="y")`` and its recorded ratio (network Chamfer / Chamfer of k-means boxes with as many boxes). On its
own category it should stay silent; off its category (``--cross`` shapes per pair) the per-shape fit
(``model=None``) is run too, and the check should speak where the network is at least 1.5x worse than the fit.
Prints the share of silent in-category shapes and of warned cross-category shapes, at the library's
threshold and at a few others, and the seconds of the check.

Example::

    python benchmarks/bench_reference_check.py --per-split 200 --cross 10
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from cuboidlib.abstraction import REFERENCE_RATIO, abstract
from cuboidlib.applications import load_trained_model
from cuboidlib.dataset import load_splits
from cuboidlib.train import course_config

CATEGORIES = ("chair", "table", "airplane", "animal")


def _test_split(category: str):
    config = course_config(category)
    return load_splits(getattr(config, "data", config))["test"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--per-split", type=int, default=200, help="in-category shapes per test split")
    parser.add_argument("--cross", type=int, default=10, help="shapes per (network, other category) pair")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    splits = {c: _test_split(c) for c in CATEGORIES}
    nets = {c: load_trained_model(c, "cpu") for c in CATEGORIES}
    own, cross, seconds = [], [], []
    for net_cat, (net, state, path) in nets.items():
        for shape_cat, split in splits.items():
            count = args.per_split if shape_cat == net_cat else args.cross
            for i in range(min(count, len(split.points))):
                shape = np.concatenate([np.asarray(split.points[i]), np.asarray(split.normals[i])], axis=1)
                start = time.perf_counter()
                result = abstract(shape, net, up="y", seed=0, check=True)
                seconds.append(time.perf_counter() - start)
                ratio = result.method["reference_check"]["ratio"]
                if shape_cat == net_cat:
                    own.append(ratio)
                else:
                    fit = abstract(shape, None, seed=0)
                    cross.append((ratio, result.chamfer / fit.chamfer))
                    print(f"{net_cat} network on {shape_cat} {i}: ratio to k-means {ratio:.2f}, to the fit "
                          f"{result.chamfer / fit.chamfer:.2f}", flush=True)
        mine = np.array(own[-min(args.per_split, len(splits[net_cat].points)):])
        print(f"{net_cat} network on its test split: {len(mine)} shapes, ratio to k-means median "
              f"{np.median(mine):.2f}, 99th percentile {np.percentile(mine, 99):.2f}, max {mine.max():.2f}; above "
              f"{REFERENCE_RATIO}: {(mine > REFERENCE_RATIO).sum()}", flush=True)
    own = np.array(own)
    print(f"in-category shapes: {len(own)}; ratio to k-means: median {np.median(own):.2f}, "
          f"99th percentile {np.percentile(own, 99):.2f}, max {own.max():.2f}")
    bad = np.array([r for r, f in cross if f >= 1.5])
    print(f"cross-category shapes: {len(cross)}, of which {len(bad)} have the network >= 1.5x worse than the fit")
    for threshold in sorted({1.3, 1.4, REFERENCE_RATIO, 1.6, 1.8, 2.0}):
        mark = " (REFERENCE_RATIO)" if threshold == REFERENCE_RATIO else ""
        spoke = f"{(bad > threshold).mean():.1%}" if len(bad) else "n/a"
        print(f"threshold {threshold:.2f}{mark}: silent on {(own <= threshold).mean():.1%} in-category, warns on "
              f"{spoke} of the cross-category shapes >= 1.5x worse than the fit")
    print(f"abstract(up='y') with the check: median {np.median(seconds):.3f} s")


if __name__ == "__main__":
    main()
