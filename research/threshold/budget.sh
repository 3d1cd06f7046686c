#!/usr/bin/env bash
# Criterion (d) of the operating threshold's rule v1 (docs/studies/operating_threshold.md):
# `make run` (seed 0) with rule v1's settings from an empty cache, wall time and peak memory by /usr/bin/time -v.
# Run it alone on the machine: anything else running beside it inflates the figure. The numba kernels' own cache
# (neuralcol/collision/kernels/__pycache__) stays warm, as after `make install`'s first run.
# Output: outputs/threshold/budget_<label>/ (the run), budget_<label>.time (time -v), budget_<label>.log.
#   research/threshold/budget.sh [rule_v1|rule_v2|defaults] [EXTRA OVERRIDE...]
set -euo pipefail
cd "$(dirname "$0")/../.."
label=${1:-rule_v1}
shift || true
out=outputs/threshold
cache=$(mktemp -d "${TMPDIR:-/tmp}/neuralcol-budget.XXXXXX")
trap 'rm -rf "$cache"' EXIT
mkdir -p "$out"
rm -rf "$out/budget_$label"
source research/threshold/rules.sh
case $label in
  rule_v1) RULE=("${RULE_v1[@]}") ;;
  rule_v2) RULE=("${RULE_v2[@]}") ;;
  defaults) RULE=() ;;
  *) echo "budget.sh: unknown rule '$label'; use rule_v1, rule_v2 or defaults" >&2; exit 2 ;;
esac
NEURALCOL_DATA=../shared/data NEURALCOL_PROGRESS=lines /usr/bin/time -v -o "$out/budget_$label.time" \
  .venv/bin/python -m experiments.run seed=0 "${RULE[@]}" "$@" paths.cache_dir="$cache" \
  hydra.run.dir="$out/budget_$label" > "$out/budget_$label.log" 2>&1
grep -E "Elapsed|Maximum resident" "$out/budget_$label.time"
.venv/bin/python -c "import json,sys; s=json.load(open(sys.argv[1]))['sittings']; print(s['minutes'], 'min;', {k: round(v) for k, v in s['stage_seconds'].items()})" "$out/budget_$label/metrics.json"
