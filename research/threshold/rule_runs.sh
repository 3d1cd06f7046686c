#!/usr/bin/env bash
# The deciding runs of a registered operating threshold rule (docs/studies/operating_threshold.md): make run
# (proc_hand), SCAPE's, proc_cloth's and anny_body's CPU presets, seeds 0-2, each with the rule's overrides
# (research/threshold/rules.sh) into outputs/threshold/rule_<v>/. Today's rule on the same test sets is scored
# offline from the same runs:
#   .venv/bin/python -m research.threshold.rule_summary --dir outputs/threshold/rule_v2
# Rerun the same command to go on: a finished run (metrics.json) is skipped, an unfinished one resumes in its
# directory. Cache: $NEURALCOL_CACHE (default $HOME/neuralcol-cache).
#   research/threshold/rule_runs.sh v1|v2 [make_run|scape|proc_cloth|anny_body ...]   (default: all four, in order)
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${NEURALCOL_CACHE:-$HOME/neuralcol-cache}"
rule=${1:?"usage: research/threshold/rule_runs.sh v1|v2 [data set ...]"}
shift
source research/run_once.sh
source research/threshold/rules.sh
case $rule in
  v1) GRID=("${RULE_v1[@]}"); BODY=("${BODY_v1[@]}") ;;
  v2) GRID=("${RULE_v2[@]}"); BODY=("${BODY_v2[@]}") ;;
  *) echo "rule_runs.sh: unknown rule '$rule'; use v1 or v2" >&2; exit 2 ;;
esac
OUT=outputs/threshold/rule_$rule
sets=("$@")
[ ${#sets[@]} -gt 0 ] || sets=(make_run scape proc_cloth anny_body)
run_presets "$OUT" "0 1 2" "${sets[*]}" "${GRID[*]}" "${BODY[*]}"
