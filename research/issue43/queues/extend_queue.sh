#!/bin/bash
# issue 43, stop 52: the extra_iter rule's runs (docs/studies/untangle_extra_iterations.md),
# untangle alone on held-out colliding realistic meshes, extra_iter=0 then 160, alone (paper-scale run paused),
# from a frozen worktree.
M_ROOT=/work/main
cd /work/decide6
git rev-parse HEAD
export PYTHONPATH=/work/decide6 NEURALCOL_DATA=/work/shared/data
PY=/work/main/.venv/bin/python
pause() { for p in $(pgrep -f "experiments.run experiment=paper_scape"); do kill -$1 $p; pkill -$1 -P $p; done; }
trap 'pause CONT' EXIT
pause STOP
for spec in anny_def_s0:40:80 scape_def_s0:40:120 cloth_def_s0:60:140 item4/makerun4_fresh:0:60; do
  IFS=: read n a b <<< "$spec"
  for E in 0 160; do
    echo "== $n $a:$b extra_iter=$E"
    $PY research/issue43/untangle_probe.py $M_ROOT/outputs/issue41/$n $a:$b --untangle-only extra_iter=$E
  done
done
echo done > $M_ROOT/outputs/issue43/extend.done
