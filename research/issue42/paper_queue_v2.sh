#!/bin/bash
# issue 42, item 3: SCAPE at the paper's scale in sittings, from a frozen worktree (first argument, default
# /work/paperq; `git worktree add -f /work/paperq COMMIT --detach`) so that edits in the checkout cannot change a
# running sitting. Each line is rerun until it exits 0 (75 = a sitting's budget spent, everything saved).
# Caches and run directories live outside the checkout:
#   cache: $HOME/neuralcol-cache   runs: $HOME/neuralcol-runs/issue42/<name>
# Start: nohup research/issue42/paper_queue_v2.sh /work/paperq > outputs/issue42/paper_queue.out 2>&1 &
# Stop: kill the script and its python child; rerunning the script goes on where it stopped.
# (paper_queue_frozen.sh, stop 52-53, ran issue 41's make-run seeds first; those are done and recorded.)
W=${1:-/work/paperq}
cd $W || exit 1
source /work/main/.venv/bin/activate; export PYTHONPATH=$W
export NEURALCOL_DATA=/work/shared/data
C="paths.cache_dir=$HOME/neuralcol-cache"
R=$HOME/neuralcol-runs/issue42
mkdir -p $R
run() {  # name, overrides...
  local name=$1; shift
  test -f $R/$name/metrics.json && return 0
  while true; do
    /usr/bin/time -v python -m experiments.run "$@" max_minutes=${SITTING_MINUTES:-120} $C hydra.run.dir=$R/$name >> $R/$name.log 2>&1
    rc=$?
    [ $rc -eq 0 ] && return 0
    [ $rc -ne 75 ] && { echo "$name failed with exit code $rc (see $R/$name.log)"; return $rc; }
  done
}
run neuralcol_s0 experiment=paper_scape_neuralcol seed=0
run paper_active_s0 experiment=paper_scape method=active_paper seed=0
run paper_supv_bd_s0 experiment=paper_scape method=supv_bd seed=0
run paper_supv_s0 experiment=paper_scape method=supv seed=0
run neuralcol_s1 experiment=paper_scape_neuralcol seed=1
run paper_active_s1 experiment=paper_scape method=active_paper seed=1
run paper_supv_bd_s1 experiment=paper_scape method=supv_bd seed=1
echo done > /work/main/outputs/issue42/paper_queue.done
