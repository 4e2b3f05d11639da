#!/usr/bin/env bash
# The 15-minute recipe's second round, one command at a time on a quiet machine (after run_all.sh's first round):
# the table and the chair (seed 1, as the committed chair) at the recipe's 15 minutes, the airplane at 23.
set -euo pipefail
python benchmarks/bench_time_to_quality.py --category table --out runs/ttq_table --json runs/ttq_table.json
python benchmarks/bench_time_to_quality.py --category chair --set seed=1 --out runs/ttq_chair_seed1 --json runs/ttq_chair_seed1.json
python benchmarks/bench_time_to_quality.py --category airplane --budget 23 --out runs/ttq_airplane_23 --json runs/ttq_airplane_23.json
