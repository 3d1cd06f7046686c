#!/bin/bash
# issue 43, stop 53: a user's run.resolve of anny_body's first 20 colliding realistic meshes with cap_steps 0 and 6,
# ALONE (paper-scale queue paused), from the frozen worktree /work/decide10 (the cap rule v10's code).
M_ROOT=/work/main
cd /work/decide10 || exit 1
git rev-parse HEAD
export PYTHONPATH=/work/decide10 NEURALCOL_DATA=/work/shared/data
PY=/work/main/.venv/bin/python
pause() { for p in $(pgrep -f "experiments.run experiment=paper_scape"); do kill -$1 $p; pkill -$1 -P $p; done; }
trap 'pause CONT' EXIT
pause STOP
for S in 0 6; do
  $PY research/issue43/resolve_time.py $M_ROOT/outputs/issue41/anny_def_s0 0:20 --methods contact_untangle \
      --set handler.repair.cap_steps=$S --out $M_ROOT/outputs/issue43/user_anny_cap${S}_stop53b.json \
      > $M_ROOT/outputs/issue43/user_anny_cap${S}_stop53b.log 2>&1
done
