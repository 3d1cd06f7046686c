#!/bin/bash
# issue 42 (stop 57 on): the side queue's jobs from its end, on the core paper_queue_v3.sh frees when it finishes.
# v3 holds 7 jobs of ~2 h (neuralcol_s1 went to the side queue), the side queue 6 with two neuralcol runs of ~5 h:
# alone, the side queue would run ~9 h after v3 is done with one core idle. Same jobs, commands and options (nothing
# added or dropped; registered in docs/studies/scape_paper_scale.md): neuralcol_s2, paper_supv_s2, paper_supv_bd_s2, paper_active_s2,
# paper_supv_s1, then one variant run (paper_active_bdbatch_s0, below); a job the side queue runs is refused by
# its lock (exit 2, the tail moves on), one it finished is skipped, and the side queue skips what the tail holds or
# finished the same way.
# Waits until v3 is done (outputs/issue42/paper_queue.done). Frozen worktree as first argument (default /work/paperq).
# Start: nohup research/issue42/paper_queue_tail.sh /work/paperq >> outputs/issue42/paper_queue_tail.out 2>&1 &
W=${1:-/work/paperq}
until [ -f /work/main/outputs/issue42/paper_queue.done ]; do sleep 60; done
source /work/main/research/issue42/queue_lib.sh
run neuralcol_s2 experiment=paper_scape_neuralcol seed=2
run paper_supv_s2 experiment=paper_scape method=supv seed=2 $B3
run paper_supv_bd_s2 experiment=paper_scape method=supv_bd seed=2 $B3
run paper_active_s2 experiment=paper_scape method=active_paper seed=2
run paper_supv_s1 experiment=paper_scape method=supv seed=1 $B3
# after Table 3's jobs, outside $R so the report does not pool it with active_paper (stop 57, registered in
# docs/studies/scape_paper_scale.md): the paper's configuration with one change, L_b averaged over the batch instead of over D_b's rows
R=$HOME/neuralcol-runs/issue42_side run paper_active_bdbatch_s0 experiment=paper_scape method=active_paper seed=0 \
  detector.loss.boundary_reduction=batch
echo done > /work/main/outputs/issue42/paper_queue_tail.done
