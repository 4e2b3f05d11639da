"""Shapes in any rotation: how well each way of finding the frame lets the upright-trained networks abstract them.

The networks were trained upright (+y up, facing +z). Each shape is turned, a frame is found for it by each
option below, and the network abstracts it in that frame (the same ``cuboidlib.abstract`` call, one shape at a
time, at the network's 1024 points, the network named as a user names it):

* ``none``: no search, ``up="y"``: what the turn costs;
* ``axes``: the best of the 24 axis frames by the network's Chamfer distance (``up="auto"`` before the frame
  search; ``cuboidlib.frames.candidate_frames``);
* ``principal``: the best of the 24 frames on the points' principal axes (a canonical frame from PCA), by the
  same score;
* ``mirror``: the best of 24 frames about the mirror plane (``cuboidlib.frames.mirror_normal``), the up every
  30 degrees in it, both ways, by the same score: the network searching the one angle the mirror plane leaves;
* ``cues``: the frames of ``cuboidlib.frames.search_frames`` (the ups of the grounds the shape can stand on and of
  its flat area, about the mirror plane), the best by the Chamfer distance alone;
* ``auto``: ``abstract(..., up="auto")``: the same frames chosen by ``cuboidlib.frames.choose_frame`` (the
  orientation by the Chamfer and the latent distance, in it the axis frame, the ground, the flat area first),
  and for a shape with two mirror planes the second pass (``yawed_frames``).

Shapes: the networks' test split (``split_indices(1000, (0.7, 0.1, 0.2), 0)["test"]``, the first
``--per-category`` of each category, 1024 points, part labels), and the real meshes of
``benchmarks/bench_real_meshes.py`` (its loader, 2048 points, normals oriented as there; the network sees the
first 1024, every Chamfer distance is against all 2048, in the file's own units). Turns: a yaw of 0, 15, 30, 45,
90 and 180 degrees about the up axis of the upright shape, ``--random`` random rotations per shape (seeded by the
shape), and for the real meshes the file as it is (``file``: its own axes).

Per category, turn and option: the up axis found within 10 degrees (upside down counts as wrong) and upside
down (and for ``auto`` how often it warned that up and down scored alike, and how often it was then upside
down); the median over shapes of the Chamfer distance over the upright one's (``up="y"`` on the upright shape),
and the median Chamfer distance over the upright median (one category's files share no units: the first is the
measure for the real meshes); mIoU by label transfer as ``bench_real_meshes.py`` scores it (each cuboid slot named
by the majority part of its points on a fifth of the category's shapes, seed 0, the others scored), against the
upright mIoU. Cost, in the same process on one thread: the median CPU time of ``--repeats`` calls of
``abstract(data_samples/meshes/<category>_0.ply, category)`` with ``up="y"`` (one network pass), the default
(``up=None``) and ``up="auto"``, taken in turn, and their ratios to the first (CPU time, since the machine is
shared: wall times are recorded too).

``--geometry`` measures instead, on each upright shape and without the network, what the search relies on: the
mirror normal's angle to the side axis, whether a second mirror plane is found, the flat area's dominance (the
normals' spread along their first principal axis over the second) and its up's error, and the rank of the ground
the shape stands on among the grounds tried: the constants of ``cuboidlib.frames`` (``--repeats 0 --json
benchmarks/results/rotation_geometry.json``).

Command (the full run, about 1.5 hours on 2 busy cores; ``--per-category 4 --max-per-category 3 --random 1`` for a
look; the roots as in ``benchmarks/real_meshes/README.md``)::

    python benchmarks/bench_rotation.py --root diegogb=/work/realsrc/diegogb \\
        --root flightairmap=/work/realsrc/flightairmap --root quaternius=/work/realsrc/quaternius \\
        --root pyvista=data_samples/real/pyvista --per-category 40 --json benchmarks/results/rotation.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import bench_real_meshes as real_bench  # noqa: E402  (benchmarks/ is not a package; it imports the loader)

import cuboidlib.abstraction as pipeline  # noqa: E402
from cuboidlib.applications import load_trained_model  # noqa: E402
from cuboidlib.dataset import split_indices  # noqa: E402
from cuboidlib.files import write_text_atomic  # noqa: E402
from cuboidlib.frames import (GROUND_LINES, candidate_frames, flat_ups, frame_rotation, ground_ups,  # noqa: E402
                              mirror_normal, search_frames)
from cuboidlib.normals import orient_normals  # noqa: E402
from cuboidlib.shapes import make_shape  # noqa: E402

CATEGORIES = ("chair", "table", "airplane", "animal")
YAWS = (0, 15, 30, 45, 90, 180)
OPTIONS = ("none", "axes", "principal", "mirror", "cues", "auto")
NET_POINTS = 1024
AXIS_FRAMES = [frame_rotation(u, f) for u, f in candidate_frames()]


def about_y(degrees: float) -> np.ndarray:
    t = np.radians(degrees)
    return np.array([[np.cos(t), 0.0, np.sin(t)], [0.0, 1.0, 0.0], [-np.sin(t), 0.0, np.cos(t)]])


def random_rotation(seed) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def procedural_shapes(category: str, count: int) -> list[dict]:
    """The first ``count`` shapes of the category's test split, upright, with part labels."""
    out = []
    for index in split_indices(1000, (0.7, 0.1, 0.2), 0)["test"][:count].tolist():
        s = make_shape(category, index, n_points=NET_POINTS, version=1)  # the committed networks' shapes
        out.append({"name": f"{category}_{index}", "key": index, "points": s.points.astype(np.float64),
                    "normals": s.normals.astype(np.float64), "labels": s.labels, "file": None})
    return out


def real_shapes(shapes, category: str, count: int | None) -> list[dict]:
    """The real meshes of a category, upright (``to_network``), normals oriented as bench_real_meshes.py does."""
    out = []
    for k, s in enumerate([s for s in shapes if s.category == category][:count]):
        points = s.points.astype(np.float64) @ s.to_network.T
        normals = orient_normals(points.astype(np.float32), (s.normals @ s.to_network.T).astype(np.float32))
        out.append({"name": s.name, "key": 1000 + k, "points": points, "normals": normals.astype(np.float64),
                    "labels": s.labels, "file": s.to_network.T})  # file: the rotation from upright to the file
    return out


def turns(shape: dict, category: str, randoms: int) -> dict[str, np.ndarray]:
    """{name: Q}, the input being Q @ p of the upright shape."""
    out = {f"yaw {a}": about_y(a) for a in YAWS}
    for k in range(randoms):
        out[f"random {k}"] = random_rotation([CATEGORIES.index(category), shape["key"], k])
    if shape["file"] is not None:
        out["file"] = shape["file"]
    return out


# ----------------------------------------------------------------------------------------------
# The options: each a frame R (p_course = R p_input) for the turned cloud
# ----------------------------------------------------------------------------------------------


def _scored(pc, net, state, rotations, centroids):
    chamfer, latent, _, _ = pipeline._frame_scores(pc, net, state, rotations, 0.5, centroids, 0)
    return chamfer, latent


def principal_frames(points: np.ndarray) -> list[np.ndarray]:
    """The 24 axis frames on the points' principal axes (a right-handed basis)."""
    centred = points - points.mean(axis=0)
    basis = np.linalg.eigh(centred.T @ centred)[1]
    basis[:, 2] *= np.sign(np.linalg.det(basis))
    return [r @ basis.T for r in AXIS_FRAMES]


def mirror_frames(normal: np.ndarray, step: float = 30.0) -> list[np.ndarray]:
    """The frames with ``normal`` as the side axis (both ways) and the up every ``step`` degrees about it."""
    a = np.cross(normal, [1.0, 0, 0]) if abs(normal[0]) < 0.9 else np.cross(normal, [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    out = []
    for sign in (1.0, -1.0):
        for t in np.radians(np.arange(0.0, 360.0, step)):
            up = np.cos(t) * a + np.sin(t) * b
            out.append(np.stack([sign * normal, up, np.cross(sign * normal, up)]))
    return out


def option_frames(cloud: np.ndarray, net, state, centroids, wanted) -> dict[str, np.ndarray]:
    """The frame of every option but ``auto`` and ``none``, on the cloud as ``abstract`` reads it."""
    pc = pipeline._as_point_cloud(cloud, NET_POINTS, 0)
    mirror = mirror_normal(pc.points, pc.normals) if {"mirror", "cues"} & set(wanted) else None
    options = {"axes": lambda: AXIS_FRAMES, "principal": lambda: principal_frames(pc.points),
               "mirror": lambda: mirror_frames(mirror.normal),
               "cues": lambda: [c.rotation for c in search_frames(pc.points, pc.normals, mirror)]}
    frames = {}
    for name, make in options.items():
        if name in wanted:
            candidates = make()
            frames[name] = candidates[int(np.argmin(_scored(pc, net, state, candidates, centroids)[0]))]
    return frames


def up_error(rotation: np.ndarray, true_up: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(rotation[1] @ true_up, -1.0, 1.0))))


def run_shape(shape: dict, category: str, net, state, args) -> list[dict]:
    """Every turn and option of one shape: up error, Chamfer in the file's units, segmentation, seconds."""
    centroids = pipeline._centroids("auto", state)
    points, normals = shape["points"], shape["normals"]
    upright = pipeline.abstract(np.concatenate([points, normals], axis=1)[:NET_POINTS], category, up="y")
    rows = [{"turn": "upright", "option": "upright", "chamfer": real_bench.chamfer(points, upright.cuboids_in()),
             "labels": upright.labels}]
    for turn_name, Q in turns(shape, category, args.random).items():
        p, n = points @ Q.T, normals @ Q.T
        cloud = np.concatenate([p, n], axis=1)
        true_up = Q @ np.array([0.0, 1.0, 0.0])
        start = time.perf_counter()
        frames = option_frames(cloud, net, state, centroids, args.options)
        search_seconds = time.perf_counter() - start
        frames["none"] = np.eye(3)
        for option in args.options:
            start = time.perf_counter()
            if option == "auto":
                result = pipeline.abstract(cloud[:NET_POINTS], category, up="auto")
                rotation, target = (np.eye(3) if result.frame is None else result.frame), p
            else:
                rotation = frames[option]
                turned = np.concatenate([p @ rotation.T, n @ rotation.T], axis=1)
                result = pipeline.abstract(turned[:NET_POINTS], category, up="y")
                target = p @ rotation.T  # the same points in the frame: a rotation keeps the file's units
            seconds = time.perf_counter() - start + (search_seconds if option not in ("auto", "none") else 0.0)
            rows.append({"turn": turn_name, "option": option, "up_error": round(up_error(rotation, true_up), 2),
                         "chamfer": real_bench.chamfer(target, result.cuboids_in()), "labels": result.labels,
                         "seconds": round(seconds, 3), "by": (result.method.get("up_auto") or {}).get("by"),
                         "margin": (result.method.get("up_auto") or {}).get("upside_down_margin")})
    return rows


# ----------------------------------------------------------------------------------------------
# Summaries
# ----------------------------------------------------------------------------------------------


def turn_set(name: str) -> str:
    return "random" if name.startswith("random") else name


def summarise(records: list[dict], truths: dict, num_slots: int, options) -> dict:
    """Per turn set and option: up within 10 degrees, upside down, Chamfer ratios, mIoU."""
    upright = {r["shape"]: r for r in records if r["option"] == "upright"}
    out = {}
    sets = sorted({turn_set(r["turn"]) for r in records if r["option"] != "upright"},
                  key=lambda s: (s != "file", s.startswith("random"), int(s.split()[1]) if s.startswith("yaw") else 0))
    labelled = [s for s, t in truths.items() if t is not None]
    if len(labelled) >= 2:
        iou = real_bench.transferred_ious([upright[s]["labels"] for s in labelled], [truths[s] for s in labelled],
                                          num_slots, int(max(t.max() for t in truths.values() if t is not None)) + 1)
        out["upright_miou"] = float(iou[~iou.isnan()].mean())
    out["upright_median_chamfer"] = float(np.median([r["chamfer"] for r in upright.values()]))
    for name in sets:
        for option in options:
            rows = [r for r in records if turn_set(r["turn"]) == name and r["option"] == option]
            if not rows:
                continue
            errors = np.array([r["up_error"] for r in rows])
            ratios = np.array([r["chamfer"] / upright[r["shape"]]["chamfer"] for r in rows])
            entry = {"cases": len(rows), "up_within_10": round(float(np.mean(errors <= 10)), 4),
                     "upside_down": round(float(np.mean(errors > 90)), 4),
                     "median_ratio": round(float(np.median(ratios)), 4),
                     "ratio_of_medians": round(float(np.median([r["chamfer"] for r in rows]))
                                               / out["upright_median_chamfer"], 4),
                     "seconds_median": round(float(np.median([r["seconds"] for r in rows])), 3)}
            margins = [(r["margin"], r["up_error"]) for r in rows if r.get("margin") is not None]
            if margins:  # up='auto': how often it warned that up and down scored alike, and was it wrong then
                warned = [e for m, e in margins if m < pipeline.UPSIDE_DOWN_MARGIN]
                entry["warned"] = len(warned)
                entry["warned_upside_down"] = sum(e > 90 for e in warned)
            if "upright_miou" in out:
                segs = [(r["labels"], truths[r["shape"]]) for r in rows if truths[r["shape"]] is not None]
                num_parts = int(max(t.max() for _, t in segs)) + 1
                iou = real_bench.transferred_ious([s for s, _ in segs], [t for _, t in segs], num_slots, num_parts)
                entry["miou"] = round(float(iou[~iou.isnan()].mean()), 4)
                entry["miou_minus_upright_points"] = round(100 * (entry["miou"] - out["upright_miou"]), 2)
            out.setdefault(name, {})[option] = entry
    return out


def overall(summaries: dict, options) -> dict:
    """Pooled over categories and turns: the share of cases with the up within 10 degrees, per source and option."""
    out = {}
    for source, by_category in summaries.items():
        for option in options:
            cases = within = 0
            for summary in by_category.values():
                for name, entry in summary.items():
                    if isinstance(entry, dict) and option in entry:
                        cases += entry[option]["cases"]
                        within += entry[option]["up_within_10"] * entry[option]["cases"]
            if cases:
                out.setdefault(source, {})[option] = {"cases": cases, "up_within_10": round(within / cases, 4)}
    return out


def cost(repeats: int) -> dict:
    """CPU seconds of abstract on each category's sample mesh, one thread, same process: up='y', the default and
    up='auto', the three calls taken in turn ``repeats`` times (a busy machine slows all three alike), medians."""
    out = {}
    modes = {"y": "y", "default": None, "auto": "auto"}
    for category in CATEGORIES:
        mesh = ROOT / "data_samples" / "meshes" / f"{category}_0.ply"
        cpu = {label: [] for label in modes}
        wall = {label: [] for label in modes}
        for up in modes.values():
            pipeline.abstract(mesh, category, up=up)  # first call: caches
        for _ in range(repeats):
            for label, up in modes.items():
                start, start_cpu = time.perf_counter(), time.process_time()
                pipeline.abstract(mesh, category, up=up)
                cpu[label].append(time.process_time() - start_cpu)
                wall[label].append(time.perf_counter() - start)
        row = {f"{label}_cpu_s": round(statistics.median(v), 4) for label, v in cpu.items()}
        row |= {f"{label}_wall_s": round(statistics.median(v), 4) for label, v in wall.items()}
        row["default_over_y"] = round(row["default_cpu_s"] / row["y_cpu_s"], 2)
        row["auto_over_y"] = round(row["auto_cpu_s"] / row["y_cpu_s"], 2)
        out[category] = row
        print(f"cost {category:8s} up='y' {row['y_cpu_s']:.3f} s CPU, default {row['default_over_y']:.2f}x, "
              f"auto {row['auto_over_y']:.2f}x", flush=True)
    return out


def geometry(shape: dict) -> dict:
    """What the search measures on the upright shape (no network): the mirror normal's angle to x, whether a second
    plane was found, the flat area's dominance and its up's error, and the rank of the ground it stands on among
    the grounds tried (None: not among them)."""
    pc = pipeline._as_point_cloud(np.concatenate([shape["points"], shape["normals"]], axis=1)[:NET_POINTS],
                                  NET_POINTS, 0)
    mirror = mirror_normal(pc.points, pc.normals)
    grounds = ground_ups(pc.points, mirror.normal, count=GROUND_LINES)
    flats, dominance = flat_ups(pc.normals, mirror.normal)
    y = np.array([0.0, 1.0, 0.0])
    rank = next((k for k, u in enumerate(grounds) if np.degrees(np.arccos(np.clip(u @ y, -1, 1))) < 3), None)
    return {"shape": shape["name"], "mirror_error_degrees": round(float(np.degrees(np.arccos(min(1.0, abs(
        mirror.normal[0]))))), 2), "second_mirror": mirror.second is not None, "flat_dominance": round(dominance, 2),
        "flat_up_error": round(float(min(np.degrees(np.arccos(np.clip(u @ y, -1, 1))) for u in flats)), 2),
        "ground_rank": rank, "grounds": len(grounds)}


def geometry_summary(rows: list[dict]) -> dict:
    dominance = [r["flat_dominance"] for r in rows]
    ranks = [r["ground_rank"] for r in rows]
    return {"shapes": len(rows), "mirror_error_median": float(np.median([r["mirror_error_degrees"] for r in rows])),
            "mirror_within_3": float(np.mean([r["mirror_error_degrees"] < 3 for r in rows])),
            "second_mirror": int(sum(r["second_mirror"] for r in rows)),
            "flat_dominance_range": [min(dominance), max(dominance)],
            "flat_up_within_3": float(np.mean([r["flat_up_error"] < 3 for r in rows])),
            "ground_found": int(sum(k is not None for k in ranks)),
            "ground_rank_max": max((k for k in ranks if k is not None), default=None)}


def print_summary(source: str, category: str, summary: dict, options) -> None:
    print(f"== {source} {category}: upright mIoU {100 * summary.get('upright_miou', float('nan')):.1f}", flush=True)
    for name, entry in summary.items():
        if not isinstance(entry, dict):
            continue
        cells = []
        for option in options:
            e = entry.get(option)
            if e:
                miou = f" mIoU {e['miou_minus_upright_points']:+.1f}" if "miou" in e else ""
                cells.append(f"{option} {100 * e['up_within_10']:.0f}% {e['median_ratio']:.2f}x{miou}")
        print(f"   {name:10s} " + " | ".join(cells), flush=True)


def markdown(doc: dict) -> str:
    """The Markdown tables of a ``--json`` file (``--table``). Per source and category, for every option: the share
    of all turned cases with the up within 10 degrees, and over the turns (the yaws, the random rotations and for
    the real meshes the file's own axes) the largest median Chamfer ratio to upright and the largest mIoU loss in
    points; then the cost."""
    options = doc["options"]
    lines = ["| shapes | " + " | ".join(f"{o}: up within 10 degrees / worst CD ratio / worst mIoU change" for o in options)
             + " |", "|" + " --- |" * (1 + len(options))]
    for source, by_category in doc["summary"].items():
        for category, summary in by_category.items():
            turns = {t: e for t, e in summary.items() if isinstance(e, dict)}
            cells = []
            for o in options:
                entries = [e[o] for e in turns.values() if o in e]
                cases = sum(e["cases"] for e in entries)
                within = sum(e["up_within_10"] * e["cases"] for e in entries) / max(cases, 1)
                miou = [e["miou_minus_upright_points"] for e in entries if "miou_minus_upright_points" in e]
                cells.append(f"{100 * within:.0f} % of {cases} / {max(e['median_ratio'] for e in entries):.2f}x"
                             + (f" / {min(miou):+.1f}" if miou else ""))
            lines.append(f"| {source} {category} | " + " | ".join(cells) + " |")
    if doc.get("cost"):
        lines += ["", "| network | up='y' (CPU s) | default / up='y' | up='auto' / up='y' |", "| --- | --- | --- | --- |"]
        lines += [f"| {c} | {r['y_cpu_s']:.3f} | {r['default_over_y']:.2f}x | {r['auto_over_y']:.2f}x |"
                  for c, r in doc["cost"].items()]
    return "\n".join(lines)

def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--root", action="append", default=[], metavar="NAME=DIR",
                        help="a source folder of the real meshes (as bench_real_meshes.py), repeatable; none: no real "
                             "meshes")
    parser.add_argument("--categories", default=",".join(CATEGORIES))
    parser.add_argument("--per-category", type=int, default=50, help="procedural test shapes per category (0: none)")
    parser.add_argument("--max-per-category", type=int, default=None, help="real meshes per category (default: all)")
    parser.add_argument("--random", type=int, default=2, help="random rotations per shape (default 2)")
    parser.add_argument("--options", default=",".join(OPTIONS), help=f"comma-separated, of {', '.join(OPTIONS)}")
    parser.add_argument("--repeats", type=int, default=7, help="calls timed per cost measurement (0: no cost)")
    parser.add_argument("--json", type=Path, help="write the summaries and every record here")
    parser.add_argument("--geometry", action="store_true",
                        help="instead, what the search measures on each upright shape, no network (the constants of "
                             "cuboidlib.frames)")
    parser.add_argument("--table", type=Path, metavar="FILE.json",
                        help="print the Markdown tables of an earlier --json file, and nothing else")
    args = parser.parse_args(argv)
    if args.table:
        print(markdown(json.loads(args.table.read_text())))
        return 0
    args.options = [o.strip() for o in args.options.split(",") if o.strip()]
    if any(o not in OPTIONS for o in args.options):
        parser.error(f"--options: expected some of {', '.join(OPTIONS)}")
    categories = [c.strip() for c in args.categories.split(",") if c.strip()]
    roots = real_bench.parse_roots(parser, args.root)
    warnings.simplefilter("ignore")
    torch.set_num_threads(1)
    doc = {"command": "python " + " ".join([sys.argv[0]] + (argv if argv is not None else sys.argv[1:])),
           "options": args.options, "summary": {}, "records": []}
    if args.repeats:
        doc["cost"] = cost(args.repeats)
    loaded = real_bench.load_real_shapes(roots, n_points=real_bench.N_POINTS, seed=0)[0] if roots else []
    if args.geometry:
        for source in ("procedural", "real"):
            for category in categories:
                shapes = (procedural_shapes(category, args.per_category) if source == "procedural"
                          else real_shapes(loaded, category, args.max_per_category))
                if shapes:
                    rows = [geometry(shape) for shape in shapes]
                    summary = geometry_summary(rows)
                    doc["summary"].setdefault(source, {})[category] = summary
                    doc["records"] += [r | {"source": source, "category": category} for r in rows]
                    print(f"geometry {source} {category}: " + json.dumps(summary), flush=True)
        args.options = []
    for source in ("procedural", "real") if not args.geometry else ():
        for category in categories:
            shapes = (procedural_shapes(category, args.per_category) if source == "procedural"
                      else real_shapes(loaded, category, args.max_per_category))
            if not shapes:
                continue
            net, state, _ = load_trained_model(category, "cpu")
            records, truths = [], {}
            for shape in shapes:
                truths[shape["name"]] = None if shape["labels"] is None else shape["labels"][:NET_POINTS]
                for row in run_shape(shape, category, net, state, args):
                    records.append({"shape": shape["name"], **row})
                done = [r for r in records if r["shape"] == shape["name"] and r["option"] == "auto"]
                print(f"{source} {category} {shape['name']}: auto up errors "
                      + " ".join(f"{r['up_error']:.0f}" for r in done), flush=True)
            summary = summarise(records, truths, net.config.num_cuboids, args.options)
            doc["summary"].setdefault(source, {})[category] = summary
            print_summary(source, category, summary, args.options)
            doc["records"] += [{k: v for k, v in r.items() if k != "labels"} | {"source": source, "category": category}
                               for r in records]
    if not args.geometry:
        doc["overall"] = overall(doc["summary"], args.options)
        print("overall, up within 10 degrees: " + json.dumps(doc["overall"]), flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(args.json, json.dumps(doc, indent=1))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
