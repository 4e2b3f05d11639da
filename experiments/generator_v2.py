"""The gate for networks trained on a newer generator (version 2 or later, ``cuboidlib.shapes.GENERATOR_VERSIONS``).

A network trained on version V > 1 replaces the committed one of its category when both hold:

* on the version-1 test split it is at most ``MAX_V1_DROP`` mIoU points below the committed network;
* it is better (higher mIoU) on the version-V test split and on the real meshes of
  ``benchmarks/bench_real_meshes.py``.

For each ``--candidate CATEGORY=RUN`` this scores the committed network and the candidate the same way: the test
splits of versions 1 and V (``cuboidlib evaluate NETWORK --generator-version V``: mIoU by label transfer, the
Chamfer distance, N_AC) and the real meshes of the category (``bench_real_meshes.py --no-fit --no-refine``: mIoU by
label transfer over the category's real meshes, and each shape's Chamfer distance in the file's own units). It
prints the table and the verdict, and writes them with every score to ``--json``.

    python experiments/generator_v2.py --candidate animal=runs/animal_v2/finetune \\
        --root quaternius=/work/realsrc/quaternius --root pyvista=data_samples/real/pyvista \\
        --json experiments/results/generator_v2.json
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from cuboidlib.checkpoint import load_checkpoint  # noqa: E402
from cuboidlib.cli import main as cuboidlib_main  # noqa: E402
from cuboidlib.files import write_text_atomic  # noqa: E402

import bench_real_meshes  # noqa: E402

CATEGORIES = ("chair", "table", "airplane", "animal")
#: The largest mIoU drop on the version-1 test split a candidate may have, in points.
MAX_V1_DROP = 2.0


def split_scores(network: str, version: int) -> dict:
    """``cuboidlib evaluate NETWORK --generator-version VERSION`` on the test split: mIoU (%), CD, N_AC."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "scores.json"
        with contextlib.redirect_stdout(io.StringIO()):
            code = cuboidlib_main(["evaluate", network, "--generator-version", str(version), "--json", str(out)])
        if code != 0:
            raise SystemExit(f"cuboidlib evaluate {network} failed with exit code {code}")
        result = json.loads(out.read_text())["results"][0]
    return {"miou": round(100 * result["miou"], 2), "chamfer": result["chamfer"][0]["value"],
            "n_ac": result["n_ac"]}


def trained_version(run: str) -> int:
    """The generator version a checkpoint (or a run folder's ``best.pt``) was trained on; none recorded: 1."""
    path = Path(run) / "best.pt" if Path(run).is_dir() else Path(run)
    return int(load_checkpoint(path)["config"].get("generator_version", 1))


def real_scores(category: str, network: str, roots: list[str]) -> dict:
    """The network on the category's real meshes: mIoU (%) by label transfer and each shape's Chamfer distance."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "real.json"
        args = ["--categories", category, "--no-fit", "--no-refine", "--seeds", "1", "--json", str(out)]
        args += [a for root in roots for a in ("--root", root)]
        if network != category:
            args += ["--model", f"{category}={network}"]
        with contextlib.redirect_stdout(io.StringIO()):
            bench_real_meshes.main(args)
        doc = json.loads(out.read_text())
    summary = doc["summary"][category]
    return {"miou": round(100 * summary["net_miou"], 2), "shapes": summary["shapes"],
            "part_iou": summary.get("net_part_iou"),
            "chamfer": {row["name"]: row["net"]["chamfer"] for row in doc["shapes"]}}


def verdict(committed: dict, candidate: dict, version: int = 2) -> dict:
    """The gate's three tests and whether the candidate, trained on generator ``version``, passes all of them."""
    new = f"v{version}"
    real_ratio = float(np.median([candidate["real"]["chamfer"][n] / committed["real"]["chamfer"][n]
                                  for n in committed["real"]["chamfer"]]))
    tests = {
        "v1_drop": round(committed["v1"]["miou"] - candidate["v1"]["miou"], 2),
        "v1_within": committed["v1"]["miou"] - candidate["v1"]["miou"] <= MAX_V1_DROP,
        f"{new}_better": candidate[new]["miou"] > committed[new]["miou"],
        "real_better": candidate["real"]["miou"] > committed["real"]["miou"],
        "real_chamfer_median_ratio": round(real_ratio, 3),
    }
    tests["replaces"] = tests["v1_within"] and tests[f"{new}_better"] and tests["real_better"]
    return tests


def markdown(docs: list[dict]) -> str:
    """The Markdown table of earlier ``--json`` files (``--table``): per category and candidate's generator version V,
    both networks' mIoU on the version-1 and version-V test splits and on the real meshes, the Chamfer distances
    x1000, and the verdict."""
    lines = ["| category | network | V | v1 mIoU | vV mIoU | real mIoU | v1 CD x1000 | vV CD x1000 | real CD / committed's "
             "(median) | replaces |", "|" + " --- |" * 10]
    shown = set()
    for doc in docs:
        version = doc.get("version", 2)  # files written before version 3 scored version 2
        new = f"v{version}"
        for category, scores in doc["categories"].items():
            v = scores["verdict"]
            for label in ("committed", "candidate"):
                if label == "committed" and (category, version) in shown:  # the same network, scored the same way
                    continue
                shown.add((category, version))
                s = scores[label]
                where = Path(s["network"])  # a candidate's folders name it (results/generator_v2/<name>/best.pt)
                where = where.parent if where.suffix else where
                name = "committed, version 1" if label == "committed" else f"{label} ({where.parent.name}/{where.name})"
                ratio = "1" if label == "committed" else f"{v['real_chamfer_median_ratio']:.2f}"
                replaces = "" if label == "committed" else ("yes" if v["replaces"] else "no")
                lines.append(f"| {category} | {name} | {version} | {s['v1']['miou']:.1f} | {s[new]['miou']:.1f} | "
                             f"{s['real']['miou']:.1f} | {1000 * s['v1']['chamfer']:.3f} | "
                             f"{1000 * s[new]['chamfer']:.3f} | {ratio} | {replaces} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--candidate", action="append", default=[], metavar="CATEGORY=RUN",
                        help="a network trained on version 2 or later: a checkpoint or a training run's folder, "
                        "repeatable; every candidate of one call trained on the same version")
    parser.add_argument("--root", action="append", default=[], metavar="NAME=DIR",
                        help="a source folder of the real meshes (benchmarks/real_meshes/README.md), repeatable")
    parser.add_argument("--json", type=Path, help="write every score and the verdicts here")
    parser.add_argument("--table", type=Path, nargs="+", metavar="FILE.json",
                        help="print the Markdown table of earlier --json files, and nothing else")
    args = parser.parse_args(argv)
    if args.table:
        print(markdown([json.loads(path.read_text()) for path in args.table]))
        return 0
    if not args.candidate:
        parser.error("give at least one --candidate CATEGORY=RUN (or --table)")
    candidates = {}
    for item in args.candidate:
        category, sep, run = item.partition("=")
        if not sep or category not in CATEGORIES or not Path(run).exists():
            parser.error(f"--candidate takes CATEGORY=RUN with CATEGORY one of {', '.join(CATEGORIES)} and RUN an "
                         f"existing checkpoint or run folder, got {item!r}")
        candidates[category] = run
    versions = {trained_version(run) for run in candidates.values()}
    if len(versions) != 1 or min(versions) < 2:
        parser.error(f"the candidates must be trained on one generator version, 2 or later; they were on {sorted(versions)}")
    version = versions.pop()
    new = f"v{version}"
    doc = {"command": "python " + " ".join([sys.argv[0]] + (argv if argv is not None else sys.argv[1:])),
           "max_v1_drop": MAX_V1_DROP, "version": version, "categories": {}}
    print(f"{'category':9s} {'network':34s} {'v1 mIoU':>8s} {new + ' mIoU':>8s} {'real mIoU':>10s} {'v1 CD x1000':>12s} "
          f"{new + ' CD x1000':>12s}")
    for category, run in candidates.items():
        scores = {}
        for label, network in (("committed", category), ("candidate", run)):
            scores[label] = {"network": network, "v1": split_scores(network, 1), new: split_scores(network, version),
                             "real": real_scores(category, network, args.root)}
            s = scores[label]
            print(f"{category:9s} {network[-34:]:34s} {s['v1']['miou']:8.1f} {s[new]['miou']:8.1f} "
                  f"{s['real']['miou']:10.1f} {1000 * s['v1']['chamfer']:12.3f} {1000 * s[new]['chamfer']:12.3f}",
                  flush=True)
        scores["verdict"] = verdict(scores["committed"], scores["candidate"], version)
        print(f"{category:9s} verdict: {json.dumps(scores['verdict'])}", flush=True)
        doc["categories"][category] = scores
    if args.json:
        write_text_atomic(args.json, json.dumps(doc, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
