#!/usr/bin/env bash
# The 15-minute ablations (experiments/README.md, "The 15-minute ablations"): Tables 3, 4 and 6 on chairs at the
# 15-minute recipe's scale, three seeds a cell, one run at a time on one core, resumable. Usage:
#   bash experiments/ablations_15min.sh table3|table4|table6 [more options for the script, e.g. --plan]
set -euo pipefail
cd "$(dirname "$0")"
runs=results/runs_15min
common=(--recipe 15min --seeds 3 --jobs 1 --resume --runs-dir "$runs")
case "${1:-}" in
  table3) shift; exec python table3_supervision.py --categories chair "${common[@]}" "$@" ;;
  table4) shift; exec python table4_distance.py --noise 0,0.03 --columns Normal-0,Normal-0.05 "${common[@]}" "$@" ;;
  table6) shift; exec python table6_num_cuboids.py --categories chair "${common[@]}" "$@" ;;
  *) echo "usage: bash experiments/ablations_15min.sh table3|table4|table6 [options]" >&2; exit 2 ;;
esac
