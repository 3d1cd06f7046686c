# Sourced by research/detector_transfer/runs.sh: each variant's overrides (space-separated), for the 2k-vertex
# presets (VARIANTS) and, where it differs, anny_body (BODY_VARIANTS). base: today's defaults.
declare -A VARIANTS BODY_VARIANTS
VARIANTS[base]=""
