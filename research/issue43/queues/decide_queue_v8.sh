#!/bin/bash
# issue 43, stop 53: the rule registered in docs/studies/shrink_correction.md: each seed-0
# run's realistic evaluation with today's defaults (shrink_steps=0) and with shrink_steps=5, one after the other,
# ALONE (the paper-scale queue is paused with SIGSTOP while these run, resumed after). Runs from a frozen worktree
# (/work/decide8, its commit printed first) so that edits in /work/main cannot change the code mid-run.
# Writes <run>/realistic_shrink{0,5}_stop53.json; then the user path (resolve_time.py, SCAPE's first 40) with both.
M_ROOT=/work/main
cd /work/decide8 || exit 1
git rev-parse HEAD
export PYTHONPATH=/work/decide8 NEURALCOL_DATA=/work/shared/data
PY=/work/main/.venv/bin/python
pause() { for p in $(pgrep -f "experiments.run experiment=paper_scape"); do kill -$1 $p; pkill -$1 -P $p; done; }
trap 'pause CONT' EXIT
pause STOP
for R in outputs/issue41/item4/makerun4_fresh outputs/issue41/scape_def_s0 outputs/issue41/cloth_def_s0 outputs/issue41/anny_def_s0; do
  for S in 0 5; do
    test -f $M_ROOT/$R/realistic_shrink${S}_stop53.json && continue
    /usr/bin/time -v $PY -m experiments.evaluate_realistic $M_ROOT/$R --repair-set method=contact_untangle \
        --repair-set shrink_steps=$S --set repair_reference=true --out realistic_shrink${S}_stop53.json \
        >> $M_ROOT/outputs/issue43/decide_$(basename $R)_shrink${S}_stop53.log 2>&1
  done
done
for S in 0 5; do
  $PY research/issue43/resolve_time.py $M_ROOT/outputs/issue41/scape_def_s0 0:40 --methods contact_untangle \
      --set handler.repair.shrink_steps=$S --out $M_ROOT/outputs/issue43/user_scape_shrink${S}_stop53.json \
      > $M_ROOT/outputs/issue43/user_scape_shrink${S}_stop53.log 2>&1
done
echo done > $M_ROOT/outputs/issue43/decide_v8.done
