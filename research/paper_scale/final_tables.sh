#!/usr/bin/env bash
# Every table and chart of the paper-scale Table 3 (docs/studies/scape_paper_scale.md) from the finished runs of
# research/paper_scale/runs.sh, in one command (rerun it as runs finish; what exists is kept): the report (Table 3 at
# logit 0 beside the paper's, curves of Figs. 3-4), the gradient-boosted reference per run, the gap's explanation
# (train against test, the curve's slope, the trees) and the handler's success per round (Fig. 5, from each round's
# saved detector, HANDLER_INPUTS colliding test codes). Runs: $NEURALCOL_RUNS/paper_scale (default $HOME/neuralcol-runs);
# outputs: outputs/paper_scale/.
#   research/paper_scale/final_tables.sh [HANDLER_INPUTS (default 1000)]
# The trees (about 20-40 min a run on one core) run for the runs whose name matches GBT_RUNS (a shell pattern,
# default '*_s0': one reference per method; GBT_RUNS='*' for every seed); their peak memory goes to gbt_NAME.time.
# Memory: the trees on a run over code and mesh (4.5e5 rows x 1452 pair features) peak at 14.5 GB; on a 24 GB machine
# run them when no training runs.
set -e
cd "$(dirname "$0")/../.."
source .venv/bin/activate
export PYTHONPATH=. NEURALCOL_DATA="${NEURALCOL_DATA:-../shared/data}"
R="${NEURALCOL_RUNS:-$HOME/neuralcol-runs}/paper_scale"
P=outputs/paper_scale
O=$P/final
GBT_RUNS=${GBT_RUNS:-*_s0}
mkdir -p $O
runs=$(for d in $R/*/; do [ -f $d/metrics.json ] && echo ${d%/}; done)
[ -n "$runs" ] || { echo "no finished run in $R yet"; exit 1; }
python -m experiments.report $runs --out $O/report
for d in $runs; do
  g=$P/gbt_$(basename $d).json
  t=$P/gbt_$(basename $d).time
  case $(basename $d) in $GBT_RUNS) [ -f $g ] || /usr/bin/time -v python -m research.gbt_reference $d --out $g 2> $t \
    || { echo "the trees on $d failed: see $t"; exit 1; };; esac
done
python research/paper_scale/explain_gap.py $runs --gbt $(ls $P/gbt_*.json) \
  --out $O/explain.json | tee $O/explain.md
for d in $runs; do  # one run a call, kept: a rerun measures only the runs finished since
  h=$P/handling_curve_$(basename $d).json
  [ -f $h ] || python research/paper_scale/handling_curve.py $d --inputs ${1:-1000} --out $h
done
python research/paper_scale/handling_curve.py --from-json $(for d in $runs; do echo $P/handling_curve_$(basename $d).json; done) \
  --out $O/handling_curve.json --plot $O/fig5.png | tee $O/handling_curve.md
