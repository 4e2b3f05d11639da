"""experiments/generator_v2.py: the gate a network trained on generator version 2 passes to replace the committed one."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def gate():
    spec = importlib.util.spec_from_file_location("generator_v2", ROOT / "experiments" / "generator_v2.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _scores(v1, v2, real, chamfers):
    return {"v1": {"miou": v1}, "v2": {"miou": v2}, "real": {"miou": real, "chamfer": chamfers}}


def test_a_candidate_replaces_only_when_all_three_tests_hold(gate):
    committed = _scores(80.0, 70.0, 60.0, {"a": 1.0, "b": 2.0, "c": 4.0})
    good = _scores(80.0 - gate.MAX_V1_DROP, 75.0, 65.0, {"a": 0.5, "b": 2.0, "c": 2.0})
    out = gate.verdict(committed, good)
    assert out["replaces"] and out["v1_drop"] == gate.MAX_V1_DROP and out["real_chamfer_median_ratio"] == 0.5
    assert not gate.verdict(committed, _scores(77.9, 75.0, 65.0, good["real"]["chamfer"]))["replaces"]  # v1 fell
    assert not gate.verdict(committed, _scores(80.0, 70.0, 65.0, good["real"]["chamfer"]))["replaces"]  # v2 tie
    assert not gate.verdict(committed, _scores(80.0, 75.0, 59.0, good["real"]["chamfer"]))["replaces"]  # real fell


def test_a_version_3_candidate_is_judged_on_the_version_3_split(gate):
    committed = {"v1": {"miou": 80.0}, "v3": {"miou": 70.0}, "real": {"miou": 60.0, "chamfer": {"a": 1.0}}}
    better = {"v1": {"miou": 79.0}, "v3": {"miou": 71.0}, "real": {"miou": 61.0, "chamfer": {"a": 1.0}}}
    out = gate.verdict(committed, better, 3)
    assert out["replaces"] and out["v3_better"] and "v2_better" not in out
    worse = {**better, "v3": {"miou": 69.0}}
    assert not gate.verdict(committed, worse, 3)["replaces"]


@pytest.mark.parametrize("bad", ["animal", "boat=runs/x", "animal=/no/such/run"])
def test_a_candidate_must_name_a_category_and_an_existing_run(gate, bad, capsys):
    with pytest.raises(SystemExit) as stop:
        gate.main(["--candidate", bad])
    assert stop.value.code == 2 and "--candidate takes CATEGORY=RUN" in capsys.readouterr().err


def test_the_readme_table_is_the_committed_gate_runs(gate, capsys):
    results = ROOT / "experiments" / "results"
    files = ["generator_v2_animal.json", "generator_v2_animal_seed2.json", "generator_v3_animal.json",
             "generator_v2_airplane.json"]
    assert gate.main(["--table", *(str(results / f) for f in files)]) == 0
    table = capsys.readouterr().out.strip()
    readme = (ROOT / "experiments" / "README.md").read_text()
    block = readme.split("<!-- generator-v2-networks:start -->")[1].split("<!-- generator-v2-networks:end -->")[0]
    assert block.strip() == table
    rows = [line for line in table.splitlines() if "| candidate" in line]
    verdicts = {r.split("|")[2].strip(): r.rstrip(" |").rsplit("|", 1)[1].strip() for r in rows}
    assert verdicts == {"candidate (generator_v2/animal_seed1)": "no", "candidate (generator_v2/animal_seed2)": "no",
                        "candidate (generator_v3/animal)": "no", "candidate (generator_v2/airplane)": "yes"}, \
        "the verdicts the README states: every animal fails, the airplane passes"
