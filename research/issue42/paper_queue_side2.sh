#!/bin/bash
# issue 42, stop 58 on: the side queue (paper_queue_side.sh) with one change of order, none of commands. Issue 42 asks
# for two seeds of supv_bd and of the active methods; supv_bd_s1 was last in v3's list, behind paper_active_s1 (about
# 2 h on one core), so it would have waited a session. This queue runs it right after paper_supv_s1. The jobs and
# their overrides are those of paper_queue_side.sh and paper_queue_v3.sh, unchanged. v3 skips paper_supv_bd_s1 when
# this queue holds its lock (exit 2) or has finished it (metrics.json), then writes paper_queue.done and the tail starts.
# Usage: research/issue42/paper_queue_side2.sh /work/paperq (resume_queue.sh starts it).
W=${1:-/work/paperq}
source /work/main/research/issue42/queue_lib.sh
# paper_supv_s1 may still run, started by paper_queue_side.sh (stopped when this queue replaced it): wait for it, then
# let run() go on with it (a sitting that hit max_minutes) or return at once (finished).
while pgrep -f "hydra.run.dir=$R/paper_supv_s1( |$)" > /dev/null; do sleep 30; done
run paper_supv_s1 experiment=paper_scape method=supv seed=1 $B3
run paper_supv_bd_s1 experiment=paper_scape method=supv_bd seed=1 $B3
run paper_active_s2 experiment=paper_scape method=active_paper seed=2
run paper_supv_bd_s2 experiment=paper_scape method=supv_bd seed=2 $B3
run paper_supv_s2 experiment=paper_scape method=supv seed=2 $B3
run neuralcol_s2 experiment=paper_scape_neuralcol seed=2
echo done > /work/main/outputs/issue42/paper_queue_side2.done
