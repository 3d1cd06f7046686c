"""Compare methods across runs: ``python -m experiments.report RUN_OR_SWEEP_DIR... [--out DIR]``.

Reads every ``metrics.json`` below the given directories (a Hydra multirun directory, single run directories,
or any mix), groups the runs by data set and method (seeds are pooled: mean ± std), and writes into ``--out``
(default: the first directory):

* ``report.md`` and ``table3.csv``: the paper's Table 3 layout per data set — final data set size, accuracy
  and false negative rate of each method at logit 0 (and, for runs with an operating point, at it, in rows of their
  own), the paper's own figures beside for the data sets of its Table 3, the equivalent data set size (the size
  supv_bd needs to reach the method's final accuracy, linearly interpolated on supv_bd's mean accuracy curve, as in
  the paper), and the detector's parameter count; then accuracy and FNR at every size, the collision handler's
  exact results, the speed figures and the stability checks;
* ``accuracy.png``, ``fnr.png``, ``handling.png``: accuracy, FNR and handling success (runs with
  ``handler.eval_every_round=true``) vs data set size, mean ± std bands over seeds (paper Figs. 3-5);
* ``speed.png``: accuracy against cumulative labeling + training time per method, and neural vs exact
  detection time per sample (from ``bench/results.json`` when present);
* ``stability.png``: the spread of accuracy across seeds per method and size, and handling success vs size
  per seed (is it monotone?);
* ``projection.png`` and a table in ``report.md`` (active runs): where the projected samples of each round
  landed: share within eps and 2 eps of the true boundary, next to the round's uniform samples, and how far
  each latent level moved (docs/diagnosis.md);
* ``pareto.png``, ``cost.png``, ``failures.png`` and their tables (:mod:`experiments.reporting`): accuracy
  against detector size and CPU inference time with the Pareto front (and the choice of a ``model_size.json``
  in a given directory marked), accuracy against cumulative seconds per method, and where each method fails:
  detector accuracy by exact-PD bin and recall by sub-domain of the test rows, handler success by PD bin of its
  inputs, mean ± std over seeds;
* ``speed_accuracy_<data set>.png`` and a table (runs with ``metrics["speed_accuracy"]``): samples per
  second of every method (exact labeler, MeshLab, FCL, the detectors, the cascade's targets) against accuracy and
  FNR, medians over the runs;
* ``report.json``: the aggregated numbers.

The work is done by the :mod:`experiments.reporting` package; this module is its command line.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from experiments.reporting.build import write_report
from neuralcol.utils.cli import report_user_errors


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.report", description=__doc__.splitlines()[0])
    parser.add_argument("dirs", nargs="+", type=Path, help="run or multirun directories")
    parser.add_argument("--out", type=Path, default=None, help="output directory (default: the first DIR)")
    parser.add_argument("--bench", type=Path, default=None,
                        help="benchmark results for the detection-time panel (default: bench/results.json)")
    args = parser.parse_args(argv)
    out = args.out or args.dirs[0]
    written = write_report(args.dirs, out, args.bench)
    print(written.text)
    for note in written.notes:
        print(f"left out: {note}", file=sys.stderr)
    print(f"{written.n_runs} runs; wrote {out / 'report.md'}, table3.csv, report.json, {', '.join(written.charts)}",
          file=sys.stderr)


if __name__ == "__main__":
    main()
