"""The network check of ``abstract(shape, model, check=True)`` (:mod:`cuboidlib.network_check`): its thresholds
calibrated in one command, how often it speaks on each group of shapes, and whether the route it names does better.

Every committed network is given every group (the networks see 1024 points, +y up):

* ``own test``: its category's procedural test split (``split_indices(1000, (0.7, 0.1, 0.2), 0)["test"]``, 200
  shapes); target: silent on at least 99 %;
* ``own real``: the real meshes of its category (``benchmarks/real_meshes/``, oriented as
  ``bench_real_meshes.py`` orients them, their first 1024 points); target: silent on all but 1 in 20;
* ``off test``, ``off real``: the other categories' test splits and real meshes; target: speaks on at least 90 %;
* ``thin``: the thin-structure set (:func:`cuboidlib.thin_shapes.thin_structure_set`); target: speaks on 90 %.

The latent distances are computed in batches (:func:`cuboidlib.network_check.latent_distances`) and decided by
:func:`~cuboidlib.network_check.network_verdict`, as ``abstract`` decides; ``--verify`` shapes per group go
through ``abstract`` itself and must give the same verdict. The thresholds are calibrated on each network's
validation split and real in-category meshes (:func:`~cuboidlib.network_check.calibrated_threshold`); the rates
are measured with the library's :data:`~cuboidlib.network_check.LATENT_THRESHOLDS`, or with the calibrated ones
after ``--write`` has written them into ``cuboidlib/network_check.py``.

The routes: on the first ``--routes`` shapes of each group, every network's Chamfer distance (``abstract(shape,
name, up="y")``) and the per-shape fit's (``abstract(shape, None)``, where some network's check names it), so that
each warning's route is compared with the network it was given; and ``abstract(..., fallback=True)`` timed on the
first speaking pair of each group.

Example::

    python benchmarks/bench_warning.py --root diegogb=/work/realsrc/diegogb \\
        --root flightairmap=/work/realsrc/flightairmap --root quaternius=/work/realsrc/quaternius \\
        --root pyvista=data_samples/real/pyvista --json benchmarks/results/warning.json
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from bench_real_meshes import network_cloud, parse_roots
from cuboidlib.abstraction import NetworkFitWarning, abstract
from cuboidlib.dataset import load_splits
from cuboidlib.files import write_text_atomic
from cuboidlib.network_check import (LATENT_THRESHOLDS, calibrated_threshold, committed_networks, latent_distances,
                                     network_verdict)
from cuboidlib.normalization import normalize
from cuboidlib.thin_shapes import thin_structure_set
from cuboidlib.train_config import course_config

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks" / "real_meshes"))
from load import load_real_shapes  # noqa: E402  (benchmarks/ is not a package)

CATEGORIES = ("chair", "table", "airplane", "animal")
N_POINTS = 1024
KINDS = ("own test", "own real", "off test", "off real", "thin")
TARGETS = {"own test": ("silent", 0.99), "own real": ("silent", 0.95), "off test": ("speaks", 0.90),
           "off real": ("speaks", 0.90), "thin": ("speaks", 0.90)}


def _cloud(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N, 6): the first N_POINTS points normalised as ``abstract`` normalises them, and unit normals."""
    p = normalize(np.asarray(points[:N_POINTS], dtype=np.float64))[0]
    n = np.asarray(normals[:N_POINTS], dtype=np.float64)
    return np.concatenate([p, n / np.linalg.norm(n, axis=1, keepdims=True)], axis=1).astype(np.float32)


def load_groups(roots: dict[str, Path], limit: int | None = None) -> dict[str, dict]:
    """{group: {"category": c or None, "names": [...], "clouds": (S, N, 6)}} for "val:c", "test:c", "real:c" and
    "thin", at most ``limit`` shapes of each (None: all)."""
    groups = {}
    for c in CATEGORIES:
        splits = load_splits(course_config(c))
        for split in ("val", "test"):
            s = splits[split].subset(torch.arange(min(limit or 10 ** 9, len(splits[split].points))))
            groups[f"{split}:{c}"] = {"category": c, "names": [f"{split} {i}" for i in range(len(s.points))],
                                      "clouds": np.stack([_cloud(np.asarray(p), np.asarray(n))
                                                          for p, n in zip(s.points, s.normals)])}
    shapes, skipped = load_real_shapes(roots, n_points=2048, seed=0) if roots else ([], [])
    for line in skipped:
        print(f"skipped: {line}")
    for c in CATEGORIES:
        mine = [s for s in shapes if s.category == c][:limit]
        if mine:
            groups[f"real:{c}"] = {"category": c, "names": [s.name for s in mine],
                                   "clouds": np.stack([_cloud(network_cloud(s)[:, :3], network_cloud(s)[:, 3:])
                                                       for s in mine])}
    thin = dict(list(thin_structure_set().items())[:limit])
    groups["thin"] = {"category": None, "names": list(thin),
                      "clouds": np.stack([_cloud(p, n) for p, n in thin.values()])}
    return groups


def kind_of(group: str, network: str) -> str | None:
    """The row of the table a (group, network) pair counts in (None: the validation splits)."""
    split, _, category = group.partition(":")
    if split == "val":
        return None
    if split == "thin":
        return "thin"
    return f"{'own' if category == network else 'off'} {split}"


def calibrate(groups: dict, distances: dict) -> dict[str, float]:
    """Each network's threshold from its validation split and its real in-category meshes."""
    return {c: calibrated_threshold(distances[f"val:{c}"][c], distances.get(f"real:{c}", {}).get(c, ()))
            for c in CATEGORIES}


def verdicts(groups: dict, distances: dict, thresholds: dict) -> dict[tuple[str, str], list]:
    """{(group, network): [NetworkVerdict per shape]}."""
    out = {}
    for g, group in groups.items():
        for c in CATEGORIES:
            out[(g, c)] = [network_verdict({n: float(distances[g][n][i]) for n in CATEGORIES}, thresholds, c)
                           for i in range(len(group["names"]))]
    return out


def rates(groups: dict, decided: dict) -> dict:
    """Speak counts per (kind, network) and the route named against the truth (the category, or the fit)."""
    table = {}
    for (g, c), vs in decided.items():
        kind = kind_of(g, c)
        if kind is None:
            continue
        cell = table.setdefault(kind, {}).setdefault(c, {"shapes": 0, "speaks": 0, "route_true": 0, "routes": {}})
        truth = groups[g]["category"] or "fit"
        for v in vs:
            cell["shapes"] += 1
            if v.speaks:
                cell["speaks"] += 1
                cell["route_true"] += v.route == truth
                cell["routes"][v.route] = cell["routes"].get(v.route, 0) + 1
    return table


def print_table(table: dict) -> None:
    print(f"\n{'group':10s} " + " ".join(f"{c:>14s}" for c in CATEGORIES) + f" {'all':>16s}  target")
    for kind in KINDS:
        if kind not in table:
            continue
        cells = [table[kind].get(c, {"shapes": 0, "speaks": 0}) for c in CATEGORIES]
        n, k = sum(x["shapes"] for x in cells), sum(x["speaks"] for x in cells)
        what, level = TARGETS[kind]
        share = (n - k) / n if what == "silent" else k / n
        text = " ".join(f"{x['speaks']:>5d}/{x['shapes']:<4d} spk" for x in cells)
        print(f"{kind:10s} {text} {k:>6d}/{n:<5d} {share:6.1%} {what} ({'met' if share >= level else 'MISSED'}, "
              f">= {level:.0%})")
    for kind in ("off test", "off real", "thin"):
        if kind in table:
            cells = table[kind].values()
            truth = "the fit" if kind == "thin" else "the shape's own category's network"
            print(f"{kind}: the warning names {truth} in {sum(x['route_true'] for x in cells)} of "
                  f"{sum(x['speaks'] for x in cells)} warnings")


def route_costs(groups: dict, decided: dict, per_group: int, seed: int = 0) -> list[dict]:
    """On the first ``per_group`` shapes of each non-validation group (the thin set whole): every network's Chamfer distance, the
    fit's where a route names it, and for each speaking (shape, network) pair the route's against the given's."""
    rows = []
    for g, group in groups.items():
        if g.startswith("val"):
            continue
        for i in range(len(group["names"]) if g == "thin" else min(per_group, len(group["names"]))):
            cloud = group["clouds"][i]
            chamfer = {c: abstract(cloud, c, up="y", seed=seed).chamfer for c in CATEGORIES}
            speaking = [(c, decided[(g, c)][i]) for c in CATEGORIES if decided[(g, c)][i].speaks]
            if any(v.route == "fit" for _, v in speaking):
                start = time.perf_counter()
                chamfer["fit"] = abstract(cloud, None, n_points=N_POINTS, seed=seed).chamfer
                print(f"  {g} {group['names'][i]}: the fit in {time.perf_counter() - start:.1f} s", flush=True)
            for c, v in speaking:
                other = min(chamfer[n] for n in CATEGORIES if n != c)  # the best other network, in hindsight
                rows.append({"group": g, "shape": group["names"][i], "given": c, "route": v.route,
                             "kind": kind_of(g, c), "given_chamfer": chamfer[c], "route_chamfer": chamfer[v.route],
                             "best_other_network_chamfer": other})
    return rows


def fallback_times(groups: dict, decided: dict, seed: int = 0) -> list[dict]:
    """``abstract(..., fallback=True)`` timed on the first speaking pair of each group and route kind."""
    rows, seen = [], set()
    for (g, c), vs in decided.items():
        for i, v in enumerate(vs):
            key = (g.split(":")[0], "fit" if v.route == "fit" else "network")
            if g.startswith("val") or not v.speaks or key in seen:
                continue
            seen.add(key)
            start = time.perf_counter()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                out = abstract(groups[g]["clouds"][i], c, up="y", seed=seed, fallback=True)
            seconds = time.perf_counter() - start
            taken = "fit" if out.method["name"] == "fit" else Path(out.method["checkpoint"]).stem
            rows.append({"group": g, "shape": groups[g]["names"][i], "given": c, "route": v.route, "taken": taken,
                         "seconds": round(seconds, 2), "warned": any(issubclass(w.category, NetworkFitWarning)
                                                                     for w in caught)})
    return rows


def verify(groups: dict, decided: dict, per_group: int) -> int:
    """Run ``abstract(check=True)`` on the first ``per_group`` shapes of each group with each network; count the
    verdicts that differ from the batched ones."""
    differ = 0
    for g, group in groups.items():
        for i in range(min(per_group, len(group["names"]))):
            for c in CATEGORIES:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    record = abstract(group["clouds"][i], c, up="y", check=True).method["network_check"]
                batched = decided[(g, c)][i]
                if (record["speaks"], record["route"]) != (batched.speaks, batched.route):
                    differ += 1
                    print(f"  differs: {g} {group['names'][i]} under {c}: {record} against {batched}")
    return differ


def write_thresholds(thresholds: dict[str, float]) -> Path:
    """Write the calibrated thresholds into ``cuboidlib/network_check.py``'s LATENT_THRESHOLDS line."""
    path = ROOT / "cuboidlib" / "network_check.py"
    text = path.read_text()
    line = "LATENT_THRESHOLDS: dict[str, float] = {" + ", ".join(f'"{c}": {t}' for c, t in thresholds.items()) + "}"
    new, count = re.subn(r"^LATENT_THRESHOLDS: dict\[str, float\] = \{.*\}$", line, text, flags=re.M)
    if count != 1:
        raise SystemExit(f"{path}: expected one LATENT_THRESHOLDS line, found {count}")
    write_text_atomic(path, new)
    return path


def summarise_routes(rows: list[dict]) -> dict:
    """Per group kind and route (another network, the fit): speaking pairs, on how many the route's Chamfer distance
    is below the given network's, the median ratio, and on how many it is at most the best other network's."""
    out = {}
    for kind in KINDS:
        for what in ("network", "fit"):
            mine = [r for r in rows if r["kind"] == kind and (r["route"] == "fit") == (what == "fit")]
            if mine:
                ratio = np.array([r["route_chamfer"] / r["given_chamfer"] for r in mine])
                other = np.array([r["route_chamfer"] / r["best_other_network_chamfer"] for r in mine])
                out[f"{kind}, {what}"] = {"pairs": len(mine), "route_better": int((ratio < 1).sum()),
                                          "median_ratio": round(float(np.median(ratio)), 3),
                                          "route_at_most_best_other_network": int((other <= 1).sum())}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--root", action="append", default=[], metavar="NAME=DIR",
                        help="a source folder of the real meshes (benchmarks/real_meshes/README.md), repeatable")
    parser.add_argument("--write", action="store_true",
                        help="write the calibrated thresholds into cuboidlib/network_check.py and measure with them")
    parser.add_argument("--routes", type=int, default=10, help="shapes per group whose routes are measured")
    parser.add_argument("--verify", type=int, default=2, help="shapes per group run through abstract itself")
    parser.add_argument("--shapes", type=int, default=None, help="at most this many shapes per group (default all)")
    parser.add_argument("--json", type=Path, help="write the measurements here")
    args = parser.parse_args(argv)
    roots = parse_roots(parser, args.root)
    torch.set_num_threads(1)
    start = time.perf_counter()
    groups = load_groups(roots, args.shapes)
    networks = committed_networks()
    distances = {g: latent_distances(group["clouds"][..., :3], group["clouds"][..., 3:], networks)
                 for g, group in groups.items()}
    print(f"latent distances of {sum(len(g['names']) for g in groups.values())} shapes under {len(networks)} "
          f"networks: {time.perf_counter() - start:.0f} s")
    calibrated = calibrate(groups, distances)
    print(f"thresholds: the library's {LATENT_THRESHOLDS}; calibrated now {calibrated}")
    if args.write:
        if args.shapes is not None or not all(f"real:{c}" in groups for c in CATEGORIES):
            parser.error("--write needs every shape and the real meshes of every category (--root ..., no --shapes)")
        print(f"wrote {write_thresholds(calibrated)}")
    thresholds = calibrated if args.write else LATENT_THRESHOLDS
    decided = verdicts(groups, distances, thresholds)
    table = rates(groups, decided)
    print_table(table)
    differ = verify(groups, decided, args.verify)
    print(f"abstract(check=True) on {args.verify} shapes per group and network: {differ} verdicts differ")
    routes = route_costs(groups, decided, args.routes)
    summary = summarise_routes(routes)
    for what, s in summary.items():
        print(f"{what} route: better than the given network (Chamfer) on {s['route_better']} of {s['pairs']} "
              f"speaking pairs, median ratio {s['median_ratio']:.3f}; at most the best other network's on "
              f"{s['route_at_most_best_other_network']}")
    falls = fallback_times(groups, decided)
    for r in falls:
        print(f"fallback=True: {r['group']} {r['shape']} given {r['given']}: took {r['taken']} in {r['seconds']} s")
    if args.json:
        doc = {"command": "python " + " ".join([sys.argv[0]] + (argv if argv is not None else sys.argv[1:])),
               "thresholds": thresholds, "calibrated": calibrated, "table": table, "verify_differ": differ,
               "routes": summary, "route_pairs": routes, "fallback": falls,
               "distances": {g: {c: np.round(d, 2).tolist() for c, d in per.items()} for g, per in distances.items()},
               "names": {g: group["names"] for g, group in groups.items() if not g.startswith(("val", "test"))}}
        write_text_atomic(args.json, json.dumps(doc, indent=1))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
