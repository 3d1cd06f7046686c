#!/usr/bin/env bash
# The data sets' runs that research/anymesh/realistic_resolve.py --runs resolves with (the trained path beside the
# exact repairs alone): proc_cloth's and anny_body's CPU presets, seed 0, one after the other (SCAPE's and
# proc_hand's come from research/exact_labels/remeasure.sh). Rerun the same command to go on after an interruption:
# a finished run (metrics.json) is skipped, an unfinished one resumes in its directory.
# Cache outside the checkout: $NEURALCOL_CACHE (default $HOME/neuralcol-cache). Runs: outputs/anymesh/runs/.
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${NEURALCOL_CACHE:-$HOME/neuralcol-cache}"
PY=".venv/bin/python"
OUT=outputs/anymesh/runs
run() {  # name, overrides...
  local name=$1; shift
  local dir="$OUT/$name"
  if [ -f "$dir/metrics.json" ]; then echo "$name: done"; return; fi
  echo "$name: $(date -u +%H:%M) start"
  NEURALCOL_DATA=../shared/data NEURALCOL_PROGRESS=lines $PY -m experiments.run "$@" paths.cache_dir="$CACHE" \
    hydra.run.dir="$dir" > "$OUT/$name.log" 2>&1
  echo "$name: $(date -u +%H:%M) end"
}
mkdir -p "$OUT"
run cpu_proc_cloth_s0 experiment=cpu_proc_cloth seed=0
run cpu_anny_body_s0 experiment=cpu_anny_body seed=0
