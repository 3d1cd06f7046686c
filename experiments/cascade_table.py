"""The certified cascade of finished runs under every accuracy floor, from their saved arrays (no labeling):

    python -m experiments.cascade_table RUN_DIR [RUN_DIR ...] [--targets 0.01 0.02 0.05]

Per run and floor (``pointwise``, ``detector``) and target FNR: the band chosen on the run's calibration set
(``cascade.npz``), FNR, accuracy and exact share on its U(Z) test set (``test_predictions.npz``, the exact labels
standing for the exact calls), and the throughput priced with the run's own timings (``metrics.json`` →
``cascade.exact_ms_per_sample`` and ``detector_us_per_sample``): ``1 / (t_detector + share * t_exact)``, and that
against the exact path alone. Prints a markdown table (docs/studies/cascade_band.md).

``--chart PNG --floor pointwise`` (one run): the run's speed/accuracy chart (``metrics.json`` →
``speed_accuracy``) drawn again with the cascade of that floor, priced with the speed stage's timings, e.g. for a
run made before the floor's default changed (docs/studies/one_detector_speed.md).
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


def cascade_rows(run_dir: Path, targets, floors=(POINTWISE, DETECTOR), confidence: float | None = None) -> list[dict]:
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
            band = choose_band(cal["logit"], cal["collides"], float(t), floor, confidence)
            s = cascade_scores(test["logit"], test["collides"], band)
            sps = 1.0 / (t_det + s["exact_share"] * t_exact)
            rows.append({"run": str(run_dir), "floor": floor, "confidence": confidence, "target_fnr": float(t),
                         "lo": float(band.lo), "hi": float(band.hi), **s, "detector_alone_accuracy": alone,
                         "samples_per_s": sps, "vs_exact": sps * t_exact})
    return rows


def redraw_chart(run_dir: Path, png: Path, targets, floor: str, title: str | None = None,
                 confidence: float | None = None) -> Path:
    """The run's speed/accuracy points with the cascade of ``floor`` (see the module docstring)."""
    from experiments.reporting.speed_accuracy import plot_speed_accuracy
    from neuralcol.stages.speed import CODE_AND_MESH, cascade_points

    sa = json.loads(RunDir(run_dir).metrics.read_text()).get("speed_accuracy")
    if not sa:
        raise UserInputError(f"{run_dir}: metrics.json has no speed_accuracy (speed_accuracy.enabled=false?)")
    sps = {(p["method"], p["variant"]): p["samples_per_s"] for p in sa["points"]}
    rows = cascade_rows(run_dir, targets, (floor,), confidence)
    cascade = {"targets": [{"target_fnr": r["target_fnr"], "samples_per_s": r["samples_per_s"],
                            "test": {k: r[k] for k in ("fnr", "accuracy", "exact_share", "n")}} for r in rows]}
    exact = sps.get(("exact", "verdict")) or sps.get(("exact", "label + PD"))  # the cascade's exact path: the verdict
    points = [p for p in sa["points"] if p["method"] != "cascade"]
    detector = sps.get(("latent detector", "float32 eager")) or sps.get((CODE_AND_MESH, "float32 eager"))
    points += cascade_points(cascade, exact, detector)
    png.parent.mkdir(parents=True, exist_ok=True)
    plot_speed_accuracy(points, png, title or f"{run_dir}: speed against accuracy (cascade: {floor} floor)")
    return png


@report_user_errors
def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--targets", nargs="+", type=float, default=[0.01, 0.02, 0.05])
    parser.add_argument("--chart", type=Path, default=None, help="redraw the run's speed/accuracy chart here")
    parser.add_argument("--floor", default=POINTWISE, choices=[POINTWISE, DETECTOR], help="the chart's cascade")
    parser.add_argument("--title", default=None, help="the chart's title")
    parser.add_argument("--confidence", type=float, default=None,
                        help="certify the FNR at this level (Clopper-Pearson; default: the calibration FNR alone)")
    args = parser.parse_args(argv)
    if args.chart is not None:
        redraw_chart(args.runs[0], args.chart, args.targets, args.floor, args.title, args.confidence)
    print("| run | floor | target FNR | band [lo, hi) | test FNR | accuracy (alone) | exact share | samples/s "
          "| vs exact |")
    print("| --- | --- | ---: | --- | ---: | ---: | ---: | ---: | ---: |")
    for run in args.runs:
        for r in cascade_rows(run, args.targets, confidence=args.confidence):
            print(f"| {run} | {r['floor']} | {r['target_fnr']:g} | [{r['lo']:.2f}, {r['hi']:.2f}) | {r['fnr']:.4f} "
                  f"| {r['accuracy']:.4f} ({r['detector_alone_accuracy']:.4f}) | {r['exact_share']:.1%} "
                  f"| {r['samples_per_s']:.0f} | {r['vs_exact']:.1f}x |")


if __name__ == "__main__":
    main()
