#!/bin/bash
# issue 42: where the paper-scale queues (paper_queue_v3.sh, paper_queue_side2.sh, paper_queue_tail.sh) stand: each job's state and finished rounds.
R=$HOME/neuralcol-runs/issue42
cd /work/main
for name in neuralcol_s0 paper_active_s0 paper_supv_bd_s0 paper_supv_s0 neuralcol_s1 paper_active_s1 paper_supv_bd_s1 \
    paper_supv_s1 paper_active_s2 paper_supv_bd_s2 paper_supv_s2 neuralcol_s2; do
  d=$R/$name
  if [ -f $d/metrics.json ]; then state=finished
  elif pgrep -f "hydra.run.dir=$d( |$)" > /dev/null; then state=running
  elif [ -d $d ]; then state="stopped (rerun the queue to go on)"
  else state="not started"; fi
  echo "== $name: $state"
  [ -f $d/detector_rounds.json ] && PYTHONPATH=. .venv/bin/python research/issue42/rounds_table.py $d
  [ "$state" = running ] && tail -c 300 $R/$name.log | tr '\r' '\n' | tail -2
done
true
