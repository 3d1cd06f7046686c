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
GRID=("${VARIANTS[$variant]:-}")
[ -n "${VARIANTS[$variant]+x}" ] || { echo "runs.sh: unknown variant '$variant'" >&2; exit 2; }
read -r -a GRID <<< "${VARIANTS[$variant]}"
read -r -a BODYGRID <<< "${BODY_VARIANTS[$variant]:-${VARIANTS[$variant]}}"
OUT=outputs/detector_transfer/$variant
sets=("$@")
[ ${#sets[@]} -gt 0 ] || sets=(make_run scape proc_cloth anny_body)
for d in "${sets[@]}"; do
  for s in $seeds; do
    case $d in
      make_run) run_once "$OUT" "make_run_s$s" seed=$s "${GRID[@]}" ;;
      scape) run_once "$OUT" "scape_s$s" experiment=cpu_scape seed=$s "${GRID[@]}" ;;
      proc_cloth) run_once "$OUT" "proc_cloth_s$s" experiment=cpu_proc_cloth seed=$s "${GRID[@]}" ;;
      anny_body) run_once "$OUT" "anny_body_s$s" experiment=cpu_anny_body seed=$s "${BODYGRID[@]}" ;;
      *) echo "runs.sh: unknown data set '$d'" >&2; exit 2 ;;
    esac
  done
done
