"""Display helpers of lessons 08 and 09: read the committed results, print tables, and write verdicts in words.

Lessons 08 and 09 put ``experiments/`` on ``sys.path`` and import this module in their first code cell, so the
lessons' cells hold the experiments and not the plumbing. Every verdict comes from :mod:`ablations` (the rule and the
tests); this module only reads values and formats them.

* :func:`load_results` reads ``results/<name>.json``; :func:`value`, :func:`seeds` and :func:`span` read one cell.
* :func:`table_text` and :func:`table_html` format a table; :func:`show_table` displays both forms.
* :func:`show_verdicts` prints every test's verdict at each scale; :func:`verdict_sentence` and
  :func:`verdict_line` turn verdicts into a sentence, so that the lesson's prose cannot go stale.
* :func:`fifteen_rows` and :func:`show_fifteen` give a 15-minute table: the finished cells and what is pending;
  :func:`check_fifteen` checks that each verdict counts exactly the records read.
* :func:`config_differences` lists the fields where two run configurations differ.
* :func:`summary_rows` builds the summary's two tables (the paper's claims, the course's tests);
  :func:`luck_rows` counts the verdicts that luck alone would settle.
* :func:`loss_rows` lists the loss weights of groups of runs (lesson 08's losses table).
"""

from __future__ import annotations

import html
import json
import statistics
from pathlib import Path
from typing import Sequence

import ablations
import runner

#: The committed results files that lessons 08 and 09 read.
RESULT_NAMES = ("table1_2_comparison", "table3_supervision", "table4_distance", "table5_compactness",
                "table5_compactness_15min", "table6_num_cuboids", "fig8_supervision", "fig9_nearest_surface",
                "fig10_compactness", "fig11_point_density", "paper_vs_code")


def load_results(results_dir: str | Path = runner.RESULTS_DIR, names: Sequence[str] = RESULT_NAMES) -> dict:
    """name -> the parsed ``<results_dir>/<name>.json`` of each name."""
    return {name: json.loads((Path(results_dir) / f"{name}.json").read_text()) for name in names}


# ----------------------------------------------------------------------------------------------
# Reading one cell
# ----------------------------------------------------------------------------------------------


def value(result: dict, metric: str, **where) -> float:
    """The mean of ``metric`` in a results file's summary, on the one row whose fields match ``where``."""
    rows = [r for r in result["summary"] if all(r.get(k) == v for k, v in where.items())]
    if len(rows) != 1:
        raise ValueError(f"{where} matches {len(rows)} summary rows, not one")
    return rows[0][f"{metric}_mean"]


def seeds(result_or_runs: dict | Sequence[dict], metric: str, **where) -> list[float]:
    """The metric of every run (seed) of one cell, from a results file or a list of run records."""
    runs = result_or_runs["runs"] if isinstance(result_or_runs, dict) else result_or_runs
    return ablations.cell_values(runs, where, metric)


def span(xs: Sequence[float], scale: float = 1.0, digits: int = 2) -> str:
    """A cell's lowest and highest seed, "1.00 to 1.20" (the range the rule compares); "1.10 (1 seed)" for a single
    seed; "-" when there is none."""
    if not xs:
        return "-"
    if len(xs) == 1:
        return f"{scale * xs[0]:.{digits}f} (1 seed)"
    return f"{scale * min(xs):.{digits}f} to {scale * max(xs):.{digits}f}"


# ----------------------------------------------------------------------------------------------
# Tables
# ----------------------------------------------------------------------------------------------


def table_text(header: Sequence, rows: Sequence[Sequence]) -> str:
    """The table as aligned text: the first column left-aligned, the others right-aligned."""
    cells = [[str(x) for x in row] for row in [header, *rows]]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    lines = []
    for row in cells:
        first, *rest = zip(row, widths)
        lines.append("  ".join([first[0].ljust(first[1]), *(x.rjust(w) for x, w in rest)]))
    return "\n".join(lines)


def table_html(header: Sequence, rows: Sequence[Sequence]) -> str:
    """The table as an HTML ``<table>``, every cell escaped."""
    def line(row, tag):
        return "<tr>" + "".join(f"<{tag}>{html.escape(str(x))}</{tag}>" for x in row) + "</tr>"
    return "<table>" + line(header, "th") + "".join(line(row, "td") for row in rows) + "</table>"


def show_table(header: Sequence, rows: Sequence[Sequence]) -> None:
    """Display a table in two forms: HTML for Jupyter and GitHub, aligned text for a terminal (and nbval)."""
    from IPython.display import display
    display({"text/html": table_html(header, rows), "text/plain": table_text(header, rows)}, raw=True)


def show_markdown(text: str) -> None:
    """Display a computed sentence as Markdown (its text form is the same string)."""
    from IPython.display import Markdown, display
    display(Markdown(text))


def legend_below(fig, ax, ncol: int = 4) -> None:
    """One legend for the whole figure, under its panels, where it hides no data."""
    fig.legend(*ax.get_legend_handles_labels(), loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=ncol,
               frameon=False, fontsize=9)


def plain_log(ax) -> None:
    """A log y-axis labelled 1, 2, 5, 10, ... instead of 10^0 and 4x10^0."""
    from matplotlib.ticker import FuncFormatter
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}" if f"{v:.0e}"[0] in "25" else ""))


# ----------------------------------------------------------------------------------------------
# Verdicts in words
# ----------------------------------------------------------------------------------------------


def said(v: dict) -> str:
    """A verdict in a table's words; an unresolved one says why ("unresolved at three seeds: the runs overlap")."""
    return ablations.word(v) + (f": {v['why']}" if v["verdict"] == "unresolved at three seeds" else "")


def show_verdicts(tests: Sequence[ablations.Test], **scales: Sequence[dict]) -> dict[str, list[dict]]:
    """Display the verdict of every test at each scale (scale name -> its run records); return them by scale."""
    found = {scale: [ablations.verdict(t, runs) for t in tests] for scale, runs in scales.items()}
    header = ["test", *[scale.replace("_", " ") for scale in scales]]
    rows = [[ablations.describe(t), *[said(found[scale][i]) for scale in scales]] for i, t in enumerate(tests)]
    show_table(header, rows)
    return found


def _join(items: Sequence[str]) -> str:
    items = list(items)
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def verdict_sentence(verdicts: Sequence[tuple]) -> str:
    """Which tests hold and which fail, in one to three sentences, from (claim, verdict) or (claim, where, verdict).

    The claim is an :class:`ablations.Test` or a string. A test is put in :func:`ablations.in_words`' words: what it
    claims where it holds ("P2C-Seg's Chamfer distance is below P2C-Dis's"), what was found where it fails
    ("P2C-Seg's Chamfer distance lies above P2C-Dis's"); a string is used as it is. ``where``
    names the cell it ran on ("chairs"), and one claim that passes in several places is named once ("on airplanes
    and tables: ..."). Claims that hold come first, then those that fail; the rest are counted by verdict.
    Written from the verdicts, the sentence changes with them.
    """
    groups: dict[str, dict[str, list[str]]] = {}  # verdict -> claim -> wheres
    for item in verdicts:
        label, where, v = item if len(item) == 3 else (item[0], None, item[1])
        if isinstance(label, ablations.Test):
            label = ablations.in_words(label, negated=v["verdict"] == "fails")
        groups.setdefault(v["verdict"], {}).setdefault(label, []).extend([where] if where else [])

    def named(word: str) -> tuple[str, int]:
        found = groups.get(word, {})
        items = [f"on {_join(wheres)}, {label}" if wheres else label for label, wheres in found.items()]
        return "; ".join(items), sum(max(len(w), 1) for w in found.values())

    holds, n_holds = named("holds")
    fails, n_fails = named("fails")
    parts = [f"By the rule, {'this holds' if n_holds == 1 else 'these hold'}: {holds}." if holds
             else "No test holds by the rule."]
    if fails:
        parts.append(f"{'This test fails' if n_fails == 1 else 'These tests fail'}, "
                     f"the runs lying apart the other way: {fails}.")
    rest = {w: sum(max(len(x), 1) for x in found.values()) for w, found in groups.items() if w not in ("holds", "fails")}
    if rest:
        counted = [f"{n} {'is' if n == 1 and i == 0 else 'are' if i == 0 else ''} {w}".replace("  ", " ")
                   for i, (w, n) in enumerate(rest.items())]
        parts.append(f"Of the other tests, {_join(counted)}.")
    return " ".join(parts)


def verdict_line(tests: Sequence[ablations.Test], records: Sequence[dict], scale: str = "the 15-minute scale") -> str:
    """The verdict of each of the tests' claims, in one Markdown line computed from the records:
    "**Verdict at the 15-minute scale:** <claim>: <verdict>; ..." (a pending claim counts its runs)."""
    judged = ablations.judge(tests, records)
    return f"**Verdict at {scale}:** " + "; ".join(f"{claim}: *{word}*" for claim, word in judged.items()) + "."


# ----------------------------------------------------------------------------------------------
# The 15-minute tables
# ----------------------------------------------------------------------------------------------


_NOT_SHOWN = ("finished", "planned", "category", "distance")  # the same in every cell of the 15-minute tables


def _cell(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in ("finished", "planned")}


def _name(row: dict) -> str:
    return ", ".join(v if isinstance(v, str) else f"{k} {v:g}" for k, v in row.items() if k not in _NOT_SHOWN)


def fifteen_rows(table: str, records: Sequence[dict], metrics: Sequence[tuple[str, float, int, str]],
                 first_look: Sequence[dict]) -> tuple[list[str], list[list[str]], str]:
    """A 15-minute table: (header, one row per planned cell, a line on what is finished and pending).

    Args:
        table: "table3", "table4" or "table6".
        records: its finished 15-minute records (:func:`ablations.read_records`).
        metrics: (metric, scale, digits, label) of each column; each cell gives its seeds' range.
        first_look: the 600-step runs of the same cells; the first metric's 600-step median closes each row (a
            median, since one far run can carry a mean of three).
    """
    rows = ablations.cells(table, records)
    keys = [k for k in rows[0] if k not in _NOT_SHOWN]
    metric, scale, digits, label = metrics[0]
    header = [*keys, "seeds finished", *[f"{m[3]}, 15 min" for m in metrics], f"{label}, 600 steps (median)"]
    body = []
    for row in rows:  # a cell with no finished seed shows "-" in its 15-minute columns
        ranges = [span(seeds(records, m, **_cell(row)), s, d) for m, s, d, _ in metrics]
        first = statistics.median(seeds(first_look, metric, **_cell(row)))
        body.append([*(row[k] for k in keys), f"{row['finished']} of {row['planned']}", *ranges,
                     f"{scale * first:.{digits}f}"])
    missing = {_name(row): row["planned"] - row["finished"] for row in rows if row["finished"] < row["planned"]}
    waiting = [f"{name} ({n} {'seed' if n == 1 else 'seeds'} missing)" for name, n in missing.items()]
    line = f"finished: {len(records)} of {len(ablations.planned_runs(table))} runs"
    if waiting:
        line += "; pending: " + ("every cell" if len(waiting) == len(rows) else "; ".join(waiting))
    return header, body, line


def show_fifteen(table: str, records: Sequence[dict], metrics: Sequence[tuple[str, float, int, str]],
                 first_look: Sequence[dict]) -> None:
    """Display :func:`fifteen_rows`: the table, then the line on what is finished and pending."""
    header, body, line = fifteen_rows(table, records, metrics, first_look)
    show_table(header, body)
    print(line)


def check_fifteen(table: str, tests: Sequence[ablations.Test], found: Sequence[dict], records: Sequence[dict]) -> None:
    """Check a 15-minute table at any stage of its runs: the records read are planned runs of the 15-minute recipe,
    one each, and each verdict counts exactly them and is "pending" exactly while a cell has fewer than three seeds.

    Args:
        table: "table3", "table4" or "table6".
        tests, found: the table's tests and their verdicts on ``records`` (:func:`show_verdicts`'s "fifteen_minutes").
        records: the table's finished runs (:func:`ablations.read_records`).
    Raises:
        AssertionError: naming the first check that fails.
    """
    planned = {run.name for run in ablations.planned_runs(table)}
    names = [r["name"] for r in records]
    counts = [[sum(all(r["key"][k] == x for k, x in cell.items()) for r in records) for cell in t.cells] for t in tests]
    checks = [(set(names) <= planned, f"{table}: records of runs it does not plan: {sorted(set(names) - planned)}"),
              (len(set(names)) == len(names), f"{table}: one record per finished run"),
              (all(r["config"]["n_shapes"] == runner.FIFTEEN_MINUTE_SHAPES for r in records), f"{table}: 15-minute runs only"),
              (len(tests) == len(found), f"{table}: one verdict per test")]
    for t, v, n in zip(tests, found, counts):
        checks += [(v["finished"] == sum(n), f"{ablations.describe(t)}: counts {v['finished']} runs, {sum(n)} were read"),
                   ((v["verdict"] == "pending") == (min(n) < 3), f"{ablations.describe(t)}: {v['verdict']} with seeds {n}")]
    failed = [why for ok, why in checks if not ok]
    if failed:
        raise AssertionError(failed[0])


# ----------------------------------------------------------------------------------------------
# Records
# ----------------------------------------------------------------------------------------------



def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def config_differences(a: dict, b: dict) -> list[tuple[str, object, object]]:
    """(field, a's value, b's value) for every field where two nested configurations differ, in a's order
    ("loss.lambda_compact"); a field missing on one side reads None there."""
    fa, fb = _flatten(a), _flatten(b)
    fields = [*fa, *(k for k in fb if k not in fa)]
    return [(k, fa.get(k), fb.get(k)) for k in fields if fa.get(k) != fb.get(k)]


#: The two forms of the compactness loss, by the configuration field ``loss.compactness_average``.
LOSS_FORMS = {True: "Eq. (6) / M^2", False: "Eq. (6) as printed"}


def loss_rows(groups: Sequence[tuple[str, Sequence[dict]]]) -> list[list[str]]:
    """The losses table of lesson 08: the loss weights that each group of runs trained with.

    Args:
        groups: ``(label, runs)`` pairs. A run is a results record or a release card. Its stages are its
            ``"config"``, plus ``"finetune_config"`` (a 15-minute run's second stage) or
            ``"initialised_from"["config"]`` (a released network's first stage) where there is one.

    Returns:
        One row per group: ``[label, compactness weights, their forms, existence weights, KL weights]``. Each
        entry lists the distinct values over every stage of every run, comma-separated, the weights in
        increasing order, the form Eq. (6) / M^2 first.
    """
    rows = []
    for label, runs in groups:
        configs = []
        for run in runs:
            configs.append(run["config"])
            if run.get("finetune_config"):
                configs.append(run["finetune_config"])
            if run.get("initialised_from"):
                configs.append(run["initialised_from"]["config"])
        losses = [config["loss"] for config in configs]
        weights = lambda field: ", ".join(f"{w:g}" for w in sorted({loss[field] for loss in losses}))
        forms = sorted({loss["compactness_average"] for loss in losses}, reverse=True)
        rows.append([label, weights("lambda_compact"), ", ".join(LOSS_FORMS[f] for f in forms),
                     weights("lambda_exist"), weights("lambda_kl")])
    return rows


# ----------------------------------------------------------------------------------------------
# The summary, and how many clear verdicts luck alone would give
# ----------------------------------------------------------------------------------------------

#: The summary's experiments, in the order of the paper.
EXPERIMENTS = ("Tables 1-2", "Table 3", "Table 4", "Table 5", "Table 6", "Fig. 11", "the authors' code")


def summary_rows(first: dict, fifteen: dict, extra: Sequence[Sequence] = ()) -> dict[str, list[list]]:
    """The summary's two tables: source ("paper", "course") -> rows [experiment, claim, first look, 15-minute
    recipe]. ``first`` and ``fifteen`` map the same tables of :data:`ablations.TESTS` to their run records at each
    scale (a lesson passes the tables it covers);
    ``extra`` adds rows [experiment, claim, source, first look, 15-minute recipe] for claims outside those tests.
    Rows follow :data:`EXPERIMENTS`; within an experiment the extra rows come first."""
    unknown = set(first) ^ set(fifteen) | set(first) - set(ablations.TESTS)
    if unknown:
        raise ValueError(f"first and fifteen must name the same tables of {tuple(ablations.TESTS)}; check {sorted(unknown)}")
    rows = [list(row) for row in extra]
    for table in first:
        tests = ablations.TESTS[table]
        late, whose = ablations.judge(tests, fifteen[table]), ablations.sources(tests)
        rows += [[f"Table {table[-1]}", claim, whose[claim], word, late[claim]]
                 for claim, word in ablations.judge(tests, first[table]).items()]
    rows.sort(key=lambda row: EXPERIMENTS.index(row[0]))  # stable: extra rows stay first in their experiment
    words = {ablations.SOURCE_WORDS[s]: s for s in ablations.SOURCES}
    out: dict[str, list[list]] = {s: [] for s in ablations.SOURCES}
    for experiment, claim, source, word, late in rows:
        out[words.get(source, source)].append([experiment, claim, word, late])
    return out


def luck_rows(tests: Sequence[ablations.Test], draws: int = 20_000, seed: int = 0, seeds: int = 3) -> list[list]:
    """How many verdicts luck alone would settle when no cell differs from another. One row per kind of test and
    number of cells: [kind, cells, tests, chance of monotone means, chance, expected]. A "difference" settles by
    luck when the seeds are apart either way (2 of C(6, 3) orders); a "no difference" when they are apart the way it
    rules out (1 order); a trend when it holds or fails, simulated (seeded) with the rule of :mod:`ablations`."""
    import math

    import torch

    orders = math.comb(2 * seeds, seeds)
    groups: dict[tuple[str, int], list] = {}
    for t in tests:
        kind = "trend" if t.kind in ("falls", "grows") else "no difference" if t.kind.startswith("not_") else "difference"
        groups.setdefault((kind, len(t.cells)), []).append(t)
    gen = torch.Generator().manual_seed(seed)
    rows = []
    for (kind, n), group in groups.items():
        monotone = 2 / math.factorial(n) if kind == "trend" else None
        if kind == "trend":
            values = torch.randn(draws, n, seeds, generator=gen).tolist()  # equal cells: every seed from one law
            chance = sum(ablations._compare(group[0], v)[0] in ("holds", "fails") for v in values) / draws
        else:
            chance = (2 if kind == "difference" else 1) / orders
        rows.append([kind, n, len(group), monotone, chance, len(group) * chance])
    return rows
