#!/usr/bin/env bash
# The recipe's two stages with another seed, repeatably: one thread, the first stage stopped after 2500 steps
# (about what its 9 minutes give on a quiet machine) instead of by the clock, so that a learning rate that falls over
# the recipe's minutes falls over those steps. Two runs side by side use both cores; each takes about 15 minutes.
# Usage: bash experiments/fifteen/seeds.sh CATEGORY SEED NAME [--set KEY=VALUE ...] [--both KEY=VALUE ...]
#   SEED seeds both stages; --set changes the first stage, --both both stages; a NAME ending in "-<N>steps" stops
#   the first stage after N steps instead of 2500. Writes runs/seeds/<category>--NAME--seed<SEED>/ and its card to
#   experiments/fifteen/results/seeds/<category>--NAME--seed<SEED>.json (test scores as in every card).
#   python experiments/fifteen/seeds_table.py tabulates the cards.
set -euo pipefail
category=$1 seed=$2 name=$3
shift 3
first_sets=() second_sets=()
while (($#)); do
  case $1 in
    --set) first_sets+=(--set "$2"); shift 2 ;;
    --both) first_sets+=(--set "$2"); second_sets+=(--set "$2"); shift 2 ;;
    *) echo "seeds.sh: expected --set KEY=VALUE or --both KEY=VALUE, got $1" >&2; exit 2 ;;
  esac
done
run="$category--$name--seed$seed"
out="runs/seeds/$run"
mkdir -p experiments/fifteen/results/seeds
config="data_samples/checkpoints/configs/15min/$category.json"
steps=2500
if [[ $name =~ -([0-9]+)steps$ ]]; then steps=${BASH_REMATCH[1]}; fi
# a rate that falls over the recipe's 9 minutes falls over the steps instead
schedule=$(python -c "import json, sys; s = json.load(open(sys.argv[1])).get('lr_schedule', 'constant'); \
print('cosine' if s == 'cosine_minutes' else s)" "$config")
python -m cuboidlib train --config "$config" --out "$out" --quiet --set num_threads=1 --set seed="$seed" \
  --set max_steps="$steps" --set max_minutes=60 --set lr_schedule="$schedule" ${first_sets[@]+"${first_sets[@]}"}
python -m cuboidlib train --config "data_samples/checkpoints/configs/15min/finetune/$category.json" \
  --out "$out/finetune" --release "$out/released.pt" --quiet \
  --set init_from="$out/best.pt" --set num_threads=1 --set max_minutes=30 --set seed="$seed" \
  ${second_sets[@]+"${second_sets[@]}"}
cp "$out/released.json" "experiments/fifteen/results/seeds/$run.json"
