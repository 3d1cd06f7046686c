#!/bin/bash
# issue 43, stop 51: rule v2 (contact_untangle) deciding runs; the rule registered in docs/studies/untangle_repair.md (untangle as the default
# repair): each seed-0 run's realistic evaluation with the contact repair and with untangle, ALONE (the paper-scale
# queue is paused with SIGSTOP while these run, resumed after). Runs from a frozen worktree (/work/decide, commit
# noted in decide_queue.out) so that edits in /work/main cannot change the code mid-run.
# Writes <run>/realistic_{contact,untangle}_stop51.json.
M_ROOT=/work/main
cd /work/decide
git rev-parse HEAD
export PYTHONPATH=/work/decide NEURALCOL_DATA=/work/shared/data
PY=/work/main/.venv/bin/python
pause() { for p in $(pgrep -f "experiments.run experiment=paper_scape"); do kill -$1 $p; pkill -$1 -P $p; done; }
trap 'pause CONT' EXIT
pause STOP
for R in outputs/issue41/item4/makerun4_fresh outputs/issue41/scape_def_s0 outputs/issue41/cloth_def_s0 outputs/issue41/anny_def_s0; do
  for M in contact_untangle; do
    test -f $M_ROOT/$R/realistic_${M}_stop51.json && continue
    /usr/bin/time -v $PY -m experiments.evaluate_realistic $M_ROOT/$R --repair-set method=$M --set repair_reference=true \
        --out realistic_${M}_stop51.json >> $M_ROOT/outputs/issue43/decide_$(basename $R)_$M.log 2>&1
  done
done
echo done > $M_ROOT/outputs/issue43/decide_v2.done
