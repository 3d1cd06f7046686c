#!/bin/bash
# issue 42, item 3: SCAPE at the paper's scale in sittings. Each line is rerun until it exits 0 (75 = a sitting's
# budget spent, everything saved). Caches and run directories live outside the checkout:
#   cache: $HOME/neuralcol-cache   runs: $HOME/neuralcol-runs/issue42/<name>
# Start (after issue 41's queue): nohup outputs/issue42/paper_queue.sh > outputs/issue42/paper_queue.out 2>&1 &
# Stop: kill the script and its python child; rerunning the script goes on where it stopped.
cd /work/main
while [ ! -f outputs/issue41/queue2.done ]; do sleep 60; done  # issue 41's queue (queue5.sh) writes it when done
source .venv/bin/activate
export NEURALCOL_DATA=../shared/data
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
# first, issue 41 item 4: `make run` at its re-sized preset (4 rounds, stop 49), seeds 1 and 2 (seed 0:
# outputs/issue41/item4/makerun4_fresh), with the shared cache, for the README's 3-seed numbers
for S in 1 2; do
  test -f outputs/issue41/item4/makerun4_s$S/metrics.json || /usr/bin/time -v python -m experiments.run seed=$S $C \
      hydra.run.dir=outputs/issue41/item4/makerun4_s$S >> outputs/issue41/item4/makerun4_s$S.log 2>&1
done
run neuralcol_s0 experiment=paper_scape_neuralcol seed=0
run paper_active_s0 experiment=paper_scape method=active_paper seed=0
run paper_supv_bd_s0 experiment=paper_scape method=supv_bd seed=0
run paper_supv_s0 experiment=paper_scape method=supv seed=0
run neuralcol_s1 experiment=paper_scape_neuralcol seed=1
run paper_active_s1 experiment=paper_scape method=active_paper seed=1
run paper_supv_bd_s1 experiment=paper_scape method=supv_bd seed=1
echo done > outputs/issue42/paper_queue.done
