"""Per-shape methods on shapes off and on the training categories: k-means boxes, the fit, a network and
the network refined, with their Chamfer distances, cuboid counts and seconds.

The shapes: the thin-structure set (:func:`cuboidlib.thin_shapes.thin_structure_set`, +y up) and the meshes
of ``data_samples/meshes/`` (2048 points sampled by :func:`cuboidlib.abstract`, seed 0). For each:

* ``kmeans``: :func:`cuboidlib.baseline.fit_cluster_boxes` with as many boxes as the fit's cuboids, the
  best of ``--seeds`` seeds (independent of any start the fit takes from k-means);
* ``fit``: ``abstract(shape, None)`` (the default :class:`~cuboidlib.fitting.FitConfig`);
* ``net``: ``abstract(shape, model, up="y", check=True)``, the network of the mesh's category, or for the thin
  shapes the one named in :data:`THIN_NETWORK`; the shape's latent distance under it (``method["latent_distance"]``);
* ``refined``: the same with ``refine=--refine`` steps.

Chamfer distances x1000 in the course's convention (:class:`~cuboidlib.metrics.ChamferConvention`, squared
L2, sum of the two directions, 4096 samples, seed 0), all on the same normalised points.

Example::

    python benchmarks/bench_real_shapes.py
    python benchmarks/bench_real_shapes.py --only insect_0 airplane_0 --refine 300
    python benchmarks/bench_real_shapes.py --fit-only
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from cuboidlib.abstraction import abstract
from cuboidlib.baseline import fit_cluster_boxes
from cuboidlib.metrics import ChamferConvention, cuboid_chamfer_distance
from cuboidlib.thin_shapes import thin_structure_set

ROOT = Path(__file__).resolve().parents[1]
#: The network run on each kind of the thin-structure set (none of them is a training category).
THIN_NETWORK = {"insect": "animal", "spider": "animal", "stool": "chair", "ladder": "chair", "wheel": "airplane",
                "drone": "airplane", "mug": "table", "lamp": "table"}


def kmeans_chamfer(points: np.ndarray, normals: np.ndarray, boxes: int, seeds: int) -> float:
    """Best Chamfer distance of k-means boxes (``boxes`` boxes) over ``seeds`` seeds, on (N, 3) points."""
    p, n = torch.as_tensor(points, dtype=torch.float32), torch.as_tensor(normals, dtype=torch.float32)
    best = np.inf
    for seed in range(seeds):
        c = fit_cluster_boxes(p, n, boxes, seed=seed).cuboids
        d = cuboid_chamfer_distance(p[None], c.centers, c.quaternions, c.half_sizes, c.exists, ChamferConvention(),
                                    torch.Generator().manual_seed(0))
        best = min(best, float(d[0]))
    return best


def _timed(call):
    start = time.perf_counter()
    result = call()
    return result, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--refine", type=int, default=300, help="refinement steps (default 300)")
    parser.add_argument("--seeds", type=int, default=5, help="k-means seeds, the best kept (default 5)")
    parser.add_argument("--only", nargs="*", default=None, help="these shapes only (names as printed)")
    parser.add_argument("--fit-only", action="store_true", help="k-means and the fit only (no network)")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    shapes: dict[str, tuple[object, str]] = {}
    for name, (p, n) in thin_structure_set().items():
        shapes[name] = (np.concatenate([p, n], axis=1), THIN_NETWORK[name.split("_")[0]])
    for path in sorted((ROOT / "data_samples" / "meshes").glob("*.ply")):
        shapes[path.stem] = (str(path), path.stem.rsplit("_", 1)[0])
    rows = []
    print(f"{'shape':12s} {'network':8s} | {'kmeans':>7s} {'fit':>7s} {'n':>3s} {'s':>5s} | {'net':>7s} {'n':>3s} "
          f"{'latent':>6s} {'s':>5s} | {'refined':>7s} {'s':>5s} | k-means same count as the network")
    for name, (shape, model) in shapes.items():
        if args.only and name not in args.only:
            continue
        fit, fit_s = _timed(lambda: abstract(shape, None, n_points=2048, seed=0))
        km = kmeans_chamfer(fit.points, fit.normals, fit.num_existing, args.seeds)
        if args.fit_only:
            rows.append((name, km, fit.chamfer, np.nan, np.nan, np.nan))
            print(f"{name:12s} {'-':8s} | {km * 1e3:7.3f} {fit.chamfer * 1e3:7.3f} {fit.num_existing:3d} {fit_s:5.1f} |",
                  flush=True)
            continue
        out, net_s = _timed(lambda: abstract(shape, model, n_points=2048, seed=0, up="y", check=True))
        ref, ref_s = _timed(lambda: abstract(shape, model, n_points=2048, seed=0, up="y", refine=args.refine))
        km_net = kmeans_chamfer(out.points, out.normals, out.num_existing, args.seeds)
        latent = out.method["latent_distance"]  # the checkpoint's statistics: the network is given by name
        rows.append((name, km, fit.chamfer, out.chamfer, ref.chamfer, km_net))
        print(f"{name:12s} {model:8s} | {km * 1e3:7.3f} {fit.chamfer * 1e3:7.3f} {fit.num_existing:3d} {fit_s:5.1f} | "
              f"{out.chamfer * 1e3:7.3f} {out.num_existing:3d} {latent:6.2f} {net_s:5.1f} | {ref.chamfer * 1e3:7.3f} "
              f"{ref_s:5.1f} | {km_net * 1e3:7.3f}", flush=True)
    thin = [r for r in rows if not (ROOT / "data_samples" / "meshes" / f"{r[0]}.ply").exists()]
    for label, group in (("thin-structure set", thin), ("all shapes", rows)):
        if not group:
            continue
        km, fit, net, ref, _ = (np.array([r[i] for r in group]) for i in range(1, 6))
        print(f"{label}: {len(group)} shapes; fit below k-means (same count) by >= 5% on {(fit <= 0.95 * km).sum()}, "
              f"below at all on {(fit < km).sum()}; refined below the network on {(ref < net).sum()}, above on "
              f"{(ref > net).sum()}; network >= 1.5x the fit on {(net >= 1.5 * fit).sum()}")


if __name__ == "__main__":
    main()
