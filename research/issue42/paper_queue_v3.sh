#!/bin/bash
# issue 42, item 3 (stop 54 on): paper_queue_v2.sh with the two uniform baselines (supv, supv_bd) trained at three of
# the active methods' eight sizes, 2e5, 3.75e5 and 5.5e5 (detector.n_aug=175000 detector.max_rounds=2) instead of all
# eight: each baseline point is re-trained from scratch on the first N uniform samples of the seed's pool (paper sec.
# 5, "we re-train our two baselines ... after each iteration"), so fewer sizes change the curve's resolution, not any
# point's value, and cost 100 x (2 + 3.75 + 5.5) instead of 100 x (2 + 2.5 + ... + 5.5) row-epochs (2.7x fewer; about
# 8 h of training each at all eight sizes on 2 cores). Registered in docs/studies/scape_paper_scale.md before these runs.
# Frozen worktree as first argument (default /work/paperq). Waits for a sitting still running (from v2) to exit first.
# Start: nohup research/issue42/paper_queue_v3.sh /work/paperq > outputs/issue42/paper_queue.out 2>&1 &
W=${1:-/work/paperq}
cd $W || exit 1
while pgrep -f "experiments.run experiment=paper_scape" > /dev/null; do sleep 30; done
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
B3="detector.n_aug=175000 detector.max_rounds=2"  # the baselines at 2e5, 3.75e5, 5.5e5
run neuralcol_s0 experiment=paper_scape_neuralcol seed=0
run paper_active_s0 experiment=paper_scape method=active_paper seed=0
run paper_supv_bd_s0 experiment=paper_scape method=supv_bd seed=0 $B3
run paper_supv_s0 experiment=paper_scape method=supv seed=0 $B3
run neuralcol_s1 experiment=paper_scape_neuralcol seed=1
run paper_active_s1 experiment=paper_scape method=active_paper seed=1
run paper_supv_bd_s1 experiment=paper_scape method=supv_bd seed=1 $B3
echo done > /work/main/outputs/issue42/paper_queue.done
