#!/bin/bash
# issue 43, stop 52: what a user's resolve costs with the new default (contact_untangle), ALONE (the paper-scale run
# paused with SIGSTOP, resumed after), from a frozen worktree (/work/decide5); then the three SCAPE motions with it.
M_ROOT=/work/main
cd /work/decide5
git rev-parse HEAD
export PYTHONPATH=/work/decide5 NEURALCOL_DATA=/work/shared/data
PY=/work/main/.venv/bin/python
O=$M_ROOT/outputs/issue43
pause() { for p in $(pgrep -f "experiments.run experiment=paper_scape"); do kill -$1 $p; pkill -$1 -P $p; done; }
trap 'pause CONT' EXIT
pause STOP
$PY research/issue43/resolve_time.py $M_ROOT/outputs/issue41/scape_def_s0 0:40 --methods contact_untangle untangle \
    --out $O/resolve_time_scape_stop52.json > $O/resolve_time_scape_stop52.log 2>&1
$PY research/issue43/resolve_time.py $M_ROOT/outputs/issue41/anny_def_s0 0:20 --methods contact_untangle \
    --out $O/resolve_time_anny_stop52.json > $O/resolve_time_anny_stop52.log 2>&1
for S in 0 1 2; do
  $PY research/issue43/sequence_probe.py $M_ROOT/outputs/issue41/scape_def_s0 --seed $S \
      --set handler.repair.method=contact_untangle --out $O/sequence_scape_contact_untangle_s$S.json \
      > $O/sequence_scape_contact_untangle_s$S.log 2>&1
done
echo done > $O/user_v5.done
