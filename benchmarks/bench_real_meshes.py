"""The committed networks, the per-shape fit and k-means boxes on real meshes made by people.

The shapes are those of ``benchmarks/real_meshes/manifest.json`` (chairs, tables, airplanes and four-legged
animals with part labels; sources and licences in ``benchmarks/real_meshes/README.md``), 2048 points sampled
on every triangle (seed 0), their normals oriented outward as the mesh loader orients those of a mesh that is
not watertight (:func:`cuboidlib.normals.orient_normals`), turned into the networks' frame (+y up, facing +z) by each entry's ``to_network``,
in the file's own units. For each shape:

* ``net``: ``abstract(points, category, up="y", check=True)``: its Chamfer distance, its mIoU by the network's
  label transfer, and whether its network-fit check warned (:class:`cuboidlib.abstraction.NetworkFitWarning`);
* ``refined``: the same with ``refine=--refine`` steps;
* ``fit``: ``abstract(points, None)``, the per-shape fit with its default settings (``--fit-count portion``:
  with the paper's count rule), and its cuboid count;
* ``kmeans``: k-means boxes (:func:`cuboidlib.baseline.fit_cluster_boxes`) with as many boxes as the
  network has cuboids, the best of ``--seeds`` seeds.

Chamfer distances are measured in the file's own units (squared, so they scale with the square of the size)
against the same 2048 points, in the course's convention (:class:`cuboidlib.metrics.ChamferConvention`, 4096
samples, seed 0); a rotation of the input changes the normalising box but not these distances. Across
shapes of different units only ratios mean something: the summary gives per category the median ratio of
each method to the network, and on how many shapes each is below it.

mIoU as ``cuboidlib evaluate`` scores a folder (Sec. 4.2): each cuboid slot is named by the majority part of
its points on a fifth of a category's labelled shapes (:func:`cuboidlib.evaluation.label_transfer_split`,
seed 0), and the other shapes are scored with those names (:func:`cuboidlib.metrics.part_ious` over their
points).

Example::

    python benchmarks/bench_real_meshes.py --root diegogb=/work/realsrc/diegogb \\
        --root flightairmap=/work/realsrc/flightairmap --root quaternius=/work/realsrc/quaternius \\
        --root pyvista=data_samples/real/pyvista --json benchmarks/results/real_meshes.json --png /tmp/real
    python benchmarks/bench_real_meshes.py --root ... --categories chair --only ChairArms1 --no-refine
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

from cuboidlib.abstraction import NetworkFitWarning, abstract
from cuboidlib.applications import load_trained_model
from cuboidlib.baseline import fit_cluster_boxes
from cuboidlib.files import write_text_atomic
from cuboidlib.fitting import FitConfig
from cuboidlib.evaluation import label_transfer_split
from cuboidlib.metrics import ChamferConvention, cuboid_chamfer_distance, part_ious, transfer_part_labels
from cuboidlib.normals import orient_normals
from cuboidlib.shapes import PART_NAMES

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks" / "real_meshes"))
from load import load_real_shapes  # noqa: E402  (benchmarks/ is not a package)

CATEGORIES = ("chair", "table", "airplane", "animal")
N_POINTS = 2048


def chamfer(points: np.ndarray, cuboids) -> float:
    """Chamfer distance between (N, 3) points and a shape's existing cuboids, in the points' units."""
    p = torch.as_tensor(points, dtype=torch.float32)[None]
    c = cuboids
    return float(cuboid_chamfer_distance(p, c.centers.float(), c.quaternions.float(), c.half_sizes.float(), c.exists,
                                         ChamferConvention(), torch.Generator().manual_seed(0))[0])


def kmeans_chamfer(points: np.ndarray, normals: np.ndarray, boxes: int, seeds: int, target: np.ndarray) -> float:
    """The best Chamfer distance to ``target`` of k-means boxes (``boxes`` of them) on ``points``, over ``seeds``
    seeds."""
    p, n = torch.as_tensor(points, dtype=torch.float32), torch.as_tensor(normals, dtype=torch.float32)
    return min(chamfer(target, fit_cluster_boxes(p, n, boxes, seed=s).cuboids) for s in range(seeds))


def network_cloud(shape) -> np.ndarray:
    """(N, 6) points and normals of a real shape in the networks' frame (+y up, facing +z), in its own units.

    The files' face normals follow their winding, which real meshes rarely keep consistent: they are oriented
    outward as :func:`cuboidlib.io.load_mesh_as_point_cloud` orients those of a mesh that is not watertight."""
    points = (shape.points @ shape.to_network.T).astype(np.float32)
    normals = orient_normals(points, (shape.normals @ shape.to_network.T).astype(np.float32))
    return np.concatenate([points, normals], axis=1)


def run_shape(shape, model: str, net_points: int, args) -> tuple[dict, dict]:
    """One shape: every method's record, and the network's result for the picture. ``model``: the network as
    ``abstract`` takes it, a committed name or a checkpoint (``--model``).

    The network (and its refinement and the k-means boxes) sees the first ``net_points`` points, as many as it
    was trained with; the fit sees all of them; every Chamfer distance is measured against all of them."""
    cloud = network_cloud(shape)
    points, normals = cloud[:, :3], cloud[:, 3:]
    seen = cloud[:net_points]  # the samples are independent: the first ones are a uniform subsample
    row = {"name": shape.name, "category": shape.category, "points": len(points), "network_points": len(seen)}
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = abstract(seen, model, seed=0, up="y", check=True)  # by name or path: with its latent statistics
    row["net"] = {"chamfer": chamfer(points, out.cuboids_in()), "cuboids": out.num_existing,
                  "seconds": round(time.perf_counter() - start, 2),
                  "warned": any(issubclass(w.category, NetworkFitWarning) for w in caught),
                  "check": out.method.get("network_check")}
    pictures = {"net": out}
    if args.refine:
        start = time.perf_counter()
        ref = abstract(seen, model, seed=0, up="y", refine=args.refine)
        row["refined"] = {"chamfer": chamfer(points, ref.cuboids_in()), "seconds": round(time.perf_counter() - start, 2)}
        pictures["refined"] = ref
    if not args.no_fit:
        start = time.perf_counter()
        config = None if args.fit_count is None else FitConfig(count=args.fit_count)
        fit = abstract(cloud, None, n_points=N_POINTS, seed=0, up="y", fit_config=config)
        row["fit"] = {"chamfer": chamfer(points, fit.cuboids_in()), "cuboids": fit.num_existing,
                      "seconds": round(time.perf_counter() - start, 2)}
        pictures["fit"] = fit
    row["kmeans"] = {"chamfer": kmeans_chamfer(points[:net_points], normals[:net_points], max(out.num_existing, 1),
                                               args.seeds, points),
                     "boxes": out.num_existing}
    if shape.labels is not None:
        row["labels"] = True
        pictures["truth"] = shape.labels[:net_points]
        pictures["segments"] = {key: np.asarray(result.labels) for key, result in pictures.items()
                                if key in ("net", "refined")}
    return row, pictures


def transferred_ious(segments: list[np.ndarray], truth: list[np.ndarray], num_slots: int, num_parts: int):
    """Per-part IoU (num_parts,) by label transfer: slots named on a fifth of the shapes, the rest scored."""
    seg, gt = torch.as_tensor(np.stack(segments)), torch.as_tensor(np.stack(truth))
    labelled, scored = label_transfer_split(len(seg), 0.2, 0)
    names = transfer_part_labels(seg[labelled], gt[labelled], num_slots, num_parts)
    return part_ious(names[seg[scored]], gt[scored], num_parts)


def category_summary(rows: list[dict], parts: dict[str, tuple[list, list]], category: str, num_slots: int) -> dict:
    """Per-category numbers: mIoU and per-part IoU where labels exist, ratios to the network, warnings."""
    names = PART_NAMES[category]
    out = {"shapes": len(rows), "labelled": sum(bool(r.get("labels")) for r in rows),
           "warned": sum(r["net"]["warned"] for r in rows)}
    net = np.array([r["net"]["chamfer"] for r in rows])
    for method in ("refined", "fit", "kmeans"):
        values = np.array([r[method]["chamfer"] for r in rows if method in r])
        if len(values) == len(net) and len(values):
            out[method] = {"median_ratio_to_net": float(np.median(values / net)),
                           "below_net": int((values < net).sum())}
    if "fit" in out:
        out["fit"]["cuboids_mean"] = float(np.mean([r["fit"]["cuboids"] for r in rows]))
    out["net_cuboids_mean"] = float(np.mean([r["net"]["cuboids"] for r in rows]))
    for method, (predicted, truth) in parts.items():
        if not truth:
            continue
        iou = transferred_ious(predicted, truth, num_slots, len(names))
        out[f"{method}_miou"] = float(iou[~iou.isnan()].mean())
        out[f"{method}_part_iou"] = {n: (None if torch.isnan(v) else round(float(v), 4)) for n, v in zip(names, iou)}
    return out


def draw(path: Path, shape, pictures: dict) -> None:
    """Three views of one shape: its labelled points, the network's parts with its cuboids, the fit's cuboids."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from cuboidlib.geometry import cuboid_corners

    panels = [("file's labels", pictures.get("truth"), pictures["net"]),
              ("network", pictures["net"].labels, pictures["net"])]
    if "fit" in pictures:
        panels.append(("fit", pictures["fit"].labels, pictures["fit"]))
    fig = plt.figure(figsize=(4 * len(panels), 4))
    edges = [(0, 1), (0, 2), (0, 4), (1, 3), (1, 5), (2, 3), (2, 6), (3, 7), (4, 5), (4, 6), (5, 7), (6, 7)]
    for i, (title, colours, result) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), i + 1, projection="3d")
        points = result.points  # normalised, in the frame of the result's cuboids
        c = np.zeros(len(points)) if colours is None else np.asarray(colours)
        ax.scatter(points[:, 2], points[:, 0], points[:, 1], c=c, cmap="tab20", s=1, vmin=0, vmax=19)
        if i > 0:
            cub = result.cuboids
            corners = cuboid_corners(cub.centers, cub.quaternions, cub.half_sizes)[0].numpy()
            for m in np.nonzero(cub.exists[0].numpy())[0]:
                for a, b in edges:
                    seg = corners[m, [a, b]]
                    ax.plot(seg[:, 2], seg[:, 0], seg[:, 1], color="k", lw=0.6)
        ax.set_title(title, fontsize=9)
        ax.set_axis_off()
    fig.suptitle(f"{shape.category}: {shape.name}", fontsize=10)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def parse_roots(parser: argparse.ArgumentParser, items: list[str]) -> dict[str, Path]:
    """``--root NAME=DIR`` options (the real meshes' source folders) as {name: folder}; a malformed one is a usage
    error of ``parser``."""
    roots = {}
    for item in items:
        name, sep, folder = item.partition("=")
        if not sep:
            parser.error(f"--root takes NAME=DIR, got {item!r}")
        roots[name] = Path(folder)
    return roots


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--root", action="append", default=[], metavar="NAME=DIR",
                        help="a source folder of the manifest (benchmarks/real_meshes/README.md), repeatable")
    parser.add_argument("--categories", default=",".join(CATEGORIES), help="comma-separated categories (default: all)")
    parser.add_argument("--only", nargs="*", default=None, help="these shapes only (names as in the manifest)")
    parser.add_argument("--refine", type=int, default=300, help="refinement steps (default 300)")
    parser.add_argument("--no-refine", dest="refine", action="store_const", const=0, help="no refinement")
    parser.add_argument("--no-fit", action="store_true", help="leave the per-shape fit out")
    parser.add_argument("--fit-count", choices=("chamfer", "portion"), default=None,
                        help="the fit's count rule (cuboidlib.fitting.FitConfig.count; default: abstract's, chamfer)")
    parser.add_argument("--seeds", type=int, default=3, help="k-means seeds, the best kept (default 3)")
    parser.add_argument("--json", type=Path, help="write the records and the summary here")
    parser.add_argument("--png", type=Path, help="write one picture per shape into this folder")
    parser.add_argument("--model", action="append", default=[], metavar="CATEGORY=CHECKPOINT",
                        help="score this checkpoint (a file or a training run's folder) instead of the committed "
                             "network of CATEGORY, repeatable")
    args = parser.parse_args(argv)
    models = {}
    for item in args.model:
        name, sep, checkpoint = item.partition("=")
        if not sep or name not in CATEGORIES:
            parser.error(f"--model takes CATEGORY=CHECKPOINT with CATEGORY one of {', '.join(CATEGORIES)}, got {item!r}")
        models[name] = checkpoint
    roots = parse_roots(parser, args.root)
    categories = [c.strip() for c in args.categories.split(",") if c.strip()]
    if any(c not in CATEGORIES for c in categories):
        parser.error(f"--categories: expected some of {', '.join(CATEGORIES)}, got {args.categories!r}")
    if args.png:
        args.png.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    shapes, skipped = load_real_shapes(roots, n_points=N_POINTS, seed=0)
    for line in skipped:
        print(f"skipped: {line}")
    rows, summary = [], {}
    for category in categories:
        group = [s for s in shapes if s.category == category and (not args.only or s.name in args.only)]
        if not group:
            continue
        net, state, _ = load_trained_model(models.get(category, category), "cpu")
        net_points = int(state["config"]["n_points"])
        done, parts = [], {"net": ([], []), "refined": ([], [])}
        for shape in group:
            row, pictures = run_shape(shape, models.get(category, category), net_points, args)
            done.append(row)
            for key in parts:
                if "truth" in pictures and key in pictures["segments"]:
                    parts[key][0].append(pictures["segments"][key])
                    parts[key][1].append(pictures["truth"])
            if args.png:
                draw(args.png / f"{category}_{shape.name}.png", shape, pictures)
            n = row["net"]
            extra = "".join(f"  {k} {row[k]['chamfer'] / n['chamfer']:5.2f}x" for k in ("refined", "fit", "kmeans")
                            if k in row)
            print(f"{category:8s} {shape.name:28s} net CD {n['chamfer']:.3g} ({n['cuboids']} cuboids"
                  f"{', warned' if n['warned'] else ''}){extra}", flush=True)
        summary[category] = category_summary(done, parts, category, net.config.num_cuboids)
        rows += done
        s = summary[category]
        print(f"== {category}: {s['shapes']} shapes ({s['labelled']} labelled); network mIoU "
              f"{100 * s.get('net_miou', float('nan')):.1f} %, refined {100 * s.get('refined_miou', float('nan')):.1f} %; "
              + "; ".join(f"{k}: median {s[k]['median_ratio_to_net']:.2f}x the network, below it on {s[k]['below_net']}"
                          for k in ("refined", "fit", "kmeans") if k in s)
              + f"; warned on {s['warned']}", flush=True)
    if args.json:
        doc = {"command": "python " + " ".join([sys.argv[0]] + (argv if argv is not None else sys.argv[1:])),
               "skipped": skipped, "summary": summary, "shapes": rows}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(args.json, json.dumps(doc, indent=1))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
