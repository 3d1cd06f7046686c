# Sourced by the study scripts (research/*/...sh), from the repository root with CACHE set:
#   run_once OUT NAME OVERRIDE...
# runs `python -m experiments.run OVERRIDE...` once into OUT/NAME (its log: OUT/NAME.log). A finished run
# (metrics.json) is skipped and an unfinished one resumes in its directory, so a study script can be rerun to go on.
run_once() {
  local out=$1 name=$2
  shift 2
  local dir="$out/$name"
  mkdir -p "$out"
  if [ -f "$dir/metrics.json" ]; then echo "$name: done"; return; fi
  echo "$name: $(date -u +%H:%M) start"
  NEURALCOL_DATA=../shared/data NEURALCOL_PROGRESS=lines .venv/bin/python -m experiments.run "$@" \
    paths.cache_dir="$CACHE" hydra.run.dir="$dir" > "$out/$name.log" 2>&1
  echo "$name: $(date -u +%H:%M) end"
}
