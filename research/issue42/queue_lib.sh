# issue 42: what the paper-scale queues share (sourced; paper_queue_tail.sh on — v3 and side carry their own copy,
# written before this file and not edited while bash runs them). Frozen worktree as first argument of the caller.
# run NAME OVERRIDES...: one job to its end in sittings of max_minutes (rerun on exit 75); returns at once when
# NAME finished (metrics.json) and with the run's exit code when it fails or another queue holds its lock (2).
W=${W:-/work/paperq}
cd $W || exit 1
source /work/main/.venv/bin/activate; export PYTHONPATH=$W
export NEURALCOL_DATA=/work/shared/data
C="paths.cache_dir=$HOME/neuralcol-cache"
R=$HOME/neuralcol-runs/issue42
mkdir -p $R
B3="detector.n_aug=175000 detector.max_rounds=2"  # the baselines at 2e5, 3.75e5, 5.5e5
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
