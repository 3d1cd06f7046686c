"""The certified cascade of finished runs under every accuracy floor, from their saved arrays (no labeling):

    python -m experiments.cascade_table RUN_DIR [RUN_DIR ...] [--targets 0.01 0.02 0.05]

Per run and floor (``pointwise``, ``detector``) and target FNR: the band chosen on the run's calibration set
(``cascade.npz``), FNR, accuracy and exact share on its U(Z) test set (``test_predictions.npz``, the exact labels
standing for the exact calls), and the throughput priced with the run's own timings (``metrics.json`` →
``cascade.exact_ms_per_sample`` and ``detector_us_per_sample``): ``1 / (t_detector + share * t_exact)``, and that
against the exact path alone. Prints a markdown table (docs/cascade.md, "Measurements").
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from neuralcol.errors import UserInputError
from neuralcol.metrics.cascade import DETECTOR, POINTWISE, cascade_scores, choose_band
from neuralcol.rundir import RunDir
from neuralcol.utils.cli import report_user_errors


def cascade_rows(run_dir: Path, targets, floors=(POINTWISE, DETECTOR)) -> list[dict]:
    """One row per (floor, target) of a finished run with a cascade (see the module docstring)."""
    rd = RunDir(run_dir)
    missing = [p for p in (rd.cascade, rd.test_predictions, rd.metrics) if not p.is_file()]
    if missing:
        raise UserInputError(f"{run_dir}: no {missing[0].name}; run experiments.run with detector.cascade.enabled=true "
                             "to make one")
    cal, test = np.load(rd.cascade), np.load(rd.test_predictions)
    casc = json.loads(rd.metrics.read_text()).get("cascade") or {}
    t_exact = float(casc.get("exact_ms_per_sample", np.nan)) * 1e-3
    t_det = float(casc.get("detector_us_per_sample", np.nan)) * 1e-6
    alone = float(((test["logit"] > 0) == test["collides"].astype(bool)).mean())
    rows = []
    for floor in floors:
        for t in targets:
            band = choose_band(cal["logit"], cal["collides"], float(t), floor)
            s = cascade_scores(test["logit"], test["collides"], band)
            sps = 1.0 / (t_det + s["exact_share"] * t_exact)
            rows.append({"run": str(run_dir), "floor": floor, "target_fnr": float(t), "lo": float(band.lo),
                         "hi": float(band.hi), **s, "detector_alone_accuracy": alone, "samples_per_s": sps,
                         "vs_exact": sps * t_exact})
    return rows


@report_user_errors
def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--targets", nargs="+", type=float, default=[0.01, 0.02, 0.05])
    args = parser.parse_args(argv)
    print("| run | floor | target FNR | band [lo, hi) | test FNR | accuracy (alone) | exact share | samples/s "
          "| vs exact |")
    print("| --- | --- | ---: | --- | ---: | ---: | ---: | ---: | ---: |")
    for run in args.runs:
        for r in cascade_rows(run, args.targets):
            print(f"| {run} | {r['floor']} | {r['target_fnr']:g} | [{r['lo']:.2f}, {r['hi']:.2f}) | {r['fnr']:.4f} "
                  f"| {r['accuracy']:.4f} ({r['detector_alone_accuracy']:.4f}) | {r['exact_share']:.1%} "
                  f"| {r['samples_per_s']:.0f} | {r['vs_exact']:.1f}x |")


if __name__ == "__main__":
    main()
