"""Summaries and result files of the experiment scripts (used through :mod:`runner`).

* :func:`result_rows` flattens run records to one row per (run, method), the metrics under today's names
  (:func:`current_metrics`); :func:`summarize` groups
  rows and gives the mean, sample standard deviation and count of every metric; :func:`mean_sd`,
  :func:`paper_value` and :func:`text_table` format them.
* :func:`write_results` writes ``experiments/results/<name>.json`` (everything, with provenance from
  :func:`machine`) and ``<name>.csv`` (the summary table).
"""

from __future__ import annotations

import csv
import io
import json
import os
import platform
import statistics
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from cuboidlib.files import write_text_atomic

__all__ = ["RENAMED_METRICS", "current_metrics", "result_rows", "summarize", "mean_sd", "paper_value", "text_table", "CD_CONVENTION", "machine",
           "write_results"]


# ----------------------------------------------------------------------------------------------
# Summaries and tables
# ----------------------------------------------------------------------------------------------


#: Metrics renamed after records were written: old name -> name today. Runs pinned to an older commit (the
#: 15-minute ablations) keep writing the old name, so every reader of records goes through :func:`current_metrics`.
RENAMED_METRICS = {"flatness": "thickness"}


def current_metrics(metrics: dict) -> dict:
    """A run's metrics under today's names (:data:`RENAMED_METRICS`); a record holding both names keeps today's."""
    renamed = {RENAMED_METRICS.get(k, k): v for k, v in metrics.items() if k in RENAMED_METRICS}
    return {**renamed, **{k: v for k, v in metrics.items() if k not in RENAMED_METRICS}}


def result_rows(records: Sequence[dict]) -> list[dict]:
    """One flat row per (successful run, method): the run's key, ``method`` and the metrics (today's names)."""
    rows = []
    for record in records:
        if record.get("status") != "ok":
            continue
        for result in record["results"]:
            rows.append({**record["key"], "method": result["method"], **current_metrics(result["metrics"])})
    return rows


def summarize(rows: Sequence[dict], by: Sequence[str], metrics: Sequence[str]) -> list[dict]:
    """Group ``rows`` by the ``by`` fields (in order of first appearance) and give, per metric, the
    mean, the sample standard deviation over the group (None for one value) and the count n.

    Each summary row holds the ``by`` fields, ``seeds`` (the seeds of the group) and
    ``<metric>_mean``, ``<metric>_sd``, ``<metric>_n`` (missing / None values are left out).
    """
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault(tuple(row.get(k) for k in by), []).append(row)
    out = []
    for values, members in groups.items():
        summary = dict(zip(by, values))
        summary["seeds"] = [m["seed"] for m in members if "seed" in m]
        for metric in metrics:
            xs = [float(m[metric]) for m in members if m.get(metric) is not None]
            summary[f"{metric}_mean"] = statistics.fmean(xs) if xs else None
            summary[f"{metric}_sd"] = statistics.stdev(xs) if len(xs) > 1 else None
            summary[f"{metric}_n"] = len(xs)
        out.append(summary)
    return out


def mean_sd(row: dict, metric: str, scale: float = 1.0, digits: int = 3) -> str:
    """"mean ± sd" of a summary row's metric (times ``scale``), "mean" for one value, "-" for none."""
    mean, sd = row.get(f"{metric}_mean"), row.get(f"{metric}_sd")
    if mean is None:
        return "-"
    text = f"{scale * mean:.{digits}f}"
    return text if sd is None else f"{text} ± {scale * sd:.{digits}f}"


def paper_value(value: float | None, digits: int = 3) -> str:
    """A number typed from the paper, or "-" where the paper gives none."""
    return "-" if value is None else f"{value:.{digits}f}"


def text_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A plain-text table: first column left-aligned, the others right-aligned."""
    widths = [max(len(str(r[i])) for r in [headers, *rows]) for i in range(len(headers))]

    def fmt(row) -> str:
        return "  ".join(str(c).ljust(w) if i == 0 else str(c).rjust(w) for i, (c, w) in enumerate(zip(row, widths)))

    return "\n".join([fmt(headers), fmt(["-" * w for w in widths]), *(fmt(r) for r in rows)])


CD_CONVENTION = ("CD: Chamfer distance x 1000, squared L2, mean over points per direction, sum of the two "
                 "directions, 4096 points sampled on the existing cuboids (cuboidlib.metrics.ChamferConvention()); "
                 "mean ± sample standard deviation over seeds where there are several.")


def machine() -> dict:
    """The machine a script ran on (CPUs, torch and Python versions, platform, load average)."""
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    return {"cpus": os.cpu_count(), "torch_threads_per_run": 1, "torch": torch.__version__,
            "python": platform.python_version(), "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "load_average_at_start": None if load is None else [round(x, 2) for x in load]}


def write_results(path_stem: Path, payload: dict, summary: Sequence[dict]) -> tuple[Path, Path]:
    """Write ``<stem>.json`` (``payload``, which must hold the provenance) and ``<stem>.csv`` (``summary``),
    each atomically (a reader never sees half a file)."""
    path_stem.parent.mkdir(parents=True, exist_ok=True)
    json_path, csv_path = path_stem.with_suffix(".json"), path_stem.with_suffix(".csv")
    write_text_atomic(json_path, json.dumps(payload, indent=1, default=_json_default) + "\n")
    columns: list[str] = []
    for row in summary:
        columns += [k for k in row if k not in columns]
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, columns)
    writer.writeheader()
    for row in summary:
        writer.writerow({k: (" ".join(map(str, v)) if isinstance(v, list) else v) for k, v in row.items()})
    write_text_atomic(csv_path, text.getvalue())
    return json_path, csv_path


def _json_default(value):
    if isinstance(value, (np.integer, np.floating)):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
