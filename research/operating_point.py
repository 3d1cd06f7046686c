"""Finished runs scored at another operating point, from their saved predictions (no retraining).

For each run directory: the detector's logits on the cascade's calibration set (``cascade.npz``), on the U(Z) test
set (``test_predictions.npz``) and on the realistic set (``realistic_predictions.npz``, clear cases). The threshold
whose calibration FNR is at most ``--fnr`` (:func:`~neuralcol.operating.fnr_threshold`, what
``detector.operating_fnr`` folds into a detector) is applied to the test sets, beside logit 0. It separates the
operating point's share of a gain from the inputs' share (rule v2, docs/studies/one_detector.md).

    python -m research.operating_point outputs/issue40b/hand_s0 outputs/one_detector/hand_cm_s1 --fnr 0.1 [--json OUT]

A run whose detector already has an operating point (``detector.operating_point`` in its metrics) is scored at
its own threshold (its logits are shifted already): the row says so.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from neuralcol.metrics.detection import detection_metrics
from neuralcol.operating import fnr_threshold


def score(run_dir: Path, target: float) -> dict:
    from neuralcol.stages.cascade import load_calibration

    metrics = json.loads((run_dir / "metrics.json").read_text())
    cl, cy = load_calibration(run_dir / "cascade.npz")
    own = (metrics["detector"].get("operating_point") or {}).get("operating_fnr")
    t = 0.0 if own is not None else fnr_threshold(cl, cy, target)
    with np.load(run_dir / "test_predictions.npz") as f:
        tl, ty = f["logit"].astype(np.float64), f["collides"].astype(bool)
    with np.load(run_dir / "realistic_predictions.npz") as f:
        clear = f["clear"].astype(bool)
        rl, ry = f["logit"][clear].astype(np.float64), np.nan_to_num(f["pd"][clear]) > 0
    out = {"run": str(run_dir), "inputs": metrics["detector"].get("inputs", "latent"), "own_operating_fnr": own,
           "points": {}}
    for name, thr in (("logit_0", 0.0), (f"calibration_fnr_{target:g}", t)):
        if own is not None and name != "logit_0":
            continue
        out["points"][name] = {"threshold": thr, "uz": detection_metrics(tl > thr, ty),
                               "realistic": detection_metrics(rl > thr, ry)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--fnr", type=float, default=0.1)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    rows = [score(r, a.fnr) for r in a.runs]
    print(f"{'run':44s} {'inputs':14s} {'point':22s} {'thr':>6s}  U(Z) acc / FNR   realistic acc / FNR")
    for r in rows:
        for name, p in r["points"].items():
            label = name if r["own_operating_fnr"] is None else f"own (FNR {r['own_operating_fnr']:g})"
            u, q = p["uz"], p["realistic"]
            print(f"{r['run']:44s} {r['inputs']:14s} {label:22s} {p['threshold']:+6.2f}  {u['accuracy']:.3f} / "
                  f"{u['fnr']:.3f}    {q['accuracy']:.3f} / {q['fnr']:.3f}")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
