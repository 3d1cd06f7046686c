#!/usr/bin/env bash
# Runs of the detector-transfer study (docs/studies/detector_transfer.md): one variant of the detector's training
# rows per name, on make run (proc_hand), SCAPE's, proc_cloth's and anny_body's CPU presets, into
# outputs/detector_transfer/<variant>/<set>_s<seed>. Rerun the same command to go on (research/run_once.sh).
# Cache: $NEURALCOL_CACHE (default $HOME/neuralcol-cache).
#   research/detector_transfer/runs.sh VARIANT "SEEDS" [make_run|scape|proc_cloth|anny_body ...]
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${NEURALCOL_CACHE:-$HOME/neuralcol-cache}"
variant=${1:?"usage: research/detector_transfer/runs.sh VARIANT \"SEEDS\" [data set ...]"}
seeds=${2:-"0 1 2"}
shift 2 || shift $#
source research/run_once.sh
source research/detector_transfer/variants.sh
[ -n "${VARIANTS[$variant]+x}" ] || { echo "runs.sh: unknown variant '$variant'" >&2; exit 2; }
OUT=outputs/detector_transfer/$variant
sets=("$@")
[ ${#sets[@]} -gt 0 ] || sets=(make_run scape proc_cloth anny_body)
run_presets "$OUT" "$seeds" "${sets[*]}" "${VARIANTS[$variant]}" "${BODY_VARIANTS[$variant]:-${VARIANTS[$variant]}}"
