"""The benchmark scripts run and print what their docstrings promise (tiny sizes; no timing is asserted)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

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
