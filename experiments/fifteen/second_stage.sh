#!/usr/bin/env bash
# The recipe's second stage alone, from a timed run's first stage, with settings changed by --set: which of the
# second stage's settings pay, without training the first stage again. One thread, so that two run side by side.
# Usage: bash experiments/fifteen/second_stage.sh FIRST_STAGE.pt NAME [--set KEY=VALUE ...]
#   FIRST_STAGE.pt: the best.pt of a run's first stage (results/first_stage/ keeps those used here); the category is
#   read from it. Writes runs/second_stage/<first stage>--NAME/ and its card to
#   experiments/fifteen/results/second_stage/<first stage>--NAME.json (test scores as in every card), where <first stage>
#   is the file's name without .pt. python experiments/fifteen/second_stage_table.py tabulates the cards.
set -euo pipefail
first=$1 name=$2
shift 2
category=$(python -c "import sys; from cuboidlib.checkpoint import load_checkpoint; \
print(load_checkpoint(sys.argv[1])['config']['category'])" "$first")
name="$(basename "$first" .pt)--$name"
out="runs/second_stage/$name"
mkdir -p experiments/fifteen/results/second_stage
python -m cuboidlib train --config "data_samples/checkpoints/configs/15min/finetune/$category.json" \
  --out "$out" --release "$out/released.pt" --quiet \
  --set init_from="$first" --set num_threads=1 --set max_minutes=30 "$@"
cp "$out/released.json" "experiments/fifteen/results/second_stage/$name.json"
