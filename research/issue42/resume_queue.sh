#!/bin/bash
# issue 42: start (or restart, at the beginning of a session) the paper-scale queues, then show where they stand.
# Moves the frozen worktree /work/paperq to main's HEAD when no sitting runs (the queues' code for their next
# sittings), and starts research/issue42/paper_queue_v3.sh, paper_queue_side.sh (stop 56 on) and paper_queue_tail.sh
# (stop 57 on: the side queue's jobs from its end once v3 is done) in the background unless they already run. Stop 58
# on, paper_queue_side2.sh replaces paper_queue_side.sh (same jobs, paper_supv_bd_s1 second); stop 59 on,
# paper_queue_variant.sh runs the tail's last job (the registered variant) once side2 is done. Each job's finished
# rounds: research/issue42/queue_status.sh. Usage (from /work/main): research/issue42/resume_queue.sh
set -e
cd /work/main
if ! pgrep -f "experiments.run experiment=paper_scape" > /dev/null; then
  git worktree prune
  if git worktree list | grep -q /work/paperq; then
    git -C /work/paperq checkout -q --detach "$(git rev-parse HEAD)"
  else
    git worktree add -f /work/paperq "$(git rev-parse HEAD)" --detach
  fi
fi
mkdir -p outputs/issue42
for q in paper_queue_v3 paper_queue_side2 paper_queue_tail paper_queue_variant; do
  if pgrep -f $q.sh > /dev/null; then
    echo "$q already runs (pid $(pgrep -f $q.sh | head -1))"
  elif [ -f outputs/issue42/${q%_v3}.done ]; then  # v3 writes paper_queue.done
    echo "$q is done"
  else
    nohup research/issue42/$q.sh /work/paperq >> outputs/issue42/$q.out 2>&1 &
    echo "$q started at $(git -C /work/paperq rev-parse --short HEAD) (log: outputs/issue42/$q.out)"
    sleep 5  # v3 first: a job both list goes to v3's order when neither runs it yet
  fi
done
exec research/issue42/queue_status.sh
