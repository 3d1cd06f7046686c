#!/usr/bin/env bash
# What stands on the labels, re-measured with the exact verdicts: `make run` (proc_hand) and SCAPE's CPU preset,
# seeds 0-2 each, one after the other. Rerun the same command to go on after an interruption: a finished run
# (metrics.json) is skipped, an unfinished one resumes in its directory. Summary: research/exact_labels/summary.py.
# Cache outside the checkout: $NEURALCOL_CACHE (default $HOME/neuralcol-cache). Runs: outputs/exact_labels/.
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${NEURALCOL_CACHE:-$HOME/neuralcol-cache}"
source research/run_once.sh
OUT=outputs/exact_labels
for s in 0 1 2; do run_once $OUT "make_run_s$s" seed=$s; done
for s in 0 1 2; do run_once $OUT "cpu_scape_s$s" experiment=cpu_scape seed=$s; done
