#!/bin/bash
# issue 42: start (or restart, at the beginning of a session) the paper-scale queue, then show where it stands.
# Moves the frozen worktree /work/paperq to main's HEAD when no sitting runs (the queue's code for its next sittings),
# and starts research/issue42/paper_queue_v3.sh in the background unless it already runs. Each job's finished
# rounds: research/issue42/queue_status.sh. Usage (from /work/main): research/issue42/resume_queue.sh
set -e
cd /work/main
if pgrep -f paper_queue_v3.sh > /dev/null; then
  echo "the queue already runs (pid $(pgrep -f paper_queue_v3.sh | head -1))"
else
  if ! pgrep -f "experiments.run experiment=paper_scape" > /dev/null; then
    git worktree prune
    if git worktree list | grep -q /work/paperq; then
      git -C /work/paperq checkout -q --detach "$(git rev-parse HEAD)"
    else
      git worktree add -f /work/paperq "$(git rev-parse HEAD)" --detach
    fi
  fi
  mkdir -p outputs/issue42
  nohup research/issue42/paper_queue_v3.sh /work/paperq >> outputs/issue42/paper_queue_v3.out 2>&1 &
  echo "queue started at $(git -C /work/paperq rev-parse --short HEAD) (log: outputs/issue42/paper_queue_v3.out)"
fi
exec research/issue42/queue_status.sh
