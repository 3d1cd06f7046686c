#!/usr/bin/env bash
# What stands on the labels, re-measured with the exact verdicts: `make run` (proc_hand) and SCAPE's CPU preset,
# seeds 0-2 each, one after the other. Rerun the same command to go on after an interruption: a finished run
# (metrics.json) is skipped, an unfinished one resumes in its directory. Summary: research/exact_labels/summary.py.
# Cache outside the checkout: $NEURALCOL_CACHE (default $HOME/neuralcol-cache). Runs: outputs/exact_labels/.
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${NEURALCOL_CACHE:-$HOME/neuralcol-cache}"
PY=".venv/bin/python"
run() {  # name, overrides...
  local name=$1; shift
  local dir="outputs/exact_labels/$name"
  if [ -f "$dir/metrics.json" ]; then echo "$name: done"; return; fi
  echo "$name: $(date -u +%H:%M) start"
  NEURALCOL_DATA=../shared/data NEURALCOL_PROGRESS=lines $PY -m experiments.run "$@" paths.cache_dir="$CACHE" \
    hydra.run.dir="$dir" > "outputs/exact_labels/$name.log" 2>&1
  echo "$name: $(date -u +%H:%M) end"
}
mkdir -p outputs/exact_labels
for s in 0 1 2; do run "make_run_s$s" seed=$s; done
for s in 0 1 2; do run "cpu_scape_s$s" experiment=cpu_scape seed=$s; done
