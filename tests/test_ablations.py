"""Tests of the 15-minute ablations' verdicts (experiments/ablations.py) and lessons 08-09's tables
(experiments/lesson_tables.py): the rule that decides a difference, the tests stated before the runs, and how
finished and pending runs are read and shown."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "experiments"
sys.path.insert(0, str(EXPERIMENTS))

import ablations  # noqa: E402
import lesson_tables  # noqa: E402
import table5_compactness as table5  # noqa: E402
import table6_num_cuboids as table6  # noqa: E402


# ----------------------------------------------------------------------------------------------
# The 15-minute ablations: reading the finished runs and the tests stated before them
# ----------------------------------------------------------------------------------------------


def _record(name: str, key: dict, **metrics) -> dict:
    return {"name": name, "key": key, "status": "ok", "results": [{"method": "network", "metrics": metrics}]}


def _write_records(root: Path, table: str, stamp: str, records: list[dict]) -> None:
    folder = root / f"{ablations.ABLATIONS[table][0].EXPERIMENT.name}_15min" / stamp
    for record in records:
        (folder / record["name"]).mkdir(parents=True)
        (folder / record["name"] / "record.json").write_text(json.dumps(record))


def _table3_records(cd: dict, miou: dict) -> list[dict]:
    """Chair records of Table 3: cd / miou give each variant's three seeds."""
    return [_record(f"chair_{v}_seed{s}", {"category": "chair", "variant": v, "seed": s}, cd=cd[v][s], miou=miou[v][s])
            for v in cd for s in range(3)]


def test_the_ablation_options_are_those_of_the_shell_script():
    script = (EXPERIMENTS / "ablations_15min.sh").read_text()
    for table, (module, options) in ablations.ABLATIONS.items():
        line = next(l for l in script.splitlines() if l.strip().startswith(f"{table})"))
        assert f"python {module.EXPERIMENT.name}.py {' '.join(options)} " in line, table
    common = next(l for l in script.splitlines() if l.startswith("common=("))
    assert " ".join(ablations.COMMON) in common
    counts = {t: len(ablations.planned_runs(t)) for t in ablations.ABLATIONS}
    assert counts == {"table3": 9, "table4": 12, "table6": 15}, "the README's 9, 12 and 15 runs"


def test_the_rule_needs_every_seed_of_one_cell_below_every_seed_of_the_other():
    assert ablations.apart([1, 2, 3], [4, 5, 6]) == -1
    assert ablations.apart([4, 5, 6], [1, 2, 3]) == 1
    assert ablations.apart([1, 2, 5], [4, 5, 6]) == 0, "one seed in the other's range"
    assert ablations.apart([1, 2, 4], [4, 5, 6]) == 0, "a tie is an overlap"
    with pytest.raises(ValueError, match="both cells need values"):
        ablations.apart([], [1.0])


def test_table3_verdicts_from_partial_and_complete_records(tmp_path):
    low, high, mid = [1.0, 1.1, 1.2], [2.0, 2.1, 2.2], [1.15, 2.5, 3.0]
    complete = _table3_records({"P2C-Seg": low, "P2C-Dis": high, "Chamfer-Dis": mid},
                               {"P2C-Seg": high, "P2C-Dis": low, "Chamfer-Dis": [2.5, 2.6, 2.7]})
    _write_records(tmp_path, "table3", "20260101-000000-000000", complete[3:])  # P2C-Seg's seeds not finished yet
    partial = ablations.read_records("table3", tmp_path)
    assert [c["finished"] for c in ablations.cells("table3", partial)] == [3, 3, 0]
    verdicts = [ablations.verdict(t, partial) for t in ablations.TESTS["table3"]]
    assert {(v["verdict"], v["why"]) for v in verdicts} == {("pending", "3 of 6 runs finished")}
    assert {ablations.word(v) for v in verdicts} == {"pending (3 of 6 runs)"}, "not a result: no runs of P2C-Seg yet"
    assert set(ablations.judge(ablations.TESTS["table3"], partial).values()) == {"pending (6 of 9 runs)"}

    _write_records(tmp_path, "table3", "20260102-000000-000000", complete[:3])
    records = ablations.read_records("table3", tmp_path)
    assert len(records) == 9 and [r["name"] for r in records] == [r.name for r in ablations.planned_runs("table3")]
    got = {(t.metric, t.cells[1]["variant"]): ablations.verdict(t, records)["verdict"] for t in ablations.TESTS["table3"]}
    assert got == {("cd", "P2C-Dis"): "holds", ("cd", "Chamfer-Dis"): "unresolved at three seeds",
                   ("miou", "P2C-Dis"): "holds", ("miou", "Chamfer-Dis"): "fails"}
    claims = ablations.claims([ablations.verdict(t, records) for t in ablations.TESTS["table3"]])
    assert claims == {"P2C-Seg gives the lowest Chamfer distance": "unresolved at three seeds",
                      "P2C-Seg gives the highest mIoU": "fails"}
    assert ablations.judge(ablations.TESTS["table3"], records) == claims


def test_a_claim_fails_on_one_failed_test_even_while_others_are_pending():
    tests = [ablations.Test("c", "cd", ({"v": "a"}, {"v": "b"}), "lower"),
             ablations.Test("c", "cd", ({"v": "a"}, {"v": "d"}), "lower")]
    rows = [_record(f"{v}{s}", {"v": v, "seed": s}, cd=x + s / 10) for v, x in (("a", 2.0), ("b", 1.0)) for s in range(3)]
    assert [ablations.verdict(t, rows)["verdict"] for t in tests] == ["fails", "pending"]
    assert ablations.claims([ablations.verdict(t, rows) for t in tests]) == {"c": "fails"}
    assert ablations.judge(tests[1:], rows) == {"c": "pending (3 of 6 runs)"}


def test_a_newer_record_of_the_same_run_wins_and_foreign_records_are_left_out(tmp_path):
    old = _record("chair_M8_seed0", {"category": "chair", "M": 8, "seed": 0}, cd=2.0, n_ac=5.0)
    new = _record("chair_M8_seed0", {"category": "chair", "M": 8, "seed": 0}, cd=1.0, n_ac=5.0, flatness=0.2)
    foreign = _record("table_M8_seed0", {"category": "table", "M": 8, "seed": 0}, cd=9.0, n_ac=5.0)
    failed = {**_record("chair_M12_seed0", {"category": "chair", "M": 12, "seed": 0}, cd=1.0), "status": "failed"}
    _write_records(tmp_path, "table6", "20260101-000000-000000", [old, foreign, failed])
    _write_records(tmp_path, "table6", "20260102-000000-000000", [new])
    records = ablations.read_records("table6", tmp_path)
    assert [r["name"] for r in records] == ["chair_M8_seed0"]
    assert ablations.cell_values(records, {"M": 8}, "cd") == [1.0]
    assert ablations.cell_values(records, {"M": 8}, "thickness") == [0.2], "the old metric name is read as today's"


def _table6_records(cd_by_m: dict) -> list[dict]:
    return [_record(f"chair_M{m}_seed{s}", {"category": "chair", "M": m, "seed": s}, cd=xs[s], n_ac=float(m))
            for m, xs in cd_by_m.items() for s in range(3)]


@pytest.mark.parametrize("means, spread, cd_verdict", [
    ((5, 4, 3, 2, 1), 0.1, "holds"),  # falling means, ends apart
    ((5, 4, 4.5, 2, 1), 0.1, "unresolved at three seeds"),  # ends apart, means not monotone
    ((1.2, 1.15, 1.1, 1.05, 1.0), 0.5, "unresolved at three seeds"),  # monotone, the ends overlap
    ((1, 2, 3, 4, 5), 0.1, "fails"),  # the ends apart the other way
])
def test_table6_trend_needs_monotone_means_and_ends_apart(tmp_path, means, spread, cd_verdict):
    _write_records(tmp_path, "table6", "20260101-000000-000000",
                   _table6_records({m: [x - spread, x, x + spread] for m, x in zip(table6.NUM_CUBOIDS, means)}))
    records = ablations.read_records("table6", tmp_path)
    verdicts = {t.metric: ablations.verdict(t, records)["verdict"] for t in ablations.TESTS["table6"]}
    assert verdicts == {"cd": cd_verdict, "n_ac": "holds"}, "n_ac = M on every seed: monotone, the ends apart"


def test_table4_no_cost_fails_only_when_sigma_s_is_worse_beyond_the_seeds(tmp_path):
    def records(cd_005, cd_0):
        return [_record(f"noise{n:g}_Normal_s{s:g}_seed{seed}",
                        {"sigma_n": n, "distance": "Normal", "sigma_s": s, "seed": seed}, cd=xs[seed], nc_both=0.5)
                for n in (0.0, 0.03) for s, xs in ((0.0, cd_0), (0.05, cd_005)) for seed in range(3)]

    clean = next(t for t in ablations.TESTS["table4"] if t.kind == "not_higher")
    assert clean.cells[0]["sigma_n"] == 0.0 and clean.cells[0]["sigma_s"] == 0.05
    for cd_005, cd_0, expected in (([1, 2, 3], [2, 3, 4], "holds"), ([0, 0.1, 0.2], [1, 2, 3], "holds"),
                                   ([4, 5, 6], [1, 2, 3], "fails")):
        assert ablations.verdict(clean, records(cd_005, cd_0))["verdict"] == expected


def test_the_same_tests_apply_to_other_categories_and_to_table5():
    assert [t.cells[0]["category"] for t in ablations.table3_tests("table")] == ["table"] * 4
    assert [c["M"] for c in ablations.table6_tests("airplane")[0].cells] == list(table6.NUM_CUBOIDS)
    assert [c["lambda_1"] for c in ablations.TESTS["table5"][0].cells] == list(table5.LAMBDAS)
    runs = [_record(f"l{w}_s{s}", {"lambda_1": w, "form": "averaged", "seed": s}, n_ac=10 - 20 * w + s / 10,
                    cd=1 + w + s / 100, miou=0.8) for w in table5.LAMBDAS for s in range(3)]
    words = [ablations.verdict(t, runs)["verdict"] for t in ablations.TESTS["table5"]]
    assert words == ["holds", "holds", "unresolved at three seeds"], "mIoU tied: the runs overlap"


def test_a_test_describes_itself_in_one_line():
    lines = [ablations.describe(t) for t in (ablations.table3_tests()[0], ablations.table4_tests()[0],
                                               ablations.table6_tests()[1])]
    assert lines == ["cd: P2C-Seg < P2C-Dis", "cd at sigma_n 0.03: sigma_s 0.05 < sigma_s 0", "n_ac grows over M 8 ... 24"]


def test_ablation_reader_rejects_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="table must be one of"):
        ablations.read_records("table5", tmp_path)
    with pytest.raises(FileNotFoundError, match="no folder of 15-minute runs"):
        ablations.read_records("table3", tmp_path / "missing")
    with pytest.raises(ValueError, match="kind must be one of"):
        ablations.Test("claim", "cd", ({}, {}), "smaller")
    with pytest.raises(ValueError, match="compares two cells"):
        ablations.Test("claim", "cd", ({}, {}, {}), "lower")
    with pytest.raises(ValueError, match="at least 2 seeds"):
        ablations.verdict(ablations.TESTS["table3"][0], [], seeds=1)
    assert ablations.read_records("table3", tmp_path) == [], "no run finished yet"


def test_every_committed_15_minute_record_is_read():
    committed = {p.parent.name for p in ablations.RUNS_15MIN.glob("*/*/*/record.json")}
    read = {r["name"] for t in ablations.ABLATIONS for r in ablations.read_records(t)}
    assert read == committed


# ----------------------------------------------------------------------------------------------
# Lessons 08-09's display helpers
# ----------------------------------------------------------------------------------------------


def test_lesson_tables_format_a_table_as_aligned_text_and_escaped_html():
    text = lesson_tables.table_text(["name", "x"], [["a", 1.5], ["long name", 10]])
    assert text.splitlines() == ["name         x", "a          1.5", "long name   10"]
    page = lesson_tables.table_html(["a<b", "x"], [["1", "2"]])
    assert page == "<table><tr><th>a&lt;b</th><th>x</th></tr><tr><td>1</td><td>2</td></tr></table>"


def test_lesson_tables_read_one_cell_and_its_seeds_range():
    result = {"summary": [{"M": 8, "cd_mean": 0.5}, {"M": 12, "cd_mean": 0.25}],
              "runs": [_record(f"m{s}", {"M": 8, "seed": s}, cd=0.4 + s / 10) for s in range(3)]}
    assert lesson_tables.value(result, "cd", M=12) == 0.25
    with pytest.raises(ValueError, match="matches 0"):
        lesson_tables.value(result, "cd", M=16)
    assert lesson_tables.seeds(result, "cd", M=8) == pytest.approx([0.4, 0.5, 0.6])
    assert lesson_tables.span([0.4, 0.6, 0.5], 1000, 1) == "400.0 to 600.0" and lesson_tables.span([]) == "-"
    assert lesson_tables.span([0.00104], 1000) == "1.04 (1 seed)"


def test_lesson_tables_write_the_verdicts_in_words():
    holds, fails = {"verdict": "holds"}, {"verdict": "fails"}
    open_ = {"verdict": "unresolved at three seeds"}
    assert lesson_tables.verdict_sentence([("A", holds), ("B", fails), ("C", open_), ("D", open_)]) == (
        "By the rule, this holds: A. This test fails, the runs lying apart the other way: B. "
        "Of the other tests, 2 are unresolved at three seeds.")
    assert lesson_tables.verdict_sentence([("A", holds), ("B", holds)]) == "By the rule, these hold: A; B."
    assert lesson_tables.verdict_sentence([("A", open_)]).startswith("No test holds by the rule.")
    grouped = [("a is below b", "chairs", holds), ("a is below c", "airplanes", fails), ("a is below c", "tables", fails)]
    assert lesson_tables.verdict_sentence(grouped) == (
        "By the rule, this holds: on chairs, a is below b. These tests fail, the runs lying apart the other way: "
        "on airplanes and tables, a is below c.")


def test_a_failed_test_is_stated_as_what_was_found():
    holds, fails = {"verdict": "holds"}, {"verdict": "fails"}
    seg_vs_dis, seg_vs_chamfer = ablations.table3_tests("chair")[:2]
    sentence = lesson_tables.verdict_sentence([(seg_vs_dis, "chairs", holds), (seg_vs_chamfer, "airplanes", fails),
                                               (seg_vs_chamfer, "tables", fails)])
    assert sentence == ("By the rule, this holds: on chairs, P2C-Seg's Chamfer distance is below P2C-Dis's. "
                        "These tests fail, the runs lying apart the other way: on airplanes and tables, "
                        "P2C-Seg's Chamfer distance lies above Chamfer-Dis's.")
    negated = [ablations.in_words(t, negated=True) for t in (ablations.table4_tests()[1], ablations.table4_tests()[2],
                                                            ablations.table6_tests()[0])]
    assert negated == ["at sigma_n 0.03, the normal consistency with sigma_s 0.05 lies below that with sigma_s 0",
                       "at sigma_n 0, the Chamfer distance with sigma_s 0.05 lies above that with sigma_s 0",
                       "the Chamfer distance grows over M 8 ... 24"]


def test_each_claim_says_whether_the_paper_or_the_course_makes_it():
    found = {claim: source for tests in ablations.TESTS.values() for claim, source in ablations.sources(tests).items()}
    assert found["P2C-Seg gives the lowest Chamfer distance"] == "the paper's claim"
    assert found["P2C-Seg gives the highest mIoU"] == "course test"
    assert found["sigma_s > 0 costs nothing on clean input"] == "course test"
    assert found["sigma_s > 0 is robust to noise"] == "the paper's claim"
    with pytest.raises(ValueError, match="source"):
        ablations.Test("claim", "cd", ({}, {}), "lower", "reviewer")
    mixed = [ablations.Test("c", "cd", ({"a": 1}, {"a": 2}), "lower"),
             ablations.Test("c", "miou", ({"a": 1}, {"a": 2}), "higher", "course")]
    with pytest.raises(ValueError, match="different sources"):
        ablations.sources(mixed)


def test_a_test_states_its_claim_in_words():
    words = [ablations.in_words(t) for t in (ablations.table3_tests()[1], ablations.table4_tests()[0],
                                             ablations.table5_tests()[2], ablations.table6_tests()[0])]
    assert words == ["P2C-Seg's Chamfer distance is below Chamfer-Dis's",
                     "at sigma_n 0.03, the Chamfer distance with sigma_s 0.05 is below that with sigma_s 0",
                     "the mIoU with lambda_1 0.2 is below that with lambda_1 0.05",
                     "the Chamfer distance falls over M 8 ... 24"]


def test_lesson_tables_give_a_pending_verdict_line_and_table_until_the_runs_finish(tmp_path):
    low, high, mid = [1.0, 1.1, 1.2], [2.0, 2.1, 2.2], [1.15, 2.5, 3.0]
    complete = _table3_records({"P2C-Seg": low, "P2C-Dis": high, "Chamfer-Dis": mid},
                               {"P2C-Seg": high, "P2C-Dis": low, "Chamfer-Dis": [2.5, 2.6, 2.7]})
    tests = ablations.TESTS["table3"]
    assert lesson_tables.verdict_line(tests, []) == (
        "**Verdict at the 15-minute scale:** P2C-Seg gives the lowest Chamfer distance: *pending (0 of 9 runs)*; "
        "P2C-Seg gives the highest mIoU: *pending (0 of 9 runs)*.")
    header, rows, line = lesson_tables.fifteen_rows("table3", complete[3:], [("cd", 1, 2, "CD")], complete)
    assert header == ["variant", "seeds finished", "CD, 15 min", "CD, 600 steps (median)"]
    assert [row[:2] for row in rows] == [["P2C-Dis", "3 of 3"], ["Chamfer-Dis", "3 of 3"], ["P2C-Seg", "0 of 3"]]
    assert rows[2][2] == "-" and rows[2][3] == "1.10", "a cell with no finished seed: no range, its 600-step median"
    assert rows[1][3] == "2.50", "the 600-step median of 1.15, 2.5, 3.0, not their mean"
    assert line == "finished: 6 of 9 runs; pending: P2C-Seg (3 seeds missing)"
    *_, line = lesson_tables.fifteen_rows("table3", complete[1:], [("cd", 1, 2, "CD")], complete)
    assert line == "finished: 8 of 9 runs; pending: P2C-Seg (1 seed missing)"
    assert "*unresolved at three seeds*" in lesson_tables.verdict_line(tests, complete)


def _fifteen(records: list[dict]) -> list[dict]:
    """Records as the 15-minute recipe writes them: its number of shapes in the configuration."""
    return [{**r, "config": {"n_shapes": ablations.runner.FIFTEEN_MINUTE_SHAPES}} for r in records]


def test_check_fifteen_accepts_any_stage_of_the_runs_and_names_a_miscount():
    low, high, mid = [1.0, 1.1, 1.2], [2.0, 2.1, 2.2], [1.15, 2.5, 3.0]
    complete = _fifteen(_table3_records({"P2C-Seg": low, "P2C-Dis": high, "Chamfer-Dis": mid},
                                        {"P2C-Seg": high, "P2C-Dis": low, "Chamfer-Dis": [2.5, 2.6, 2.7]}))
    tests = ablations.TESTS["table3"]
    for records in ([], complete[:4], complete):  # none, some and all of the runs finished
        found = [ablations.verdict(t, records) for t in tests]
        lesson_tables.check_fifteen("table3", tests, found, records)
    found = [ablations.verdict(t, complete) for t in tests]
    with pytest.raises(AssertionError, match="counts 6 runs, 5 were read"):
        lesson_tables.check_fifteen("table3", tests, found, complete[1:])
    with pytest.raises(AssertionError, match="one record per finished run"):
        lesson_tables.check_fifteen("table3", tests, found, [*complete, complete[0]])
    with pytest.raises(AssertionError, match="15-minute runs only"):
        lesson_tables.check_fifteen("table3", tests, found, [{**complete[0], "config": {"n_shapes": 256}}, *complete[1:]])
    stranger = {**complete[0], "name": "chair_P2C-Seg_seed7"}
    with pytest.raises(AssertionError, match="does not plan"):
        lesson_tables.check_fifteen("table3", tests, found, [stranger, *complete[1:]])


def test_lesson_tables_list_the_fields_where_two_configurations_differ():
    a = {"steps": 600, "loss": {"lambda": 0.1, "form": "averaged"}, "seed": 0}
    b = {"steps": 2500, "loss": {"lambda": 0.1, "form": "sum"}, "seed": 0, "finetune": 500}
    assert lesson_tables.config_differences(a, b) == [("steps", 600, 2500), ("loss.form", "averaged", "sum"),
                                                     ("finetune", None, 500)]


# ----------------------------------------------------------------------------------------------
# Lessons 08-09's summaries and the verdicts luck alone would give
# ----------------------------------------------------------------------------------------------


def test_summary_rows_split_by_source_in_the_papers_order():
    empty = {table: [] for table in ablations.TESTS}
    paper, course = ablations.SOURCE_WORDS["paper"], ablations.SOURCE_WORDS["course"]
    extra = [["the authors' code", "printed losses", course, "holds", "not rerun"],
             ["Table 4", "degenerates", paper, "holds", "not rerun"]]
    out = lesson_tables.summary_rows(empty, empty, extra)
    assert set(out) == {"paper", "course"}
    claims = {s: [row[1] for row in rows] for s, rows in out.items()}
    for table, tests in ablations.TESTS.items():
        for claim, source in ablations.sources(tests).items():
            other = "course" if ablations.SOURCE_WORDS["paper"] == source else "paper"
            assert claim in claims[{v: k for k, v in ablations.SOURCE_WORDS.items()}[source]] and claim not in claims[other]
    for rows in out.values():
        ranks = [lesson_tables.EXPERIMENTS.index(row[0]) for row in rows]
        assert ranks == sorted(ranks)
        assert all(len(row) == 4 for row in rows)
    table4 = [row[1] for row in out["paper"] if row[0] == "Table 4"]
    assert table4[0] == "degenerates" and len(table4) > 1  # an extra row comes first in its experiment
    assert out["course"][-1][1] == "printed losses"
    assert all(row[2].startswith("pending") for row in out["paper"] if row[1] != "degenerates")


def test_luck_rows_count_every_test_and_match_the_counted_chance():
    tests = [t for ts in ablations.TESTS.values() for t in ts]
    rows = lesson_tables.luck_rows(tests, draws=4000)
    assert sum(row[2] for row in rows) == len(tests)
    for kind, n, count, monotone, chance, expected in rows:
        assert expected == pytest.approx(count * chance)
        if kind == "difference":
            assert chance == pytest.approx(2 / 20)
        elif kind == "no difference":
            assert chance == pytest.approx(1 / 20)
        else:  # a false "fails" alone has a chance of 1/20; a false "holds" (monotone means too) adds a little
            assert monotone == pytest.approx(2 / __import__("math").factorial(n))
            assert 0.04 < chance < 0.05 + monotone * 0.1 + 0.015
    assert lesson_tables.luck_rows(tests, draws=500) == lesson_tables.luck_rows(tests, draws=500)  # seeded


def test_summary_rows_cover_only_the_tables_a_lesson_passes():
    out = lesson_tables.summary_rows({"table3": []}, {"table3": []})
    experiments = {row[0] for rows in out.values() for row in rows}
    assert experiments == {"Table 3"}
    assert [row[1] for row in out["paper"]] == list(ablations.sources(ablations.TESTS["table3"]))[:1]
    with pytest.raises(ValueError, match="same tables"):
        lesson_tables.summary_rows({"table3": []}, {"table4": []})
    with pytest.raises(ValueError, match="same tables"):
        lesson_tables.summary_rows({"table9": []}, {"table9": []})


def test_loss_rows_list_every_stage_of_records_and_release_cards():
    def config(compact, average=True, exist=0.01, kl=6e-6):
        return {"loss": {"lambda_compact": compact, "compactness_average": average, "lambda_exist": exist,
                         "lambda_kl": kl}}

    record = {"config": config(0.05), "finetune_config": config(0.2, average=False)}  # two stages
    card = {"config": config(0.001, exist=0.02), "initialised_from": {"config": config(0.001)}}
    one_stage = {"config": config(0.1), "finetune_config": None}
    rows = lesson_tables.loss_rows([("runs", [record, one_stage]), ("card", [card])])
    assert rows == [["runs", "0.05, 0.1, 0.2", "Eq. (6) / M^2, Eq. (6) as printed", "0.01", "6e-06"],
                    ["card", "0.001", "Eq. (6) / M^2", "0.01, 0.02", "6e-06"]]
