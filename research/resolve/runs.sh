#!/usr/bin/env bash
# The studies of resolve on real meshes, rerun with this checkout's code (docs/studies/untangle_repair.md,
# untangle_extra_iterations.md, shrink_correction.md, displacement_cap.md, resolve_real_meshes.md, motion_resolve.md).
# First the four seed-0 runs they evaluate (`make run`, SCAPE's, proc_cloth's and anny_body's CPU presets; a finished
# run is skipped, an unfinished one resumes in its directory), then, one after the other, each step skipped when its
# output exists (the settings not named are this checkout's defaults):
#   repair  each run's realistic evaluation with the contact repair and with contact_untangle
#           -> RUN/realistic_{contact,contact_untangle}_rerun.json
#   extra   untangle alone on held-out colliding realistic meshes, extra_iter 0 and 160 -> extra_iter_RUN.txt
#   shrink  realistic evaluation with shrink_steps 0 and 5 -> RUN/realistic_shrink{0,5}_rerun.json; a user's resolve
#           of SCAPE's first 40 colliding realistic meshes with both -> user_scape_shrink{0,5}_rerun.json
#   cap     the same with cap_steps 0 and 6 (realistic_cap{0,6}_rerun.json, user_scape_cap{0,6}_rerun.json), and
#           anny_body's first 20 -> user_anny_cap{0,6}_rerun.json
#   user    a user's resolve of SCAPE's first 40 (contact_untangle, untangle) and anny_body's first 20
#           -> resolve_time_{scape,anny}_rerun.json; SCAPE's three motions -> sequence_scape_s{0,1,2}_rerun.json
# Runs and outputs: outputs/resolve/; cache: $NEURALCOL_CACHE (default $HOME/neuralcol-cache). Tables:
#   .venv/bin/python research/resolve/decide_table.py outputs/resolve/*_s0 --candidate contact_untangle   (repair)
#   .venv/bin/python research/resolve/shrink_table.py outputs/resolve/*_s0 [--name cap --steps 6]        (shrink, cap)
# Times are only comparable when nothing else runs on the machine.
#   research/resolve/runs.sh [repair|extra|shrink|cap|user ...]   (default: all five, in this order)
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${NEURALCOL_CACHE:-$HOME/neuralcol-cache}"
OUT=outputs/resolve
source research/run_once.sh
run_once "$OUT" make_run_s0 seed=0
run_once "$OUT" scape_s0 experiment=cpu_scape seed=0
run_once "$OUT" proc_cloth_s0 experiment=cpu_proc_cloth seed=0
run_once "$OUT" anny_body_s0 experiment=cpu_anny_body seed=0
RUNS=(make_run_s0 scape_s0 proc_cloth_s0 anny_body_s0)
export NEURALCOL_DATA=../shared/data PYTHONPATH=.
PY=.venv/bin/python

evaluate() {  # RUN NAME REPAIR_SETTING...: the run's realistic evaluation with these repair settings
  local run=$1 name=$2
  shift 2
  [ -f "$OUT/$run/realistic_${name}_rerun.json" ] && return
  local sets=()
  for kv in "$@"; do sets+=(--repair-set "$kv"); done
  echo "$run $name: $(date -u +%H:%M)"
  $PY -m experiments.evaluate_realistic "$OUT/$run" "${sets[@]}" --set repair_reference=true \
    --out "realistic_${name}_rerun.json" > "$OUT/realistic_${run}_${name}.log" 2>&1
}
user() {  # FILE RUN ROWS ARGS...: research/resolve/resolve_time.py (a user's run.resolve, timed) into OUT/FILE
  local file=$1 run=$2 rows=$3
  shift 3
  [ -f "$OUT/$file" ] && return
  echo "$file: $(date -u +%H:%M)"
  $PY research/resolve/resolve_time.py "$OUT/$run" "$rows" "$@" --out "$OUT/$file" > "$OUT/${file%.json}.log" 2>&1
}

steps=("$@")
[ ${#steps[@]} -gt 0 ] || steps=(repair extra shrink cap user)
for step in "${steps[@]}"; do
  case $step in
    repair)
      for r in "${RUNS[@]}"; do
        evaluate "$r" contact method=contact
        evaluate "$r" contact_untangle method=contact_untangle
      done ;;
    extra)  # the held-out rows of each run's colliding realistic meshes
      for spec in make_run_s0:0:60 scape_s0:40:120 proc_cloth_s0:60:140 anny_body_s0:40:80; do
        IFS=: read -r r a b <<< "$spec"
        f="$OUT/extra_iter_$r.txt"
        [ -f "$f" ] && continue
        echo "extra_iter $r: $(date -u +%H:%M)"
        for e in 0 160; do
          echo "== $r $a:$b extra_iter=$e"
          $PY research/resolve/untangle_probe.py "$OUT/$r" "$a:$b" --untangle-only extra_iter=$e
        done > "$f.part" 2>&1
        mv "$f.part" "$f"
      done ;;
    shrink|cap)
      n=5; [ "$step" = cap ] && n=6
      for r in "${RUNS[@]}"; do
        for s in 0 $n; do evaluate "$r" "$step$s" method=contact_untangle "${step}_steps=$s"; done
      done
      for s in 0 $n; do
        user "user_scape_$step${s}_rerun.json" scape_s0 0:40 --methods contact_untangle --set "handler.repair.${step}_steps=$s"
        if [ "$step" = cap ]; then
          user "user_anny_cap${s}_rerun.json" anny_body_s0 0:20 --methods contact_untangle --set "handler.repair.cap_steps=$s"
        fi
      done ;;
    user)
      user resolve_time_scape_rerun.json scape_s0 0:40 --methods contact_untangle untangle
      user resolve_time_anny_rerun.json anny_body_s0 0:20 --methods contact_untangle
      for s in 0 1 2; do
        f="$OUT/sequence_scape_s${s}_rerun.json"
        [ -f "$f" ] && continue
        echo "sequence seed $s: $(date -u +%H:%M)"
        $PY research/resolve/sequence_probe.py "$OUT/scape_s0" --seed $s --set handler.repair.method=contact_untangle \
          --out "$f" > "${f%.json}.log" 2>&1
      done ;;
    *) echo "runs.sh: unknown step '$step'; use repair, extra, shrink, cap or user" >&2; exit 2 ;;
  esac
done
