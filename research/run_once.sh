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

# run_presets OUT "SEEDS" "SETS" "GRID" "BODY_GRID": run_once for every data set of SETS (make_run, scape, proc_cloth,
# anny_body: make run and the CPU presets) and seed, into OUT/<set>_s<seed>, with the overrides GRID (space-separated;
# BODY_GRID for anny_body).
run_presets() {
  local out=$1 seeds=$2 sets=$3 grid=$4 body=$5 d s preset extra
  for d in $sets; do
    case $d in
      make_run) preset=() ; extra=$grid ;;
      scape) preset=(experiment=cpu_scape) ; extra=$grid ;;
      proc_cloth) preset=(experiment=cpu_proc_cloth) ; extra=$grid ;;
      anny_body) preset=(experiment=cpu_anny_body) ; extra=$body ;;
      *) echo "run_presets: unknown data set '$d'; use make_run, scape, proc_cloth or anny_body" >&2; return 2 ;;
    esac
    for s in $seeds; do
      # shellcheck disable=SC2086  # the overrides are space-separated words
      run_once "$out" "${d}_s$s" "${preset[@]}" seed=$s $extra
    done
  done
}
