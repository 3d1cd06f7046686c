#!/usr/bin/env bash
# make run (seed 0) with torch's portable CPU kernels (ATEN_CPU_CAPABILITY=default) beside the machine's own
# (AVX512 on this project's machine): does a run on another kernel set land inside the README's 3-seed band?
#   research/threshold/kernel_set.sh            today's settings, beside research/exact_labels/remeasure.sh's make_run_s0
#   research/threshold/kernel_set.sh rule_v2    rule v2's settings, beside research/threshold/rule_runs.sh v2's make_run_s0
# Read with:
#   .venv/bin/python -m research.exact_labels.summary outputs/threshold/kernel_default_s0
# Rerun the same command to go on (a finished run is skipped). Cache: $NEURALCOL_CACHE (default $HOME/neuralcol-cache).
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${NEURALCOL_CACHE:-$HOME/neuralcol-cache}"
name=kernel_default_s0
extra=()
source research/threshold/rules.sh
case ${1:-} in
  "") ;;
  rule_v1) name=kernel_default_rule_v1_s0; extra=("${RULE_v1[@]}") ;;
  rule_v2) name=kernel_default_rule_v2_s0; extra=("${RULE_v2[@]}") ;;
  *) echo "kernel_set.sh: unknown rule '$1'; use rule_v1, rule_v2 or nothing (today's settings)" >&2; exit 2 ;;
esac
dir=outputs/threshold/$name
mkdir -p outputs/threshold
if [ -f "$dir/metrics.json" ]; then echo "$name: done"; exit 0; fi
ATEN_CPU_CAPABILITY=default NEURALCOL_DATA=../shared/data NEURALCOL_PROGRESS=lines .venv/bin/python -m experiments.run \
  seed=0 "${extra[@]}" paths.cache_dir="$CACHE" hydra.run.dir="$dir" > "outputs/threshold/$name.log" 2>&1
echo "$name: done"
