#!/usr/bin/env bash
# The deciding runs of the operating threshold's rule v1 (docs/studies/operating_threshold.md):
# make run (proc_hand), SCAPE's, proc_cloth's and anny_body's CPU presets, seeds 0-2, each with the realistic test
# set grown (4x the candidates, up to 1000 clear meshes per class; anny_body 2x and 300) and the threshold set on a
# realistic calibration set apart from D_c drawn the same way (realistic.calibration.scale=1: as large as the grown
# test set). Today's rule on the same test sets is scored offline from the same runs
# (research/threshold/rule_summary.py). Rerun the same command to go on: a finished run (metrics.json) is
# skipped, an unfinished one resumes in its directory. Cache: $NEURALCOL_CACHE (default $HOME/neuralcol-cache).
#   research/threshold/rule_v1.sh [make_run|scape|proc_cloth|anny_body ...]   (default: all four, in this order)
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${NEURALCOL_CACHE:-$HOME/neuralcol-cache}"
OUT=outputs/threshold/rule_v1
source research/run_once.sh
source research/threshold/rules.sh
sets=("$@")
[ ${#sets[@]} -gt 0 ] || sets=(make_run scape proc_cloth anny_body)
for d in "${sets[@]}"; do
  for s in 0 1 2; do
    case $d in
      make_run) run_once "$OUT" "make_run_s$s" seed=$s "${RULE_v1[@]}" ;;
      scape) run_once "$OUT" "scape_s$s" experiment=cpu_scape seed=$s "${RULE_v1[@]}" ;;
      proc_cloth) run_once "$OUT" "proc_cloth_s$s" experiment=cpu_proc_cloth seed=$s "${RULE_v1[@]}" ;;
      anny_body) run_once "$OUT" "anny_body_s$s" experiment=cpu_anny_body seed=$s "${BODY_v1[@]}" ;;
      *) echo "rule_v1.sh: unknown data set '$d'; use make_run, scape, proc_cloth or anny_body" >&2; exit 2 ;;
    esac
  done
done
