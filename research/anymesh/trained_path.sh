#!/usr/bin/env bash
# resolve with each data set's trained run (its learned handler, then the same repairs) on the meshes the study
# without a run resolved: the seed-0 draw and the held-out seed-1 draw (research/anymesh/realistic_resolve.py;
# needs its seed-0 output, outputs/anymesh/realistic_resolve.json). Runs: SCAPE's and proc_hand's from
# research/exact_labels/remeasure.sh, proc_cloth's and anny_body's from research/anymesh/runs.sh; a data set whose
# run has not finished is left for the next call. A finished output is skipped; rerun the same command to go on.
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=outputs/anymesh/trained
mkdir -p "$OUT"
declare -A runs=([scape]=outputs/exact_labels/cpu_scape_s0 [proc_hand]=outputs/exact_labels/make_run_s0
                 [proc_cloth]=outputs/anymesh/runs/cpu_proc_cloth_s0 [anny_body]=outputs/anymesh/runs/cpu_anny_body_s0)
for name in scape proc_hand proc_cloth anny_body; do
  run=${runs[$name]}
  if [ ! -f "$run/metrics.json" ]; then echo "$name: no finished run at $run yet"; continue; fi
  common=(--datasets "$name" --motions 0 --n-free 0 --runs "$name=$run")
  [ -f "$OUT/seed0_$name.json" ] || .venv/bin/python -m research.anymesh.realistic_resolve "${common[@]}" \
    --out "$OUT/seed0_$name.json" > "$OUT/seed0_$name.log" 2>&1
  [ -f "$OUT/heldout_$name.json" ] || .venv/bin/python -m research.anymesh.realistic_resolve "${common[@]}" \
    --seed 1 --exclude-from outputs/anymesh/realistic_resolve.json --out "$OUT/heldout_$name.json" \
    > "$OUT/heldout_$name.log" 2>&1
  echo "$name: done"
done
