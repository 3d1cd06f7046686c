#!/bin/bash
# issue 42 (stop 59 on): the registered variant run paper_active_bdbatch_s0 (stop 57, docs/studies/scape_paper_scale.md) on the core
# paper_queue_side2.sh frees when it finishes, instead of waiting behind neuralcol_s2 (~4 h) at the end of
# paper_queue_tail.sh. Same command and options as the tail's last job; only which core runs it and when. Whichever
# queue comes second skips it (finished: metrics.json; running: its run directory's lock, exit 2).
# Waits until side2 is done (outputs/issue42/paper_queue_side2.done). Frozen worktree as first argument.
# Start: research/issue42/resume_queue.sh (or nohup research/issue42/paper_queue_variant.sh /work/paperq &)
W=${1:-/work/paperq}
until [ -f /work/main/outputs/issue42/paper_queue_side2.done ]; do sleep 60; done
source /work/main/research/issue42/queue_lib.sh
R=$HOME/neuralcol-runs/issue42_side run paper_active_bdbatch_s0 experiment=paper_scape method=active_paper seed=0 \
  detector.loss.boundary_reduction=batch
echo done > /work/main/outputs/issue42/paper_queue_variant.done
