#!/usr/bin/env bash
# SCAPE at the paper's scale, Table 3 over three seeds (docs/studies/scape_paper_scale.md): the twelve runs, one after
# the other; neuralcol's default (experiment=paper_scape_neuralcol), the paper's configuration (experiment=paper_scape
# method=active_paper) and its two baselines at three sizes (method=supv_bd, method=supv; detector.n_aug=175000
# detector.max_rounds=2), seeds 0-2; then the registered variant (L_b averaged over the batch) into a folder of its own,
# so that the report does not pool it with active_paper. Afterwards: research/paper_scale/final_tables.sh.
# Each run takes hours to days on a CPU. Rerun the same command to go on: a finished run (metrics.json) is skipped, an
# unfinished one resumes in its directory. Runs: $NEURALCOL_RUNS/paper_scale[_side]/<name> (default
# $HOME/neuralcol-runs); cache: $NEURALCOL_CACHE (default $HOME/neuralcol-cache).
#   research/paper_scale/runs.sh [0|1|2 ...]   (seeds, default all three; the variant runs after seed 0)
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${NEURALCOL_CACHE:-$HOME/neuralcol-cache}"
OUT="${NEURALCOL_RUNS:-$HOME/neuralcol-runs}/paper_scale"
source research/run_once.sh
B3=(detector.n_aug=175000 detector.max_rounds=2)  # the baselines at 2e5, 3.75e5 and 5.5e5 samples
seeds=("$@")
[ ${#seeds[@]} -gt 0 ] || seeds=(0 1 2)
for s in "${seeds[@]}"; do
  case $s in 0|1|2) ;; *) echo "runs.sh: unknown seed '$s'; use 0, 1 or 2" >&2; exit 2 ;; esac
  run_once "$OUT" "neuralcol_s$s" experiment=paper_scape_neuralcol seed=$s
  run_once "$OUT" "paper_active_s$s" experiment=paper_scape method=active_paper seed=$s
  run_once "$OUT" "paper_supv_bd_s$s" experiment=paper_scape method=supv_bd seed=$s "${B3[@]}"
  run_once "$OUT" "paper_supv_s$s" experiment=paper_scape method=supv seed=$s "${B3[@]}"
  if [ "$s" = 0 ]; then
    run_once "${OUT}_side" paper_active_bdbatch_s0 experiment=paper_scape method=active_paper seed=0 \
      detector.loss.boundary_reduction=batch
  fi
done
