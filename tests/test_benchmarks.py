"""The benchmark scripts run and print what their docstrings promise (tiny sizes; no timing is asserted)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_bench_model_prints_the_step_and_its_lower_bound():
    args = ["--config", "small", "--batch", "2", "--points", "128", "--cuboids", "4",
            "--repeats", "1", "--warmup", "0", "--threads", "1", "--floor"]
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_model.py"), *args],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    step = re.search(r"^\s*128\s+fast\s+([\d.]+)", proc.stdout, re.M)
    parts = dict((name, float(s)) for s, name in re.findall(r"^\s*128\s+floor\s+([\d.]+)\s+(.+?)\s*$", proc.stdout, re.M))
    assert step, proc.stdout
    assert list(parts)[:3] == ["kNN graphs", "EdgeConv products", "global feature products"], proc.stdout
    total = parts.pop("sum: a lower bound for the step")
    assert abs(total - sum(parts.values())) <= 0.002  # printed with three decimals


def test_bench_abstract_prints_the_three_orientation_choices_and_the_threads():
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_abstract.py"), "--repeats", "1",
                           "--fit-steps", "3"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    ratios = [float(r) for r in re.findall(r"\(([\d.]+)x up='y'\)", proc.stdout)]
    assert len(ratios) == 3 and ratios[0] == 1.0, proc.stdout
    rows = re.findall(r"1 thread\s+([\d.]+) s, 2 threads\s+([\d.]+) s, default\s+([\d.]+) s", proc.stdout)
    assert len(rows) == 2, proc.stdout


def test_bench_real_shapes_prints_every_method_of_a_shape():
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_real_shapes.py"), "--only", "mug_0",
                           "--refine", "5", "--seeds", "1"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    row = re.search(r"^mug_0\s+table\s+\|((\s+[\d.]+){4})\s+\|((\s+[\d.]+){4})\s+\|((\s+[\d.]+){2})\s+\|\s+[\d.]+$",
                    proc.stdout, re.M)
    assert row, proc.stdout
    assert "thin-structure set: 1 shapes" in proc.stdout, proc.stdout


def test_bench_time_to_quality_reports_both_stages_against_wall_time_and_the_targets(tmp_path):
    recipe = ROOT / "data_samples" / "checkpoints" / "configs" / "15min"
    run = tmp_path / "run"
    train = [sys.executable, "-m", "cuboidlib", "train", "--config", str(recipe / "table.json"),
             "--finetune", str(recipe / "finetune" / "table.json"), "--out", str(run), "--release",
             str(run / "released.pt"), "--shapes", "30", "--points", "128", "--quiet", "--threads", "1",
             "--set", "max_steps=100", "--set", "max_minutes=null"]
    proc = subprocess.run(train, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_time_to_quality.py"), "--category",
                           "table", "--report-only", "--out", str(run), "--json", str(tmp_path / "r.json")],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    rows = re.findall(r"^\s+([\d.]+)\s+(first|second)\s+(\d+)\s", proc.stdout, re.M)
    assert [s for _, s, _ in rows].count("first") == 1 and [s for _, s, _ in rows].count("second") == 5, proc.stdout
    minutes = [float(m) for m, _, _ in rows]
    assert minutes == sorted(minutes), proc.stdout  # the second stage follows the first on the wall clock
    for name in ("test mIoU %", "N_AC", "smallest part IoU %", "k-means CD / network CD", "box distance"):
        assert re.search(rf"^\s+{re.escape(name)}\s+[\d.]+\s+target .*(met|MISSED)$", proc.stdout, re.M), proc.stdout
    assert "cuboids per instance / instances per cuboid: top" in proc.stdout


def test_bench_training_prints_each_layout_with_the_variables_it_was_given():
    script = str(ROOT / "benchmarks" / "bench_training.py")
    proc = subprocess.run([sys.executable, script, "--layouts", "1x1", "--repeats", "1", "--warmup", "1",
                           "--env", "OMP_WAIT_POLICY=PASSIVE"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "; OMP_WAIT_POLICY=PASSIVE" in proc.stdout.splitlines()[0], proc.stdout
    assert re.search(r"^\s+1x1\s+none\s+[\d.]+\s+[\d.]+\s+1\.00x$", proc.stdout, re.M), proc.stdout
    bad = subprocess.run([sys.executable, script, "--env", "OMP_WAIT_POLICY"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "expected NAME=VALUE" in bad.stderr


def test_bench_rotation_scores_each_option_on_turned_shapes_and_writes_its_json(tmp_path):
    out = tmp_path / "rotation.json"
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_rotation.py"), "--per-category", "2",
                           "--categories", "chair", "--random", "1", "--repeats", "0", "--options", "none,auto",
                           "--json", str(out)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert re.search(r"^\s+yaw 45\s+none \d+% [\d.]+x mIoU [-+][\d.]+ \| auto \d+% [\d.]+x", proc.stdout, re.M), proc.stdout
    import json

    doc = json.loads(out.read_text())
    summary = doc["summary"]["procedural"]["chair"]
    assert set(summary) >= {"upright_miou", "yaw 0", "yaw 180", "random"}
    assert summary["random"]["auto"]["up_within_10"] == 1.0, "two test chairs turned at random, found"
    assert {r["option"] for r in doc["records"]} == {"upright", "none", "auto"}



@pytest.mark.parametrize("name", ["rotation.json", "rotation_all_options.json"])
def test_the_readme_rotation_tables_are_the_committed_runs(name):
    """benchmarks/README.md shows ``bench_rotation.py --table`` of each committed run, cell for cell."""
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_rotation.py"), "--table",
                           str(ROOT / "benchmarks" / "results" / name)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() in (ROOT / "benchmarks" / "README.md").read_text()

def test_bench_warning_prints_each_group_against_its_target_and_writes_its_json(tmp_path):
    out = tmp_path / "warning.json"
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_warning.py"), "--shapes", "2",
                           "--routes", "1", "--verify", "1", "--json", str(out)], capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr
    for kind, what in (("own test", "silent"), ("off test", "speaks"), ("thin", "speaks")):
        assert re.search(rf"^{kind}\s+(\s*\d+/\d+\s+spk){{4}}\s+\d+/\d+\s+[\d.]+% {what} \((met|MISSED)", proc.stdout,
                         re.M), proc.stdout
    assert "0 verdicts differ" in proc.stdout, "the batched verdicts are abstract's"
    doc = json.loads(out.read_text())
    assert doc["table"]["own test"]["chair"]["shapes"] == 2 and doc["table"]["off test"]["chair"]["shapes"] == 6
    assert set(doc["thresholds"]) == {"chair", "table", "airplane", "animal"} and doc["verify_differ"] == 0
