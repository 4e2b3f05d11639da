"""The 15-minute ablations (README, "The 15-minute ablations"): what the finished runs say.

``ablations_15min.sh`` trains Tables 3, 4 and 6 on chairs at the 15-minute recipe's scale, three seeds a cell. Each
finished run leaves ``results/runs_15min/<script>_15min/<stamp>/<run>/record.json``. This module reads whatever
records are there and applies the tests the README states before the runs:

* two cells **differ** when their runs do not overlap: every run of one lies below every run of the other (were
  the cells the same, three runs each would do this by chance with probability 2/20 = 0.1);
* a **trend** over M holds when the means are monotone and the ends (M = 8 against M = 24) differ.

The same tests apply to the 600-step runs of the same cells (``results/<script>.json``, the first look), and the
same rule to Table 5's 15-minute runs (``results/table5_compactness_15min.json``), whose tests were written after them.

A test's verdict is "holds", "fails" or "unresolved at three seeds" (the runs overlap): results. While some of
its runs have not finished, it is "pending", which is no result at all (:func:`word` writes "pending (k of n
runs)"). Table 4's normal consistency is measured both ways (``nc_both``), as lesson 09 reads it. Records written before the rename of ``flatness`` are read with today's metric names
(:func:`summaries.result_rows`).
"""

from __future__ import annotations

import json
import statistics
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import command_line
import runner
import table3_supervision as table3
import table4_distance as table4
import table5_compactness as table5
import table6_num_cuboids as table6

#: Where ``ablations_15min.sh`` keeps the records of the finished runs (its ``--runs-dir``).
RUNS_15MIN = runner.RESULTS_DIR / "runs_15min"

#: table -> (its script, the options ``ablations_15min.sh`` gives it besides :data:`COMMON`).
ABLATIONS = {
    "table3": (table3, ("--categories", "chair")),
    "table4": (table4, ("--noise", "0,0.03", "--columns", "Normal-0,Normal-0.05")),
    "table6": (table6, ("--categories", "chair")),
}
#: The options ``ablations_15min.sh`` gives every table that decide which runs there are.
COMMON = ("--recipe", runner.FIFTEEN_MINUTES, "--seeds", "3")

#: What a test asks of its cells: a below b, a above b, a not above b, a not below b, means falling or growing.
KINDS = ("lower", "higher", "not_higher", "not_lower", "falls", "grows")
#: Whose claim a test decides: the paper's text states it, or the course added it. SOURCE_WORDS: each in a table.
SOURCES = ("paper", "course")
SOURCE_WORDS = {"paper": "the paper's claim", "course": "course test"}


@dataclass(frozen=True)
class Test:
    """One comparison stated before the runs. claim: the paper's claim it decides. metric: a key of the runs'
    metrics. cells: the cells it compares (each a dict of key fields), two for a comparison, in order of M for a
    trend. kind: one of :data:`KINDS`; the first cell is "a". source: one of :data:`SOURCES`: "paper" when the
    paper's text makes the claim, "course" when the course added it (the paper's text does not state it)."""

    claim: str
    metric: str
    cells: tuple[dict, ...]
    kind: str
    source: str = "paper"

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"source must be one of {SOURCES}, got {self.source!r}")
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")
        if len(self.cells) < 2 or (self.kind not in ("falls", "grows") and len(self.cells) != 2):
            raise ValueError(f"a {self.kind!r} test compares {'two' if self.kind not in ('falls', 'grows') else 'two or more'} "
                             f"cells, got {len(self.cells)}")


def table3_tests(category: str = "chair") -> list[Test]:
    """Table 3's claim on one category: P2C-Seg's Chamfer distance below each other variant's (the paper's claim),
    and its mIoU above (a course test: the paper's Table 3 reports the Chamfer distance only)."""
    seg, cat = {"category": category, "variant": "P2C-Seg"}, {"category": category}
    return [Test(f"P2C-Seg gives the {word}", metric, (seg, {**cat, "variant": other}), kind, source)
            for word, metric, kind, source in (("lowest Chamfer distance", "cd", "lower", "paper"),
                                               ("highest mIoU", "miou", "higher", "course"))
            for other in ("P2C-Dis", "Chamfer-Dis")]


def table4_tests() -> list[Test]:
    """Table 4's claim on sigma_s (chairs): sigma_s = 0.05 against 0 under the most noise (the paper's claim), and
    without noise (a course test: the paper's clean-input CD even rises a little with sigma_s)."""
    cell = lambda sigma_n, sigma_s: {"sigma_n": sigma_n, "distance": "Normal", "sigma_s": sigma_s}  # noqa: E731
    noisy, clean = max(table4.NOISE), 0.0
    return [Test("sigma_s > 0 is robust to noise", "cd", (cell(noisy, 0.05), cell(noisy, 0.0)), "lower"),
            Test("sigma_s > 0 is robust to noise", "nc_both", (cell(noisy, 0.05), cell(noisy, 0.0)), "higher"),
            Test("sigma_s > 0 costs nothing on clean input", "cd", (cell(clean, 0.05), cell(clean, 0.0)), "not_higher",
                 "course"),
            Test("sigma_s > 0 costs nothing on clean input", "nc_both", (cell(clean, 0.05), cell(clean, 0.0)),
                 "not_lower", "course")]


def table6_tests(category: str = "chair") -> list[Test]:
    """Table 6's claim on one category: over M = 8 ... 24 the Chamfer distance falls (the paper's claim) and N_AC
    grows (a course test: the paper's table shows it, its text does not claim it)."""
    cells = tuple({"category": category, "M": m} for m in table6.NUM_CUBOIDS)
    return [Test("the Chamfer distance falls with M", "cd", cells, "falls"),
            Test("more cuboids are used with a larger M", "n_ac", cells, "grows", "course")]


def table5_tests(weights: Sequence[float] = table5.LAMBDAS) -> list[Test]:
    """Table 5's claims (chairs), the same rule applied after its runs: with lambda_1, N_AC falls and the Chamfer
    distance grows; the largest weight loses structure (its mIoU below the second weight's, the paper's best)."""
    cells = tuple({"lambda_1": w} for w in weights)
    return [Test("fewer cuboids with a larger lambda_1", "n_ac", cells, "falls"),
            Test("a larger Chamfer distance with a larger lambda_1", "cd", cells, "grows"),
            Test("the largest lambda_1 loses structure, in mIoU (below 0.05)", "miou", (cells[-1], cells[1]), "lower")]


#: table -> its tests on chairs, as the README states them (Table 5's: the same rule, applied after its runs).
TESTS = {"table3": table3_tests(), "table4": table4_tests(), "table5": table5_tests(), "table6": table6_tests()}


def _check_table(table: str) -> None:
    if table not in ABLATIONS:
        raise ValueError(f"table must be one of {tuple(ABLATIONS)}, got {table!r}")


def planned_runs(table: str) -> list[runner.Run]:
    """The runs ``bash experiments/ablations_15min.sh <table>`` makes (nothing is trained)."""
    _check_table(table)
    module, options = ABLATIONS[table]
    args = module.EXPERIMENT.parser().parse_args([*options, *COMMON])
    return module.EXPERIMENT.build_runs(command_line.scale_from_args(args, module.EXPERIMENT), args)


def read_records(table: str, root: str | Path = RUNS_15MIN) -> list[dict]:
    """The records of ``table``'s finished runs under ``root``, in the order of :func:`planned_runs`.

    Args:
        table: "table3", "table4" or "table6".
        root: the folder ``ablations_15min.sh`` writes to (default ``experiments/results/runs_15min``); it must exist.
    Returns:
        One record per finished planned run (``record.json``, status "ok", the planned run's name and key); where
        several invocations finished the same run, the newest one's. Records of other runs are left out.
    """
    _check_table(table)
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"no folder of 15-minute runs at {root}")
    planned = {run.name: run for run in planned_runs(table)}
    folder = root / f"{ABLATIONS[table][0].EXPERIMENT.name}_{runner.FIFTEEN_MINUTES}"
    found = {}
    for path in sorted(folder.glob(f"*/*/{runner.RECORD_FILE}")):  # the stamps sort by time: a newer record wins
        record = json.loads(path.read_text())
        run = planned.get(record.get("name"))
        if record.get("status") == "ok" and run is not None and record.get("key") == json.loads(json.dumps(run.key)):
            found[run.name] = record
    return [found[name] for name in planned if name in found]


def _matches(key: dict, cell: dict) -> bool:
    return all(key.get(k) == v for k, v in cell.items())


def cell_values(records: Sequence[dict], cell: dict, metric: str) -> list[float]:
    """The metric of every finished seed of one cell (today's metric names), in the records' order."""
    return [row[metric] for row in runner.result_rows(records) if _matches(row, cell) and row.get(metric) is not None]


def cells(table: str, records: Sequence[dict]) -> list[dict]:
    """One row per planned cell of ``table``: its key fields, ``finished`` and ``planned`` seeds."""
    rows: dict[tuple, dict] = {}
    for run in planned_runs(table):
        fields = {k: v for k, v in run.key.items() if k != "seed"}
        row = rows.setdefault(tuple(fields.items()), {**fields, "finished": 0, "planned": 0})
        row["planned"] += 1
        row["finished"] += any(r["name"] == run.name for r in records)
    return list(rows.values())


def apart(a: Sequence[float], b: Sequence[float]) -> int:
    """The README's rule: -1 when every value of ``a`` lies below every value of ``b``, +1 when above, 0 otherwise."""
    if not a or not b:
        raise ValueError(f"both cells need values, got {len(a)} and {len(b)}")
    return -1 if max(a) < min(b) else 1 if min(a) > max(b) else 0


def _compare(test: Test, values: list[list[float]]) -> tuple[str, str]:
    if test.kind in ("falls", "grows"):
        side = apart(values[-1], values[0])  # the last cell against the first
        means = [sum(v) / len(v) for v in values]
        sign = -1 if test.kind == "falls" else 1
        monotone = all(sign * (b - a) > 0 for a, b in zip(means, means[1:]))
        if side == -sign:
            return "fails", "the ends differ the other way: their runs do not overlap"
        if monotone and side == sign:
            return "holds", "the means are monotone and the ends' runs do not overlap"
        return "unresolved at three seeds", "the ends' runs overlap" if monotone else "the means are not monotone"
    side = apart(values[0], values[1])
    wanted = {"lower": -1, "higher": 1, "not_higher": 1, "not_lower": -1}[test.kind]
    if test.kind.startswith("not_"):
        if side == wanted:
            return "fails", "the runs do not overlap, in the direction the claim rules out"
        return "holds", "no difference in the direction the claim rules out"
    if side == wanted:
        return "holds", "the runs do not overlap"
    if side == -wanted:
        return "fails", "the runs do not overlap, the other way"
    return "unresolved at three seeds", "the runs overlap"


def verdict(test: Test, records: Sequence[dict], seeds: int = 3) -> dict:
    """Apply one test to the finished runs.

    Returns:
        {"claim", "metric", "finished", "planned", "verdict", "why"}: ``verdict`` is "holds", "fails",
        "unresolved at three seeds", or "pending" while fewer than ``seeds`` seeds of a cell have finished.
    """
    if seeds < 2:
        raise ValueError(f"the rule needs at least 2 seeds a cell, got {seeds}")
    values = [cell_values(records, cell, test.metric) for cell in test.cells]
    finished, planned = sum(min(len(v), seeds) for v in values), seeds * len(values)
    result = {"claim": test.claim, "metric": test.metric, "finished": finished, "planned": planned}
    if finished < planned:
        return {**result, "verdict": "pending", "why": f"{finished} of {planned} runs finished"}
    word, why = _compare(test, values)
    return {**result, "verdict": word, "why": why}


def claims(verdicts: Sequence[dict]) -> dict[str, str]:
    """claim -> its verdict over its tests: "fails" when one fails, else "pending" when one is pending, "holds" when
    all hold, "unresolved at three seeds" otherwise."""
    out: dict[str, list[str]] = {}
    for v in verdicts:
        out.setdefault(v["claim"], []).append(v["verdict"])
    return {claim: "fails" if "fails" in words else "pending" if "pending" in words
            else "holds" if set(words) == {"holds"} else "unresolved at three seeds" for claim, words in out.items()}


def sources(tests: Sequence[Test]) -> dict[str, str]:
    """claim -> whose claim it is, in :data:`SOURCE_WORDS`' words ("the paper's claim" or "course test"); a claim
    whose tests disagree raises ValueError."""
    out: dict[str, str] = {}
    for t in tests:
        if out.setdefault(t.claim, t.source) != t.source:
            raise ValueError(f"the tests of {t.claim!r} name different sources")
    return {claim: SOURCE_WORDS[source] for claim, source in out.items()}


def word(verdict_: dict) -> str:
    """A verdict in a table's words: "pending (5 of 6 runs)" while runs are missing, the verdict itself otherwise."""
    if verdict_["verdict"] == "pending":
        return f"pending ({verdict_['finished']} of {verdict_['planned']} runs)"
    return verdict_["verdict"]


def judge(tests: Sequence[Test], records: Sequence[dict], seeds: int = 3) -> dict[str, str]:
    """claim -> the verdict over its tests in :func:`word`'s words; a pending claim counts the runs of all the cells
    its tests compare: "pending (8 of 9 runs)"."""
    out = {}
    for claim, verdict_ in claims([verdict(t, records, seeds) for t in tests]).items():
        cells_ = {json.dumps((t.metric, c), sort_keys=True): (t.metric, c) for t in tests if t.claim == claim
                  for c in t.cells}
        seen = {json.dumps(c, sort_keys=True): min(len(cell_values(records, c, m)), seeds) for m, c in cells_.values()}
        finished, planned = sum(seen.values()), seeds * len(seen)
        out[claim] = word({"verdict": verdict_, "finished": finished, "planned": planned})
    return out


def describe(test: Test) -> str:
    """What a test compares, in one line: "cd: P2C-Seg < P2C-Dis", "cd at sigma_n 0.03: sigma_s 0.05 < sigma_s 0",
    "cd falls over M 8 ... 24"."""
    first, last = test.cells[0], test.cells[-1]
    varied = [k for k in first if first[k] != last.get(k)]
    fixed = [k for k in first if k not in varied and k not in ("category", "distance")]
    where = "".join(f" at {k} {first[k]:g}" for k in fixed)
    if test.kind in ("falls", "grows"):
        return f"{test.metric}{where} {test.kind[:-1]}s over {' '.join(varied)} {first[varied[0]]:g} ... {last[varied[0]]:g}"
    sign = {"lower": "<", "higher": ">", "not_higher": "not >", "not_lower": "not <"}[test.kind]
    name = lambda cell: " ".join(str(cell[k]) if isinstance(cell[k], str) else f"{k} {cell[k]:g}" for k in varied)  # noqa: E731
    return f"{test.metric}{where}: {name(first)} {sign} {name(last)}"


#: A metric's name in a sentence.
METRIC_WORDS = {"cd": "Chamfer distance", "miou": "mIoU", "nc_both": "normal consistency", "nc": "normal consistency",
                "n_ac": "number of cuboids"}


def in_words(test: Test, negated: bool = False) -> str:
    """A test's claim as a sentence fragment: "P2C-Seg's Chamfer distance is below P2C-Dis's", "at sigma_n 0.03,
    the Chamfer distance with sigma_s 0.05 is below that with sigma_s 0", "the Chamfer distance falls over M 8 ... 24".

    negated: what a failed test found instead, the other way round: "P2C-Seg's Chamfer distance lies above
    P2C-Dis's", "the Chamfer distance grows over M 8 ... 24" (for a trend: the last cell against the first)."""
    first, last = test.cells[0], test.cells[-1]
    varied = [k for k in first if first[k] != last.get(k)]
    fixed = [k for k in first if k not in varied and k not in ("category", "distance")]
    where = "".join(f"at {k} {first[k]:g}, " for k in fixed)
    metric = METRIC_WORDS.get(test.metric, test.metric)
    if test.kind in ("falls", "grows"):
        kind = {"falls": "grows", "grows": "falls"}[test.kind] if negated else test.kind
        return f"{where}the {metric} {kind} over {' '.join(varied)} {first[varied[0]]:g} ... {last[varied[0]]:g}"
    relation = {"lower": "below", "higher": "above", "not_higher": "not above", "not_lower": "not below"}[test.kind]
    if negated:
        relation = {"lower": "above", "higher": "below", "not_higher": "above", "not_lower": "below"}[test.kind]
    if all(isinstance(first[k], str) for k in varied):
        name = lambda cell: " ".join(cell[k] for k in varied)  # noqa: E731
        return f"{where}{name(first)}'s {metric} {'lies' if negated else 'is'} {relation} {name(last)}'s"
    name = lambda cell: " ".join(f"{k} {cell[k]:g}" for k in varied)  # noqa: E731
    return f"{where}the {metric} with {name(first)} {'lies' if negated else 'is'} {relation} that with {name(last)}"


def training_minutes(records: Sequence[dict]) -> list[float]:
    """The training time of each finished run, both stages, in minutes (its record's ``training`` summary)."""
    return [(r["training"]["seconds"] + r["training"].get("finetune_seconds", 0.0)) / 60 for r in records]


def main() -> int:
    """Print, for each table, the finished seeds of every cell and the verdict of every test; then the training
    time of the finished runs."""
    every = []
    for table in ABLATIONS:
        records = read_records(table)
        every += records
        print(f"{table}: {len(records)} of {len(planned_runs(table))} runs finished")
        for row in cells(table, records):
            print("  " + ", ".join(f"{k} {v}" for k, v in row.items() if k not in ("finished", "planned"))
                  + f": {row['finished']} of {row['planned']} seeds")
        for test in TESTS[table]:
            v = verdict(test, records)
            print(f"  {describe(test)}: {word(v)}" + ("" if v["verdict"] == "pending" else f" ({v['why']})"))
    if every:
        minutes = sorted(training_minutes(every))
        q1, median, q3 = statistics.quantiles(minutes, n=4) if len(minutes) > 1 else minutes * 3
        print(f"training time of the {len(minutes)} finished runs: {minutes[0]:.0f} to {minutes[-1]:.0f} min, "
              f"median {median:.0f} min, quartiles {q1:.0f} and {q3:.0f} min")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
