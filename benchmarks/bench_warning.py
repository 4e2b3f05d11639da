"""The thresholds of ``abstract``'s network check (:data:`cuboidlib.abstraction.REFERENCE_RATIO` and
:data:`~cuboidlib.abstraction.LATENT_DISTANCE`), measured.

For every committed network, ``abstract(points, net, up="y", check=True)`` records two figures: the ratio of
the network's Chamfer distance to that of k-means boxes with as many boxes, and the latent distance of the shape
from the network's training shapes. On the first ``--per-split`` shapes of its own category's test split
(:func:`cuboidlib.train.course_config` + :func:`cuboidlib.dataset.load_splits`) the check should stay silent.
Off its category (``--cross`` shapes of each other test split) and on the thin-structure set
(:func:`cuboidlib.thin_shapes.thin_structure_set`, each kind with the network of
``bench_real_shapes.THIN_NETWORK``), the per-shape fit (``model=None``) runs too, and the check should speak
where the network is at least 1.5x worse than the fit. Prints both figures' spread, the shares at the library's
thresholds and at a few others, and the seconds of the check.

Example::

    python benchmarks/bench_reference_check.py --per-split 100 --cross 6
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from bench_real_shapes import THIN_NETWORK
from cuboidlib.abstraction import LATENT_DISTANCE, REFERENCE_RATIO, abstract
from cuboidlib.dataset import load_splits
from cuboidlib.thin_shapes import thin_structure_set
from cuboidlib.train import course_config

CATEGORIES = ("chair", "table", "airplane", "animal")


def _test_split(category: str):
    return load_splits(course_config(category))["test"]


def _check(shape: np.ndarray, net) -> tuple[float, float, object]:
    """(ratio to k-means, latent distance, the result) of the network on one (N, 6) shape."""
    result = abstract(shape, net, up="y", seed=0, check=True)
    check = result.method["reference_check"]
    return check["ratio"], check["latent_distance"], result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--per-split", type=int, default=100, help="in-category shapes per test split")
    parser.add_argument("--cross", type=int, default=6, help="shapes per (network, other category) pair")
    parser.add_argument("--no-thin", action="store_true", help="leave out the thin-structure set")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    splits = {c: _test_split(c) for c in CATEGORIES}
    own, off, seconds = [], [], []  # own: (ratio, latent); off: (ratio, latent, network / fit, where)

    def off_category(shape, net, where):
        ratio, latent, result = _check(shape, net)
        fit = abstract(shape, None, seed=0)
        off.append((ratio, latent, result.chamfer / fit.chamfer, where))
        print(f"{where}: ratio to k-means {ratio:.2f}, latent distance {latent:.1f}, to the fit "
              f"{result.chamfer / fit.chamfer:.2f}", flush=True)

    for net_cat in CATEGORIES:  # networks by name: their checkpoints hold the latent statistics
        net = net_cat
        for shape_cat, split in splits.items():
            count = args.per_split if shape_cat == net_cat else args.cross
            for i in range(min(count, len(split.points))):
                shape = np.concatenate([np.asarray(split.points[i]), np.asarray(split.normals[i])], axis=1)
                if shape_cat != net_cat:
                    off_category(shape, net, f"{net_cat} network on {shape_cat} {i}")
                    continue
                start = time.perf_counter()
                ratio, latent, _ = _check(shape, net)
                seconds.append(time.perf_counter() - start)
                own.append((ratio, latent, net_cat))
        mine = np.array([(r, d) for r, d, c in own if c == net_cat])
        print(f"{net_cat} network on its test split: {len(mine)} shapes; ratio to k-means median "
              f"{np.median(mine[:, 0]):.2f}, max {mine[:, 0].max():.2f}; latent distance median "
              f"{np.median(mine[:, 1]):.1f}, 99th percentile {np.percentile(mine[:, 1], 99):.1f}, max "
              f"{mine[:, 1].max():.1f}", flush=True)
    if not args.no_thin:
        for name, (points, normals) in thin_structure_set().items():
            net_cat = THIN_NETWORK[name.split("_")[0]]
            off_category(np.concatenate([points, normals], axis=1), net_cat, f"{net_cat} network on {name}")
    ratios, latents = np.array([r for r, _, _ in own]), np.array([d for _, d, _ in own])
    bad = [(r, d, where) for r, d, f, where in off if f >= 1.5]
    thin = [b for b in bad if "_" in b[2]]
    print(f"in-category shapes: {len(own)}; off-category and thin shapes: {len(off)}, of which {len(bad)} "
          f"({len(thin)} thin) have the network >= 1.5x worse than the fit")
    for ratio_t, latent_t in sorted({(REFERENCE_RATIO, LATENT_DISTANCE), (REFERENCE_RATIO, None), (1.8, None),
                                     (REFERENCE_RATIO, 11.0), (REFERENCE_RATIO, 13.0)}, key=str):
        mark = " (the library's)" if (ratio_t, latent_t) == (REFERENCE_RATIO, LATENT_DISTANCE) else ""
        warned = lambda r, d: r > ratio_t or (latent_t is not None and d > latent_t)  # noqa: E731
        silent = np.mean([not warned(r, d) for r, d in zip(ratios, latents)])
        spoke = np.mean([warned(r, d) for r, d, _ in bad]) if bad else float("nan")
        spoke_thin = np.mean([warned(r, d) for r, d, _ in thin]) if thin else float("nan")
        print(f"ratio > {ratio_t:.2f}" + (f" or latent > {latent_t:.1f}" if latent_t else "") + f"{mark}: silent "
              f"on {silent:.1%} in-category; warns on {spoke:.1%} of the shapes >= 1.5x worse than the fit "
              f"(thin set: {spoke_thin:.1%})")
    print(f"abstract(up='y') with the check: median {np.median(seconds):.3f} s")


if __name__ == "__main__":
    main()
