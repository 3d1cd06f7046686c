#!/bin/bash
# issue 42: every table and chart of the paper-scale Table 3 from the finished runs, in one command (rerun it as runs
# finish; what exists is kept): the report (Table 3 at logit 0 beside the paper's, curves of Figs. 3-4), the
# gradient-boosted reference per run, the gap's explanation (train against test, the curve's slope, the trees) and the
# handler's success per round (Fig. 5, from each round's saved detector, --inputs colliding test codes).
# Usage (from /work/main): research/issue42/final_tables.sh [HANDLER_INPUTS (default 1000)]
# The trees (about 20-40 min a run on one core) run for the runs whose name matches GBT_RUNS (a shell pattern,
# default '*_s0': one reference per method; GBT_RUNS='*' for every seed); their peak memory goes to gbt_NAME.time.
# Memory: the trees on a run over code and mesh (4.5e5 rows x 1452 pair features) peak at 14.5 GB (stop 60); pause or
# let the queues finish first on a 24 GB machine.
set -e
cd /work/main
source .venv/bin/activate
export PYTHONPATH=. NEURALCOL_DATA=/work/shared/data
R=$HOME/neuralcol-runs/issue42
O=outputs/issue42/final
GBT_RUNS=${GBT_RUNS:-*_s0}
mkdir -p $O
runs=$(for d in $R/*/; do [ -f $d/metrics.json ] && echo ${d%/}; done)
[ -n "$runs" ] || { echo "no finished run in $R yet"; exit 1; }
python -m experiments.report $runs --out $O/report
for d in $runs; do
  g=outputs/issue42/gbt_$(basename $d).json
  t=outputs/issue42/gbt_$(basename $d).time
  case $(basename $d) in $GBT_RUNS) [ -f $g ] || /usr/bin/time -v python -m research.gbt_reference $d --out $g 2> $t \
    || { echo "the trees on $d failed: see $t"; exit 1; };; esac
done
python research/issue42/explain_gap.py $runs --gbt $(ls outputs/issue42/gbt_*.json) \
  --out $O/explain.json | tee $O/explain.md
for d in $runs; do  # one run a call, kept: a rerun measures only the runs finished since
  h=outputs/issue42/handling_curve_$(basename $d).json
  [ -f $h ] || python research/issue42/handling_curve.py $d --inputs ${1:-1000} --out $h
done
python research/issue42/handling_curve.py --from-json $(for d in $runs; do echo outputs/issue42/handling_curve_$(basename $d).json; done) \
  --out $O/handling_curve.json --plot $O/fig5.png | tee $O/handling_curve.md
