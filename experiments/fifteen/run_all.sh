#!/usr/bin/env bash
# The 15-minute networks: the one command per category (python -m cuboidlib: the code of this checkout), one at a time on a quiet machine, each from an empty
# shape cache so that generating the data counts in its time. Usage: bash experiments/fifteen/run_all.sh [category ...]
# (The committed cards record the release path of the run, data_samples/checkpoints/15min/<category>.pt; the
# files were then moved here.)
set -euo pipefail
cats=("${@:-chair airplane table animal}")
for c in ${cats[@]}; do
  rm -rf "runs/${c}_15min" "/tmp/cuboidlib_cache_15min_${c}"
  start=$(date +%s.%N)
  CUBOIDLIB_CACHE="/tmp/cuboidlib_cache_15min_${c}" python -m cuboidlib train \
    --config "data_samples/checkpoints/configs/15min/${c}.json" \
    --finetune "data_samples/checkpoints/configs/15min/finetune/${c}.json" \
    --out "runs/${c}_15min" --release "experiments/fifteen/results/${c}_15min.pt" --quiet
  end=$(date +%s.%N)
  python -c "print('${c}: the whole command took %.1f s' % (${end} - ${start}))"
done
