#!/bin/bash
# issue 42 (stop 56 on): a second queue beside paper_queue_v3.sh, registered in docs/studies/scape_paper_scale.md before its runs: the
# third seed of every method (neuralcol's default, active_paper, supv_bd, supv) and supv's second, so that Table 3's
# headline figures are means over 3 seeds (the guide's rule), plus neuralcol_s1 started now instead of after the
# paper's seed-0 runs. The paper's latent-only detector trains on one core (4 s an epoch over 1.6e5 rows), so the
# second core idles while v3 trains it; runs that overlap are marked in docs/studies/scape_paper_scale.md, their wall times are not
# those of a machine to themselves. Same commands as v3 (its `run`): a job v3 also lists (neuralcol_s1) is skipped by
# whichever queue comes second (finished: metrics.json; still running: the run directory's lock refuses it at once).
# Frozen worktree as first argument (default /work/paperq).
# Start: nohup research/issue42/paper_queue_side.sh /work/paperq >> outputs/issue42/paper_queue_side.out 2>&1 &
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
B3="detector.n_aug=175000 detector.max_rounds=2"  # the baselines at 2e5, 3.75e5, 5.5e5
run neuralcol_s1 experiment=paper_scape_neuralcol seed=1
run paper_supv_s1 experiment=paper_scape method=supv seed=1 $B3
run paper_active_s2 experiment=paper_scape method=active_paper seed=2
run paper_supv_bd_s2 experiment=paper_scape method=supv_bd seed=2 $B3
run paper_supv_s2 experiment=paper_scape method=supv seed=2 $B3
run neuralcol_s2 experiment=paper_scape_neuralcol seed=2
echo done > /work/main/outputs/issue42/paper_queue_side.done
