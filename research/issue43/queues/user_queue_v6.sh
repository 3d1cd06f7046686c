#!/bin/bash
# issue 43, stop 52: the user path re-timed with extra_iter on (default contact_untangle), ALONE (the paper-scale run
# paused with SIGSTOP, resumed after), from a frozen worktree (/work/decide7); then the three SCAPE motions with it.
M_ROOT=/work/main
cd /work/decide7
git rev-parse HEAD
export PYTHONPATH=/work/decide7 NEURALCOL_DATA=/work/shared/data
PY=/work/main/.venv/bin/python
O=$M_ROOT/outputs/issue43
pause() { for p in $(pgrep -f "experiments.run experiment=paper_scape"); do kill -$1 $p; pkill -$1 -P $p; done; }
trap 'pause CONT' EXIT
pause STOP
$PY research/issue43/resolve_time.py $M_ROOT/outputs/issue41/scape_def_s0 0:40 --methods contact_untangle \
    --out $O/resolve_time_scape_stop52b.json > $O/resolve_time_scape_stop52b.log 2>&1
$PY research/issue43/resolve_time.py $M_ROOT/outputs/issue41/anny_def_s0 0:20 --methods contact_untangle \
    --out $O/resolve_time_anny_stop52b.json > $O/resolve_time_anny_stop52b.log 2>&1
echo done > $O/user_v6.done
