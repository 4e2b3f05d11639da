"""Does ``abstract(refine=...)`` lower the Chamfer distance? Per shape, the network's and the refined result's.

On the first ``--per-split`` shapes of every category's test split (each with its own network) and on the
thin-structure set (:func:`cuboidlib.thin_shapes.thin_structure_set`, with the networks of
``bench_real_shapes.THIN_NETWORK``): ``abstract(shape, net, up="y")`` and the same with ``refine=--steps``.
Prints, per group, on how many shapes the refinement lowered the Chamfer distance (course convention,
seed 0), on how many it kept the network's cuboids (``method["refine"]["kept"]``), and the median ratio.

Example::

    python benchmarks/bench_refine.py --per-split 10 --steps 300
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from cuboidlib.abstraction import abstract
from cuboidlib.applications import load_trained_model
from cuboidlib.dataset import load_splits
from cuboidlib.thin_shapes import thin_structure_set
from cuboidlib.train_config import course_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_real_shapes import THIN_NETWORK  # noqa: E402

CATEGORIES = ("chair", "table", "airplane", "animal")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--per-split", type=int, default=10, help="shapes of each test split (default 10)")
    parser.add_argument("--steps", type=int, default=300, help="refinement steps (default 300)")
    parser.add_argument("--skip-thin", action="store_true", help="the test splits only")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    nets = {c: load_trained_model(c, "cpu")[0] for c in CATEGORIES}
    groups: dict[str, list] = {}
    for cat in CATEGORIES:
        config = course_config(cat)
        split = load_splits(getattr(config, "data", config))["test"]
        groups[f"{cat} test split"] = [(np.concatenate([split.points[i], split.normals[i]], axis=1), cat)
                                       for i in range(min(args.per_split, len(split.points)))]
    if not args.skip_thin:
        groups["thin-structure set"] = [(np.concatenate(pn, axis=1), THIN_NETWORK[name.split("_")[0]])
                                        for name, pn in thin_structure_set().items()]
    total_lowered = total = 0
    for group, shapes in groups.items():
        ratios, kept, seconds = [], 0, []
        for shape, cat in shapes:
            net = abstract(shape, nets[cat], up="y", seed=0, check=False)
            start = time.perf_counter()
            ref = abstract(shape, nets[cat], up="y", seed=0, check=False, refine=args.steps)
            seconds.append(time.perf_counter() - start)
            ratios.append(ref.chamfer / net.chamfer)
            kept += ref.method["refine"]["kept"] == "network"
        ratios = np.array(ratios)
        lowered = int((ratios < 1).sum())
        total_lowered, total = total_lowered + lowered, total + len(ratios)
        print(f"{group}: {len(ratios)} shapes, refine={args.steps} lowered the Chamfer distance on {lowered} "
              f"({lowered / len(ratios):.0%}), raised it on {int((ratios > 1).sum())}, kept the network's cuboids on "
              f"{kept}; refined / network median {np.median(ratios):.2f}, worst {ratios.max():.2f}; "
              f"median {np.median(seconds):.1f} s", flush=True)
    print(f"all: lowered on {total_lowered} of {total} ({total_lowered / total:.0%})")


if __name__ == "__main__":
    main()
