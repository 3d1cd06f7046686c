#!/usr/bin/env bash
# make run (seed 0) with torch's portable CPU kernels (ATEN_CPU_CAPABILITY=default) beside the machine's own
# (research/exact_labels/remeasure.sh's make_run_s0, AVX512 on this project's machine): does a run on another
# kernel set land inside the README's 3-seed band? Read with:
#   .venv/bin/python -m research.exact_labels.summary outputs/threshold/kernel_default_s0
# Rerun the same command to go on (a finished run is skipped). Cache: $NEURALCOL_CACHE (default $HOME/neuralcol-cache).
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${NEURALCOL_CACHE:-$HOME/neuralcol-cache}"
dir=outputs/threshold/kernel_default_s0
mkdir -p outputs/threshold
if [ -f "$dir/metrics.json" ]; then echo "kernel_default_s0: done"; exit 0; fi
ATEN_CPU_CAPABILITY=default NEURALCOL_DATA=../shared/data NEURALCOL_PROGRESS=lines .venv/bin/python -m experiments.run \
  seed=0 paths.cache_dir="$CACHE" hydra.run.dir="$dir" > outputs/threshold/kernel_default_s0.log 2>&1
echo "kernel_default_s0: done"
