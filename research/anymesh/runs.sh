#!/usr/bin/env bash
# The data sets' runs that research/anymesh/realistic_resolve.py --runs resolves with (the trained path beside the
# exact repairs alone): proc_cloth's and anny_body's CPU presets, seed 0, one after the other (SCAPE's and
# proc_hand's come from research/exact_labels/remeasure.sh). Rerun the same command to go on after an interruption:
# a finished run (metrics.json) is skipped, an unfinished one resumes in its directory.
# Cache outside the checkout: $NEURALCOL_CACHE (default $HOME/neuralcol-cache). Runs: outputs/anymesh/runs/.
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${NEURALCOL_CACHE:-$HOME/neuralcol-cache}"
source research/run_once.sh
run_once outputs/anymesh/runs cpu_proc_cloth_s0 experiment=cpu_proc_cloth seed=0
run_once outputs/anymesh/runs cpu_anny_body_s0 experiment=cpu_anny_body seed=0
