"""What costs the committed networks on real shapes: the procedural test shapes perturbed one cause at a time.

On real part-labelled meshes made by people the committed airplane and animal networks lose about 20 mIoU
points against their procedural test split; chairs and tables hold. This script trains nothing. It takes the
first ``--shapes`` test shapes of each committed network (the network's own data: 1000 procedural shapes,
split (0.7, 0.1, 0.2) with seed 0, 1024 points each), changes one thing about them at a time, and scores the
network on the changed shapes exactly as on the unchanged ones:

* **mIoU** by label transfer (Sec. 4.2, :func:`cuboidlib.evaluation.segmentation_scores`: 20 % of the shapes,
  seed 0, name the cuboid slots, the other 80 % are scored; the same shapes label in every row), with the
  standard deviation of its change from the unchanged shapes (a paired bootstrap over the scored shapes, the
  slot names held fixed);
* **CD**: the Chamfer distance (the course's convention, :class:`cuboidlib.metrics.ChamferConvention`) of the
  cuboids to the *unperturbed* surface of the same shape in the same frame (1024 area-uniform points on the
  union's outer surface, normalised with the input's box), so that noise or interior points in the input do not
  count as reconstruction error; ``chamfer_input`` in the JSON measures against the input points instead;
* **N_AC**, the existing cuboids per shape.

The changes (each applied to the same shapes; every input is normalised again, box diagonal 1, as
``cuboidlib.abstract`` would) are :data:`shape_changes.CHANGES`, described in ``shape_changes.py``: sampling,
density, noise, pose and scale, and the part proportions and variants where the real meshes' part statistics
leave the procedural range.

A change that touches only the normals is not run for a network that reads no normals (the animals'): its
row repeats the unchanged one (``same_as_clean``). The rows with points inside other solids also give
``interior_share`` and ``miou_outer``, the mIoU of the same slot names scored on the other points only: how
much of the loss is the interior points' own labels, and how much the network's view of the whole shape.

**Interior points of the real meshes.** How many of a real mesh's samples lie inside its surface (faces of one
part inside another, cabins, intakes) is estimated from the points alone: :func:`enclosed_share`, the share of
points from which no ray of a fan of 64 leaves the cloud, responds to interior points only in part, so
:func:`interior_estimate` calibrates it on 20 procedural test shapes sampled both ways (whose interior share is
known) and converts the real meshes' enclosed share into an interior share.

**Part statistics.** For each category, simple statistics of the labelled points (part shares, overall
proportions; airplanes: span, root chord, fuselage thickness, tail size, wing height, engine layout; animals:
leg length and slenderness, how high the leg labels reach up the body, tail angle and length, head position),
on the procedural test shapes and on the real meshes, both with 2048 points in the networks' frame with box
diagonal 1: the procedural 5 / 50 / 95th percentiles, the real median, and the share of real shapes outside the
procedural 2.5-97.5 % range. Engine layouts (none, wing, rear fuselage, nose) are counted per shape.

**Real meshes** (the reference gap): the shapes of ``benchmarks/real_meshes/manifest.json`` under
``--real-root`` folders, 2048 points on every triangle (seed 0), normals oriented as in
``benchmarks/bench_real_meshes.py``, the first 1024 points normalised and scored in the same way (mIoU by
label transfer within the real set, CD to their own points).

It prints one table per category and a summary (change of mIoU in points and ratio of CD per category),
and writes ``experiments/results/transfer_causes.json`` after every category (the command, the commit, the
settings, every row's metrics, part IoUs and bootstrap, the statistics). The README's table is
:func:`table` of that file.

**Generator versions** (``--generator-stats``): the part statistics that the causes name, on the first
``--shapes`` test shapes of the airplane and animal networks' split made by generator version 1 and by version 2
(:mod:`cuboidlib.shapes`), beside the real meshes' values stored in ``results/transfer_causes.json``; it trains
and scores nothing and writes ``results/transfer_causes_generator.json`` (:func:`generator_stats`,
:func:`generator_table`).

Example::

    python experiments/transfer_causes.py                          # 100 test shapes per category, about 22 minutes
    python experiments/transfer_causes.py --generator-stats        # versions 1 and 2 against the real meshes
    python experiments/transfer_causes.py --shapes 20 --categories animal --only clean,tail_raised
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import torch

from cuboidlib.applications import load_trained_model
from cuboidlib.dataset import UNVERSIONED_GENERATOR, ShapeSet, split_indices
from cuboidlib.evaluation import _shape_generator, label_transfer_split, predict_cuboids, segmentation_scores
from cuboidlib.files import write_text_atomic
from cuboidlib.metrics import ChamferConvention, cuboid_chamfer_distance
from cuboidlib.normalization import normalize
from cuboidlib.normals import orient_normals
from cuboidlib.release import git_commit
from cuboidlib.shapes import PART_NAMES, Shape, make_shape
from cuboidlib.solids import sample_union_surface

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks" / "real_meshes"))
from load import load_real_shapes  # noqa: E402  (benchmarks/ is not a package)

from shape_changes import CATEGORIES, CHANGES, Changed, buried, sample_every_face  # noqa: E402

DEFAULT_ROOTS = {"diegogb": "/work/realsrc/diegogb", "flightairmap": "/work/realsrc/flightairmap",
                 "quaternius": "/work/realsrc/quaternius"}
BOOTSTRAP = 1000


# ------------------------------------------------------------------------------------------------ scoring


def shape_set(changed: list[Changed], category: str, indices) -> tuple[ShapeSet, torch.Tensor, np.ndarray | None]:
    """The normalised inputs as a ShapeSet, the unperturbed surfaces (S, R, 3) in the same normalisation, and which
    input points lie inside another solid ((S, N) bool, None when no change says)."""
    points, normals, refs = [], [], []
    for c in changed:
        p, center, scale = normalize(np.asarray(c.points, np.float64))
        points.append(p)
        normals.append(c.normals)
        refs.append((np.asarray(c.reference, np.float64) - center) / scale)
    f32 = lambda a: torch.as_tensor(np.stack(a), dtype=torch.float32)  # noqa: E731
    names = PART_NAMES[category]
    inside = None if all(c.inside is None for c in changed) else np.stack(
        [np.zeros(len(c.points), bool) if c.inside is None else c.inside for c in changed])
    return (ShapeSet(f32(points), f32(normals), torch.as_tensor(np.stack([c.labels for c in changed])),
                     torch.as_tensor(list(indices)), names, len(names),
                     torch.as_tensor(np.stack([c.instances for c in changed]).astype(np.int64))), f32(refs), inside)


def per_shape_chamfer(points: torch.Tensor, cuboids) -> np.ndarray:
    """(S,) Chamfer distances of each shape's existing cuboids to (S, N, 3) points, with the surface samples of
    :func:`cuboidlib.evaluation.score_cuboids` (seed 0, shape i's own generator)."""
    c = cuboids
    return np.array([float(cuboid_chamfer_distance(points[i:i + 1], c.centers[i:i + 1], c.quaternions[i:i + 1],
                                                   c.half_sizes[i:i + 1], c.exists[i:i + 1], ChamferConvention(),
                                                   _shape_generator(0, i))[0]) for i in range(len(points))])


def slot_part_counts(shapes: ShapeSet, segments: torch.Tensor, num_slots: int,
                     keep: np.ndarray | None = None) -> np.ndarray:
    """(S, slots, parts) point counts: shape s's points in slot m that carry part k (only where ``keep``, (S, N) bool,
    is true, when given)."""
    num_parts = shapes.num_parts
    flat = (segments * num_parts + shapes.labels).numpy()
    if keep is None:
        keep = np.ones(flat.shape, bool)
    return np.stack([np.bincount(f[k], minlength=num_slots * num_parts).reshape(num_slots, num_parts)
                     for f, k in zip(flat, keep)])


def transfer_miou(counts: np.ndarray, labelled: np.ndarray, scored: np.ndarray,
                  scored_counts: np.ndarray | None = None) -> float:
    """The mIoU of the label transfer (:func:`cuboidlib.evaluation.segmentation_scores`) from (S, slots, parts)
    counts: each slot named by the majority part of its points on the ``labelled`` shapes (an empty slot names
    none: its points count as wrong), the IoU of every part pooled over the ``scored`` shapes' points, averaged
    over the parts present in prediction or truth; ``scored_counts`` (default ``counts``) are the counts scored."""
    named = counts[labelled].sum(0)
    names = np.where(named.sum(1) > 0, named.argmax(1), -1)
    pooled = (counts if scored_counts is None else scored_counts)[scored].sum(0)
    num_parts = counts.shape[2]
    ious = []
    for k in range(num_parts):
        mine = names == k
        inter = pooled[mine, k].sum()
        union = pooled[mine].sum() + pooled[:, k].sum() - inter
        if union > 0:
            ious.append(inter / union)
    return float(np.mean(ious))


def bootstrap(counts: np.ndarray, clean: np.ndarray | None, draws: int = BOOTSTRAP) -> tuple[float, float]:
    """Standard deviations of the mIoU and of its change from ``clean`` (paired) over bootstrap resamples of the
    labelled and of the scored shapes (the slots named again in every draw)."""
    labelled, scored = (t.numpy() for t in label_transfer_split(len(counts), 0.2, 0))
    rng = np.random.default_rng(0)
    level, delta = [], []
    for _ in range(draws):
        lab, sco = rng.choice(labelled, len(labelled)), rng.choice(scored, len(scored))
        level.append(transfer_miou(counts, lab, sco))
        if clean is not None:
            delta.append(level[-1] - transfer_miou(clean, lab, sco))
    return float(np.std(level)), float(np.std(delta)) if delta else 0.0


def score(model, shapes: ShapeSet, refs: torch.Tensor, centers_from_allocation: bool, pred=None, inside=None):
    """One row's metrics, its IoU counts (for the bootstrap) and the prediction; ``pred`` reuses a prediction on the
    same input. With ``inside`` ((S, N) bool, the points inside another solid) the row also holds ``interior_share``
    and ``miou_outer``: the same slot names, scored on the points outside the other solids only."""
    if pred is None:
        pred, _ = predict_cuboids(model, shapes, centers_from_allocation=centers_from_allocation)
    seg = segmentation_scores(shapes, pred)
    cd_ref = per_shape_chamfer(refs, pred.cuboids)
    cd_in = per_shape_chamfer(shapes.points, pred.cuboids)
    counts = slot_part_counts(shapes, pred.labels, pred.num_segments)
    labelled, scored = (t.numpy() for t in label_transfer_split(len(shapes), 0.2, 0))
    assert abs(transfer_miou(counts, labelled, scored) - seg["miou"]) < 1e-9, "the recount disagrees with the library"
    row = {"miou": seg["miou"], "part_iou": seg["part_iou"], "n_ac": seg["n_ac"],
           "chamfer": float(cd_ref.mean()), "chamfer_input": float(cd_in.mean()),
           "chamfer_per_shape": [round(float(x), 7) for x in cd_ref]}
    if inside is not None:
        outer = slot_part_counts(shapes, pred.labels, pred.num_segments, ~inside)
        row.update(interior_share=float(inside.mean()), miou_outer=transfer_miou(counts, labelled, scored, outer))
    return row, counts, pred


# ------------------------------------------------------------------------------------------ part statistics


def _extent(p: np.ndarray, axis: int, lo: float = 1, hi: float = 99) -> float:
    if len(p) < 3:
        return math.nan
    a, b = np.percentile(p[:, axis], [lo, hi])
    return float(b - a)


def _groups_along_x(p: np.ndarray, gap: float) -> list[np.ndarray]:
    """Index arrays of the groups of points whose x coordinates follow each other by less than ``gap``."""
    order = np.argsort(p[:, 0])
    cuts = np.nonzero(np.diff(p[order, 0]) > gap)[0] + 1
    return np.split(order, cuts)


def engine_layout(p: np.ndarray, labels: np.ndarray) -> str:
    """"none" or the engine groups by place, e.g. "wing2", "rear2", "nose1". Engines are told apart by their
    position across the span (groups of engine points whose x coordinates lie less than 0.015 apart, each with at
    least 5 % of them); a group at the front tenth of the fuselage is "nose" (a propeller's blades may make
    several: one nose counted), one behind the wing root within a quarter of the semi-span of the axis "rear",
    else "wing"."""
    body, wing, engine = p[labels == 0], p[labels == 1], p[labels == 3]
    if len(engine) < 3:
        return "none"
    axis_x, semi = np.median(body[:, 0]), _extent(wing, 0, 0, 100) / 2
    root = wing[np.abs(wing[:, 0] - axis_x) < 0.3 * semi]
    trailing = root[:, 2].min() if len(root) else np.median(body[:, 2])
    places = []
    for group in _groups_along_x(engine, 0.015):
        if len(group) < max(3, 0.05 * len(engine)):
            continue
        c = engine[group].mean(axis=0)
        if c[2] > np.percentile(body[:, 2], 90):
            places.append("nose")
        elif c[2] < trailing and abs(c[0] - axis_x) < 0.25 * semi:
            places.append("rear")
        else:
            places.append("wing")
    counts = {k: places.count(k) for k in ("wing", "rear")} | {"nose": min(places.count("nose"), 1)}
    return "+".join(f"{k}{n}" for k, n in counts.items() if n) or "none"


def _airplane_stats(P: dict) -> dict:
    body, wing, tail = P["body"], P["wing"], P["tail"]
    length = _extent(body, 2, 0, 100)
    semi = _extent(wing, 0, 0, 100) / 2
    root = wing[np.abs(wing[:, 0] - np.median(body[:, 0])) < 0.3 * semi]
    chord = _extent(root, 2)
    return {"span_over_length": 2 * semi / length, "root_chord_over_length": chord / length,
            "aspect_span_over_root_chord": 2 * semi / chord,
            "fuselage_thickness_over_length": _extent(body, 1) / length,
            "tail_height_over_length": _extent(tail, 1, 0, 100) / length,
            "tail_chord_over_length": _extent(tail, 2, 0, 100) / length,
            "wing_height_in_fuselage": float((np.median(root[:, 1]) - np.median(body[:, 1])) / _extent(body, 1))}


def _leg_radius(legs: np.ndarray, body: np.ndarray, ground: float) -> float:
    """Median over the four legs of the radius of their points in a band at 30-45 % of the legs' height."""
    top = legs[:, 1].max()
    band = legs[(legs[:, 1] > ground + 0.3 * (top - ground)) & (legs[:, 1] < ground + 0.45 * (top - ground))]
    cx, cz = np.median(body[:, 0]), np.median(body[:, 2])
    radii = []
    for sx in (-1, 1):
        for sz in (-1, 1):
            q = band[(np.sign(band[:, 0] - cx) == sx) & (np.sign(band[:, 2] - cz) == sz)][:, [0, 2]]
            if len(q) >= 6:
                radii.append(float(np.sqrt(((q - q.mean(0)) ** 2).sum(1).mean())))
    return float(np.median(radii)) if radii else math.nan


def _animal_stats(P: dict, ground: float) -> dict:
    body, head, legs, tail = P["body"], P["head"], P["leg"], P["tail"]
    length, height = _extent(body, 2, 0, 100), _extent(body, 1, 0, 100)
    leg_length = legs[:, 1].max() - ground
    out = {"body_height_over_length": height / length, "leg_length_over_body_length": leg_length / length,
           "leg_slenderness": leg_length / (2 * _leg_radius(legs, body, ground)),
           "leg_labels_up_the_body": float((np.percentile(legs[:, 1], 99) - body[:, 1].min()) / height),
           "head_above_body_over_length": float((head[:, 1].max() - body[:, 1].max()) / length),
           "head_ahead_of_body_over_length": float((head[:, 2].max() - body[:, 2].max()) / length),
           "tail_angle_deg": math.nan, "tail_length_over_body_length": math.nan}
    if len(tail) >= 5:
        dist = np.linalg.norm(tail - body.mean(0), axis=1)
        v = tail[dist >= np.percentile(dist, 90)].mean(0) - tail[dist <= np.percentile(dist, 15)].mean(0)
        out["tail_angle_deg"] = float(np.degrees(np.arctan2(v[1], np.hypot(v[0], v[2]))))
        out["tail_length_over_body_length"] = float(np.linalg.norm(v) / length)
    return out


def part_stats(category: str, points: np.ndarray, labels: np.ndarray) -> dict:
    """Simple statistics of one labelled shape (points in the networks' frame, box diagonal 1)."""
    names = PART_NAMES[category]
    P = {n: points[labels == i] for i, n in enumerate(names)}
    e = points.max(0) - points.min(0)
    out = {f"share_{n}": float(np.mean(labels == i)) for i, n in enumerate(names)}
    out.update(height_over_length=float(e[1] / e[2]), width_over_length=float(e[0] / e[2]))
    if category == "airplane":
        out.update(_airplane_stats(P))
    elif category == "animal":
        out.update(_animal_stats(P, float(points[:, 1].min())))
    return {k: float(v) for k, v in out.items()}


def compare_stats(procedural: list[dict], real: list[dict], real_names: list[str]) -> dict:
    """Per statistic: procedural 5/50/95th percentiles, real median, real values, share of real shapes outside
    the procedural 2.5-97.5 % range."""
    out = {}
    for key in procedural[0]:
        a = np.array([d[key] for d in procedural], float)
        b = np.array([d[key] for d in real], float)
        a, named = a[np.isfinite(a)], [(n, v) for n, v in zip(real_names, b) if np.isfinite(v)]
        b = b[np.isfinite(b)]
        if not len(a) or not len(b):
            continue
        lo, hi = np.percentile(a, [2.5, 97.5])
        out[key] = {"procedural_p5_p50_p95": [round(float(x), 4) for x in np.percentile(a, [5, 50, 95])],
                    "real_median": round(float(np.median(b)), 4),
                    "real_below": int((b < lo).sum()), "real_above": int((b > hi).sum()), "real_n": int(len(b)),
                    "real_outside_share": round(float(((b < lo) | (b > hi)).mean()), 3),
                    "real": {n: round(float(v), 4) for n, v in named}}
    return out


# ----------------------------------------------------------------------------------------------- the runs


def real_set(shapes, category: str, n_points: int) -> tuple[ShapeSet, list[np.ndarray], list]:
    """The labelled real meshes of a category as the networks see them (``benchmarks/bench_real_meshes.py``:
    normals oriented on all points, the first ``n_points`` kept, normalised), all their points in that
    normalisation, and the shapes."""
    seen, normals, labels, kept, full = [], [], [], [], []
    for s in shapes:
        if s.category != category or s.labels is None:
            continue
        points = s.network_points().astype(np.float64)
        nn = orient_normals(points, (s.normals @ s.to_network.T).astype(np.float64))
        p, center, scale = normalize(points[:n_points])
        seen.append(p)
        normals.append(nn[:n_points])
        labels.append(s.labels[:n_points])
        kept.append(s)
        full.append((points - center) / scale)
    names_ = PART_NAMES[category]
    f32 = lambda a: torch.as_tensor(np.stack(a), dtype=torch.float32)  # noqa: E731
    return (ShapeSet(f32(seen), f32(normals), torch.as_tensor(np.stack(labels)), torch.arange(len(seen)),
                     names_, len(names_)), full, kept)


def _rng(name: str, category: str, index: int) -> np.random.Generator:
    return np.random.default_rng([zlib.crc32(name.encode()), CATEGORIES.index(category), int(index)])


def run_changes(category: str, model, cfg: dict, base: list[Shape], indices: list[int], only,
                interior_share: float | None) -> dict:
    """Every change of the category on the base shapes: {name: row}; the first row is the unperturbed one. A change
    that takes the real meshes' interior share is left out without one."""
    cfa = bool(cfg["loss"].get("centers_from_allocation", False))
    reads_normals = cfg["model"].get("input_normals", "none") != "none"
    rows, clean_counts, clean_pred = {}, None, None
    for change in CHANGES:
        if category not in change.categories or (only and change.name not in only and change.name != "clean") or (
                change.takes_interior_share and interior_share is None):
            continue
        start = time.perf_counter()
        if change.normals_only and not reads_normals:
            rows[change.name] = dict(rows["clean"], same_as_clean=True, group=change.group, seconds=0.0)
            print(f"  {change.name:22s} = clean (the network reads no normals)", flush=True)
            continue
        extra = (interior_share,) if change.takes_interior_share else ()
        changed = [change.apply(s, _rng(change.name, category, i), *extra) for s, i in zip(base, indices)]
        shapes, refs, inside = shape_set(changed, category, indices)
        row, counts, pred = score(model, shapes, refs, cfa, clean_pred if change.labels_only else None, inside)
        if change.name == "clean":
            clean_counts, clean_pred = counts, pred
        clean = rows.get("clean", row)
        row["miou_sd"], row["miou_delta_sd"] = bootstrap(counts, None if change.name == "clean" else clean_counts)
        row.update(group=change.group, miou_delta=row["miou"] - clean["miou"],
                   chamfer_ratio=row["chamfer"] / clean["chamfer"], seconds=round(time.perf_counter() - start, 1))
        rows[change.name] = row
        _print_row(change.name, row)
    return rows


def _print_row(name: str, row: dict) -> None:
    sd = f" ± {100 * row['miou_delta_sd']:.1f}" if "miou_delta_sd" in row else ""
    outer = (f"  [{100 * row['interior_share']:.0f} % inside; outside them {100 * row['miou_outer']:.1f}]"
             if "miou_outer" in row else "")
    print(f"  {name:22s} mIoU {100 * row['miou']:5.1f} ({100 * row['miou_delta']:+5.1f}{sd})  CD "
          f"{1000 * row['chamfer']:.3f} ({row['chamfer_ratio']:.2f}x)  N_AC {row['n_ac']:.2f}  "
          + " ".join(f"{k} {100 * v:.0f}" for k, v in row["part_iou"].items() if v is not None) + outer
          + (f"  [{row['seconds']:.0f} s]" if "seconds" in row else ""), flush=True)


def fan_directions(k: int = 64) -> np.ndarray:
    """(k, 3) unit directions spread over the sphere (a Fibonacci lattice)."""
    i = np.arange(k) + 0.5
    z = 1 - 2 * i / k
    phi = i * math.pi * (3 - math.sqrt(5))
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def enclosed_share(points: np.ndarray, k: int = 64, queries: int = 512, chunk: int = 64) -> float:
    """The share of the points from which none of ``k`` rays leaves the cloud (estimated on the first ``queries``
    points; the samples are independent, so these are a uniform subsample): a ray is blocked by a point within
    ``rho`` of it, ahead by more than ``rho`` (``rho`` = 1.5 x the median distance to the 3rd nearest point). A point
    inside the surface is enclosed; one on the outer surface is not. With a few thousand points the rays leak
    through gaps between the samples, so this finds only part of the interior points: :func:`interior_estimate`
    calibrates it on procedural shapes whose interior is known."""
    p = torch.as_tensor(points, dtype=torch.float32)
    d = torch.as_tensor(fan_directions(k), dtype=torch.float32)
    dist = torch.cdist(p, p)
    dist.fill_diagonal_(math.inf)
    rho = 1.5 * float(dist.topk(3, largest=False).values[:, -1].median())
    enclosed, n = 0, min(queries, len(p))
    for s in range(0, n, chunk):
        q = p[None] - p[s:min(s + chunk, n), None]  # (c, M, 3)
        t = q @ d.T  # (c, M, k): how far along each ray
        off = (q * q).sum(-1, keepdim=True) - t * t  # squared distance from the ray
        enclosed += int(((t > rho) & (off < rho ** 2)).any(1).all(-1).sum())
    return enclosed / n


def interior_estimate(base: list[Shape], real_points: list[np.ndarray], n_points: int = 2048,
                      calibration: int = 20) -> dict:
    """The share of the real meshes' points that lie inside their surface, estimated with :func:`enclosed_share`
    calibrated on procedural shapes: on the first ``calibration`` base shapes, every-face samples (whose interior
    share is known) and outer-surface samples give the enclosed share's response to interior points and its level
    without them; the real meshes' enclosed share above that level, divided by the response, is the estimate."""
    every, outer, truth = [], [], []
    for i, shape in enumerate(base[:calibration]):
        rng = np.random.default_rng([7, i])
        p, _, idx = sample_every_face(shape.parts, n_points, rng)
        truth.append(float(buried(shape.parts, p, idx).mean()))
        every.append(enclosed_share(p))
        outer.append(enclosed_share(sample_union_surface(shape.parts, n_points, rng)[0]))
    real = [enclosed_share(p[:n_points]) for p in real_points]
    response = (np.mean(every) - np.mean(outer)) / np.mean(truth)
    share = max(0.0, (np.mean(real) - np.mean(outer)) / response)
    return {"every_face_interior_share": float(np.mean(truth)), "every_face_enclosed": float(np.mean(every)),
            "outer_enclosed": float(np.mean(outer)), "response": float(response),
            "real_enclosed": float(np.mean(real)), "real_enclosed_per_shape": [round(float(x), 4) for x in real],
            "real_interior_share": float(share)}


def run_category(category: str, n_shapes: int, real_shapes, only) -> dict:
    """The changes, the real meshes and the part statistics of one category."""
    model, state, path = load_trained_model(category)
    cfg = state["config"]
    test = split_indices(cfg["n_shapes"], tuple(cfg["split_fractions"]), cfg["split_seed"])["test"]
    indices = [int(i) for i in test[:n_shapes]]
    version = cfg.get("generator_version", UNVERSIONED_GENERATOR)  # the network's own shapes
    base = [make_shape(category, i, cfg["n_points"], cfg["data_seed"], version) for i in indices]
    print(f"== {category}: {path.name}, test shapes {len(indices)} of {len(test)}", flush=True)
    out = {"network": str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path),
           "test_indices": indices}
    real, full, kept = real_set(real_shapes, category, cfg["n_points"]) if real_shapes else (None, [], [])
    share = None
    if len(kept) >= 2:
        out["interior"] = interior_estimate(base, full)
        share = out["interior"]["real_interior_share"]
        print(f"  interior points of the real meshes: {100 * share:.1f} % estimated (every-face sampling of the "
              f"procedural shapes: {100 * out['interior']['every_face_interior_share']:.1f} %)", flush=True)
    out["rows"] = run_changes(category, model, cfg, base, indices, only, share)
    dense = [make_shape(category, i, 2048, cfg["data_seed"], version) for i in indices]  # as many points as the real meshes
    procedural = [part_stats(category, s.points.astype(np.float64), s.labels) for s in dense]
    out["procedural_layouts"] = _layouts(category, [(s.points, s.labels) for s in dense])
    if len(kept) >= 2:
        row, counts, _ = score(model, real, real.points, bool(cfg["loss"].get("centers_from_allocation", False)))
        row["miou_sd"] = bootstrap(counts, None)[0]
        row.update(shapes=[s.name for s in kept], miou_delta=row["miou"] - out["rows"]["clean"]["miou"],
                   chamfer_ratio=row["chamfer"] / out["rows"]["clean"]["chamfer"])
        out["real"] = row
        _print_row("real meshes", row)
        stats = [part_stats(category, p, s.labels) for p, s in zip(full, kept)]
        out["stats"] = compare_stats(procedural, stats, [s.name for s in kept])
        out["real_layouts"] = _layouts(category, [(p, s.labels) for p, s in zip(full, kept)])
    return out


def _layouts(category: str, shapes) -> dict | None:
    if category != "airplane":
        return None
    found = [engine_layout(np.asarray(p, np.float64), np.asarray(l)) for p, l in shapes]
    return {k: found.count(k) for k in sorted(set(found))}


# ------------------------------------------------------------------------------------------- the tables


def _cell(row: dict | None) -> str:
    if row is None:
        return ""
    if row.get("same_as_clean"):
        return "= unperturbed"
    cell = f"{100 * row['miou_delta']:+.1f} ± {100 * row['miou_delta_sd']:.1f} / {row['chamfer_ratio']:.2f}x"
    if "miou_outer" in row:
        cell += (f" ({100 * row['interior_share']:.0f} % inside; outside them "
                 f"{100 * (row['miou_outer'] - row['miou'] + row['miou_delta']):+.1f})")
    return cell


def table(doc: dict) -> list[str]:
    """The summary as Markdown lines: per change and category, the change of mIoU (points, ± the bootstrap's
    standard deviation) and the ratio of the CD to the unperturbed shapes'; for inputs with points inside other
    solids, their share and the change of the mIoU scored outside them; the unperturbed and real rows absolute."""
    cats = [c for c in CATEGORIES if c in doc["categories"]]
    data = {c: doc["categories"][c] for c in cats}
    lines = ["| change | group | " + " | ".join(cats) + " |", "| --- | --- |" + " --- |" * len(cats)]
    clean = [data[c]["rows"]["clean"] for c in cats]
    lines.append("| unperturbed test shapes: mIoU %, CD x1000 | | "
                 + " | ".join(f"{100 * r['miou']:.1f} ± {100 * r['miou_sd']:.1f}, {1000 * r['chamfer']:.3f}"
                              for r in clean) + " |")
    for change in CHANGES[1:]:
        rows = [data[c]["rows"].get(change.name) for c in cats]
        if any(r is not None for r in rows):
            lines.append(f"| {change.name} | {change.group} | " + " | ".join(_cell(r) for r in rows) + " |")
    real = [data[c].get("real") for c in cats]
    if any(real):
        lines.append("| real meshes: mIoU %, CD x1000 (change) | reference | " + " | ".join(
            "" if r is None else f"{100 * r['miou']:.1f} ± {100 * r['miou_sd']:.1f}, {1000 * r['chamfer']:.3f} "
            f"({100 * r['miou_delta']:+.1f} / "
            f"{r['chamfer_ratio']:.2f}x)" for r in real) + " |")
    return lines


def parts_table(doc: dict, category: str) -> list[str]:
    """Per change, the IoU (%) of every part of one category, and N_AC."""
    data = doc["categories"][category]
    names = PART_NAMES[category]
    lines = ["| change | " + " | ".join(names) + " | N_AC |", "| --- |" + " --- |" * (len(names) + 1)]
    rows = [(name, row) for name, row in data["rows"].items()] + ([("real meshes", data["real"])] if "real" in data
                                                                  else [])
    for name, row in rows:
        ious = ["-" if row["part_iou"].get(n) is None else f"{100 * row['part_iou'][n]:.1f}" for n in names]
        lines.append(f"| {name} | " + " | ".join(ious) + f" | {row['n_ac']:.2f} |")
    return lines


def stats_table(doc: dict, categories=("airplane", "animal")) -> list[str]:
    """The part statistics of the procedural test shapes beside the real meshes'."""
    lines = ["| category | statistic | procedural 5 / 50 / 95 % | real median "
             "| real outside the procedural 2.5-97.5 % |", "| --- | --- | --- | --- | --- |"]
    for c in categories:
        for key, s in doc["categories"].get(c, {}).get("stats", {}).items():
            p = s["procedural_p5_p50_p95"]
            lines.append(f"| {c} | {key} | {p[0]:.3g} / {p[1]:.3g} / {p[2]:.3g} | {s['real_median']:.3g} | "
                         f"{s['real_below'] + s['real_above']} of {s['real_n']} ({s['real_below']} below, "
                         f"{s['real_above']} above) |")
    air = doc["categories"].get("airplane", {})
    if air.get("real_layouts"):
        fmt = lambda d: ", ".join(f"{k} {v}" for k, v in sorted(d.items(), key=lambda kv: -kv[1]))  # noqa: E731
        lines.append(f"| airplane | engine layout (shapes) | {fmt(air['procedural_layouts'])} | "
                     f"{fmt(air['real_layouts'])} | |")
    return lines


# ------------------------------------------------------------------------------------ generator versions

#: The statistics that the causes name, per category (``--generator-stats``).
GENERATOR_STATS = {
    "airplane": ("fuselage_thickness_over_length", "height_over_length", "share_engine"),
    "animal": ("leg_labels_up_the_body", "tail_angle_deg", "tail_length_over_body_length", "width_over_length",
               "share_body", "share_leg"),
}


def generator_stats(doc: dict, n_shapes: int, versions=(1, 2)) -> dict:
    """The :data:`GENERATOR_STATS` of the first ``n_shapes`` test shapes (the committed networks' split, 2048 points)
    made by each generator version, against the real meshes' values in ``doc`` (``results/transfer_causes.json``).

    Returns:
        {category: {statistic: {"real": [values], "v<k>": [values]}, "layouts": {"real": {...}, "v<k>": {...}}}}.
    """
    test = split_indices(1000, (0.7, 0.1, 0.2), 0)["test"][:n_shapes]
    out = {}
    for category, keys in GENERATOR_STATS.items():
        stored = doc["categories"][category]
        rows = {key: {"real": list(stored["stats"][key]["real"].values())} for key in keys}
        layouts = {"real": stored.get("real_layouts")}
        for v in versions:
            dense = [make_shape(category, int(i), 2048, 0, v) for i in test]
            stats = [part_stats(category, s.points.astype(np.float64), s.labels) for s in dense]
            for key in keys:
                rows[key][f"v{v}"] = [d[key] for d in stats]
            layouts[f"v{v}"] = _layouts(category, [(s.points, s.labels) for s in dense])
        out[category] = {"stats": rows, "layouts": layouts}
    return out


def generator_table(found: dict) -> list[str]:
    """Markdown lines: per statistic the real median, each version's 5 / 50 / 95th percentiles and how many real
    shapes lie outside its 2.5-97.5 % range; then the airplanes' nose engines (light aircraft) per version."""
    versions = [k for k in next(iter(found.values()))["layouts"] if k != "real"]
    lines = ["| category | statistic | real median | " + " | ".join(f"{v} 5 / 50 / 95 % | real outside {v}"
                                                                  for v in versions) + " |",
             "| --- | --- | --- |" + " --- | --- |" * len(versions)]
    for category, data in found.items():
        for key, values in data["stats"].items():
            real = np.array(values["real"], float)
            cells = []
            for v in versions:
                a = np.array(values[v], float)
                a = a[np.isfinite(a)]
                lo, hi = np.percentile(a, [2.5, 97.5])
                p = np.percentile(a, [5, 50, 95])
                cells.append(f"{p[0]:.3g} / {p[1]:.3g} / {p[2]:.3g} | {int(((real < lo) | (real > hi)).sum())} of "
                             f"{len(real)}")
            lines.append(f"| {category} | {key} | {np.median(real):.3g} | " + " | ".join(cells) + " |")
    air = found.get("airplane", {}).get("layouts")
    if air:
        share = lambda d: sum(n for k, n in d.items() if "nose" in k) / sum(d.values())  # noqa: E731
        lines.append(f"| airplane | shapes with a nose engine | {share(air['real']):.2f} | "
                     + " | ".join(f"{share(air[v]):.2f} | " for v in versions) + "|")
    return lines


# -------------------------------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--shapes", type=int, default=100, help="first test shapes per category (default 100)")
    parser.add_argument("--categories", default=",".join(CATEGORIES), help="comma-separated (default: all four)")
    parser.add_argument("--only", default="", help="comma-separated changes to run (the unperturbed row always runs)")
    parser.add_argument("--real-root", action="append", default=[], metavar="NAME=DIR",
                        help="a source folder of the real meshes' manifest (default: the three under /work/realsrc)")
    parser.add_argument("--no-real", action="store_true", help="leave the real meshes out")
    parser.add_argument("--generator-stats", action="store_true",
                        help="only compare generator versions 1 and 2 with the real meshes' statistics stored in "
                        "results/transfer_causes.json (no network is scored)")
    parser.add_argument("--out", type=Path, default=ROOT / "experiments" / "results" / "transfer_causes.json")
    args = parser.parse_args(argv)
    categories = [c.strip() for c in args.categories.split(",") if c.strip()]
    if any(c not in CATEGORIES for c in categories) or not categories:
        parser.error(f"--categories: expected some of {', '.join(CATEGORIES)}, got {args.categories!r}")
    if args.shapes < 5:
        parser.error("--shapes must be at least 5 (the label transfer needs labelled and scored shapes)")
    only = {o.strip() for o in args.only.split(",") if o.strip()}
    unknown = only - {c.name for c in CHANGES}
    if unknown:
        parser.error(f"--only: unknown changes {sorted(unknown)}; choose from {[c.name for c in CHANGES]}")
    torch.set_num_threads(1)
    if args.generator_stats:
        return _generator_main(args, argv)
    start = time.time()
    roots = dict(DEFAULT_ROOTS)
    roots.update(dict(item.split("=", 1) for item in args.real_root))
    real_shapes = []
    if not args.no_real:
        real_shapes, skipped = load_real_shapes({k: Path(v) for k, v in roots.items()}, n_points=2048, seed=0,
                                                categories=tuple(categories))
        print(f"real meshes: {len(real_shapes)} loaded, {len(skipped)} skipped", flush=True)
    doc = {"command": "python experiments/transfer_causes.py" + "".join(f" {a}" for a in (argv if argv is not None
                                                                                            else sys.argv[1:])),
           "git_commit": git_commit(ROOT), "torch": torch.__version__, "started": time.strftime("%Y-%m-%d %H:%M:%S"),
           "settings": {"shapes": args.shapes, "bootstrap": BOOTSTRAP, "chamfer": ChamferConvention().describe(),
                        "label_transfer": "20 % of the shapes, seed 0"},
           "categories": {}}
    for category in categories:
        doc["categories"][category] = run_category(category, args.shapes, real_shapes, only)
        doc["wall_seconds"] = round(time.time() - start, 1)
        write_text_atomic(args.out, json.dumps(doc, indent=1) + "\n")
    print("\nchange of mIoU (points, ± bootstrap sd) / CD ratio to the unperturbed shapes:")
    print("\n".join(table(doc)))
    for c in ("airplane", "animal"):
        if c in doc["categories"]:
            print(f"\n{c}: part IoU (%)")
            print("\n".join(parts_table(doc, c)))
    print("\n".join([""] + stats_table(doc)))
    print(f"wrote {args.out} ({doc['wall_seconds'] / 60:.1f} min)")
    return 0



def _generator_main(args, argv) -> int:
    """``--generator-stats``: print :func:`generator_table` and write ``results/transfer_causes_generator.json``."""
    start = time.time()
    found = generator_stats(json.loads(args.out.read_text()), args.shapes)
    lines = generator_table(found)
    print("\n".join(lines))
    out = args.out.with_name("transfer_causes_generator.json")
    doc = {"command": "python experiments/transfer_causes.py" + "".join(f" {a}" for a in (argv if argv is not None
                                                                                            else sys.argv[1:])),
           "git_commit": git_commit(ROOT), "shapes": args.shapes, "table": lines, "found": found,
           "wall_seconds": round(time.time() - start, 1)}
    write_text_atomic(out, json.dumps(doc, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
