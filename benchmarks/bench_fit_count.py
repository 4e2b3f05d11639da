"""How the per-shape fit chooses its number of cuboids: the paper's rule against the Chamfer distance's.

``FitConfig(count="portion")`` keeps the cuboids that hold more than eps_ext of the points (Sec. 3.4.3);
``count="chamfer"`` then splits and merges them by the Chamfer distance (:mod:`cuboidlib.counting`), the
default of ``abstract(shape, None)`` and ``cuboidlib fit``. Both run through ``abstract(points, None)``
(the fit, then its final phase on the two-sided distance), on:

* the first ``--shapes`` procedural chairs and tables of the committed networks' test split (2048 points,
  seed 0), scored by the cuboids per leg instance and the leg instances per leg cuboid
  (:func:`cuboidlib.metrics.part_concision`; 1 and 1 when each leg has a cuboid of its own), the Chamfer
  distance and the cuboid count;
* the thin-structure set (:func:`cuboidlib.thin_shapes.thin_structure_set`), against the best of ``--seeds``
  k-means boxes with as many boxes (:func:`cuboidlib.baseline.fit_cluster_boxes`).

Chamfer distances x1000 in the course's convention, on the normalised shapes; seconds are wall time of one
``abstract`` call on one thread.

Example::

    python benchmarks/bench_fit_count.py                  # 10 chairs, 10 tables, the thin-structure set
    python benchmarks/bench_fit_count.py --shapes 4 --no-thin
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from cuboidlib.abstraction import abstract
from cuboidlib.baseline import fit_cluster_boxes
from cuboidlib.dataset import split_indices
from cuboidlib.files import write_text_atomic
from cuboidlib.fitting import FitConfig
from cuboidlib.metrics import ChamferConvention, cuboid_chamfer_distance, part_concision
from cuboidlib.shapes import PART_NAMES, make_shape
from cuboidlib.thin_shapes import thin_structure_set

COUNTS = ("portion", "chamfer")
#: The committed networks' data: 1000 shapes a category, split 70/10/20 with seed 0.
TEST_SPLIT = split_indices(1000, (0.7, 0.1, 0.2), 0)["test"]


def fit(points: np.ndarray, normals: np.ndarray, count: str):
    """``abstract(points, None)`` with the fit's count rule, and its seconds."""
    start = time.perf_counter()
    result = abstract(np.concatenate([points, normals], axis=1), None, seed=0, up="y",
                      fit_config=FitConfig(count=count))
    return result, time.perf_counter() - start


def kmeans_chamfer(points: np.ndarray, normals: np.ndarray, boxes: int, seeds: int) -> float:
    """The best Chamfer distance of k-means boxes (``boxes`` of them) over ``seeds`` seeds, normalised points."""
    p, n = torch.as_tensor(points, dtype=torch.float32), torch.as_tensor(normals, dtype=torch.float32)
    best = np.inf
    for seed in range(seeds):
        c = fit_cluster_boxes(p, n, boxes, seed=seed).cuboids
        d = cuboid_chamfer_distance(p[None], c.centers, c.quaternions, c.half_sizes, c.exists, ChamferConvention(),
                                    torch.Generator().manual_seed(0))
        best = min(best, float(d[0]))
    return best


def legs(category: str, n: int) -> dict:
    """Per count rule: the legs' concision, Chamfer distance, cuboids and seconds on ``n`` test shapes."""
    leg = PART_NAMES[category].index("leg")
    out = {count: {"cuboids_per_leg": [], "legs_per_cuboid": [], "chamfer": [], "cuboids": [], "seconds": []}
           for count in COUNTS}
    for index in TEST_SPLIT[:n].tolist():
        shape = make_shape(category, index, n_points=2048, version=1)  # the committed results' shapes
        for count in COUNTS:
            result, seconds = fit(shape.points, shape.normals, count)
            c = part_concision(torch.as_tensor(result.labels)[None], torch.as_tensor(shape.labels)[None],
                               torch.as_tensor(shape.instances)[None], len(PART_NAMES[category]))
            row = out[count]
            row["cuboids_per_leg"].append(float(c["cuboids_per_instance"][leg]))
            row["legs_per_cuboid"].append(float(c["instances_per_cuboid"][leg]))
            row["chamfer"].append(result.chamfer)
            row["cuboids"].append(result.num_existing)
            row["seconds"].append(seconds)
        print(f"{category} {index:4d} {shape.structure:40s} " + "  ".join(
            f"{count}: {out[count]['cuboids_per_leg'][-1]:.2f}/{out[count]['legs_per_cuboid'][-1]:.2f} "
            f"CD {1e3 * out[count]['chamfer'][-1]:.3f} K {out[count]['cuboids'][-1]} "
            f"{out[count]['seconds'][-1]:.1f}s" for count in COUNTS), flush=True)
    return out


def thin(seeds: int) -> dict:
    """Per count rule on the thin-structure set: the fit's and k-means' Chamfer distances, cuboids, seconds."""
    out = {count: {"chamfer": [], "kmeans": [], "cuboids": [], "seconds": []} for count in COUNTS}
    for name, (points, normals) in thin_structure_set().items():
        for count in COUNTS:
            result, seconds = fit(points, normals, count)
            km = kmeans_chamfer(result.points, result.normals, result.num_existing, seeds)
            for key, value in (("chamfer", result.chamfer), ("kmeans", km), ("cuboids", result.num_existing),
                               ("seconds", seconds)):
                out[count][key].append(value)
        print(f"thin {name:12s} " + "  ".join(
            f"{count}: CD {1e3 * out[count]['chamfer'][-1]:.3f} k-means {1e3 * out[count]['kmeans'][-1]:.3f} "
            f"K {out[count]['cuboids'][-1]}" for count in COUNTS), flush=True)
    return out


def summary(rows: dict, thin_rows: dict | None) -> dict:
    doc = {}
    for category, by_count in rows.items():
        for count, r in by_count.items():
            doc[f"{category}/{count}"] = {
                "cuboids_per_leg": float(np.nanmean(r["cuboids_per_leg"])),
                "legs_per_cuboid": float(np.nanmean(r["legs_per_cuboid"])),
                "shapes_without_leg_cuboid": int(np.isnan(r["legs_per_cuboid"]).sum()),
                "median_chamfer_x1000": float(1e3 * np.median(r["chamfer"])),
                "cuboids_mean": float(np.mean(r["cuboids"])), "seconds_median": float(np.median(r["seconds"])),
                "seconds_max": float(np.max(r["seconds"]))}
    if thin_rows is not None:
        for count, r in thin_rows.items():
            fit_cd, km = np.array(r["chamfer"]), np.array(r["kmeans"])
            doc[f"thin/{count}"] = {"shapes": len(fit_cd), "below_kmeans": int((fit_cd < km).sum()),
                                    "median_ratio_to_kmeans": float(np.median(fit_cd / km)),
                                    "cuboids_mean": float(np.mean(r["cuboids"])),
                                    "seconds_median": float(np.median(r["seconds"]))}
    return doc


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--shapes", type=int, default=10, help="test shapes per category (default 10)")
    parser.add_argument("--seeds", type=int, default=3, help="k-means seeds, the best kept (default 3)")
    parser.add_argument("--no-thin", action="store_true", help="leave the thin-structure set out")
    parser.add_argument("--json", type=Path, help="write the records and the summary here")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")
    torch.set_num_threads(1)
    rows = {category: legs(category, args.shapes) for category in ("chair", "table")}
    thin_rows = None if args.no_thin else thin(args.seeds)
    doc = summary(rows, thin_rows)
    for key, value in doc.items():
        print(f"{key:18s} " + ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in value.items()))
    if args.json:
        command = "python " + " ".join([sys.argv[0]] + (argv if argv is not None else sys.argv[1:]))
        write_text_atomic(args.json, json.dumps({"command": command, "summary": doc, "legs": rows, "thin": thin_rows},
                                                indent=1))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
