"""Where a finished run's decision threshold would land under each ``detector.operating_set`` rule, offline:

    python -m research.operating_rerun RUN_DIR [RUN_DIR ...] [--target 0.1] [--out FILE]

For each run: its final detector's logits on D_c's realistic validation rows (the rows ``operating_set: realistic``
reads; the detector over code and mesh on each row's own stored features) and on the cascade's calibration codes
(``cascade.npz``: the same detector's logits, saved by the run), then the threshold each rule picks there
(``realistic``, ``calibration``, ``both``: the mean of the two FNRs, :func:`neuralcol.metrics.detection.
mean_fnr_threshold`) and what the run's own test sets say at it: U(Z) (``test_predictions.npz``) and the realistic
test meshes' clear cases (``realistic_predictions.npz``): accuracy, majority, FNR, skill ``(acc - maj) / (1 - maj)``.
Every logit a run saved already has its operating threshold folded in, so thresholds are relative to it (the run's
own rule lands at ~0). Used for the operating-point rule registered in docs/studies/operating_set.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from neuralcol.api.run import load_run
from neuralcol.metrics.detection import detection_metrics
from neuralcol.operating import fnr_threshold, mean_fnr_threshold
from neuralcol.samples.store import CollisionStore, Origin

RULES = ("realistic", "calibration", "both")


def _score(logit: np.ndarray, y: np.ndarray, t: float) -> dict:
    m = detection_metrics(logit > t, y)
    maj = m["majority_accuracy"]
    return {"accuracy": m["accuracy"], "majority": maj, "fnr": m["fnr"],
            "skill": (m["accuracy"] - maj) / (1.0 - maj) if maj < 1 else float("nan")}


def realistic_validation_logits(run) -> tuple[np.ndarray, np.ndarray]:
    """The final detector's logits (N,) and exact labels (N,) on D_c's realistic validation rows."""
    store = CollisionStore(run.run_dir / "dc.h5", run.space.dim, run.space.n_parts, None)
    try:
        rows = store.read_rows((store.column("origin") == Origin.REALISTIC) & store.split_mask())
    finally:
        store.close()
    if rows.geometry is None or len(rows.z) == 0:
        raise SystemExit(f"{run.run_dir}: no realistic validation rows in dc.h5 (a detector over code and mesh with "
                         "detector.geometry.realistic_rows=true has them)")
    net = run.detector.eval()
    with torch.no_grad():
        logit = net(torch.as_tensor(rows.z), torch.as_tensor(rows.geometry)).logit.numpy()
    return logit.astype(np.float64), np.asarray(rows.collides, bool)


def evaluate(run_dir: Path, target: float) -> dict:
    """The thresholds of every rule on one run and its test sets' scores at them."""
    run = load_run(run_dir)
    real_logit, real_y = realistic_validation_logits(run)
    with np.load(run_dir / "cascade.npz") as z:
        cal_logit, cal_y = z["logit"].astype(np.float64), z["collides"].astype(bool)
    with np.load(run_dir / "test_predictions.npz") as z:
        test_logit, test_y = z["logit"].astype(np.float64), z["collides"].astype(bool)
    with np.load(run_dir / "realistic_predictions.npz") as z:
        clear = z["clear"].astype(bool) & np.isfinite(z["pd"])
        rt_logit, rt_y = z["logit"][clear].astype(np.float64), (z["pd"][clear] > 0)
    thresholds = {"realistic": fnr_threshold(real_logit, real_y, target),
                  "calibration": fnr_threshold(cal_logit, cal_y, target),
                  "both": mean_fnr_threshold([(real_logit, real_y), (cal_logit, cal_y)], target)}
    out = {"run": str(run_dir), "n_realistic_validation": int(len(real_y)), "n_calibration": int(len(cal_y)),
           "recorded_threshold": json.loads((run_dir / "metrics.json").read_text())["detector"]
           .get("operating_point", {}).get("threshold"), "rules": {}}
    for rule, t in thresholds.items():
        out["rules"][rule] = {"threshold": t, "uz": _score(test_logit, test_y, t),
                              "realistic": _score(rt_logit, rt_y, t),
                              "fnr_realistic_validation": float(np.mean(real_logit[real_y] <= t)),
                              "fnr_calibration": float(np.mean(cal_logit[cal_y] <= t))}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m research.operating_rerun", description=__doc__.splitlines()[0])
    parser.add_argument("run_dirs", type=Path, nargs="+")
    parser.add_argument("--target", type=float, default=0.1, help="the operating FNR (detector.operating_fnr)")
    parser.add_argument("--out", type=Path, default=None, help="write every run's block as JSON")
    args = parser.parse_args(argv)
    blocks = []
    print("run | rule | t (relative) | U(Z) acc / FNR / skill | realistic acc / FNR / skill")
    for rd in args.run_dirs:
        b = evaluate(rd, args.target)
        blocks.append(b)
        for rule, r in b["rules"].items():
            u, re_ = r["uz"], r["realistic"]
            print(f"{rd.name} | {rule} | {r['threshold']:+.2f} | {u['accuracy']:.3f} / {u['fnr']:.3f} / "
                  f"{u['skill']:.3f} | {re_['accuracy']:.3f} / {re_['fnr']:.3f} / {re_['skill']:.3f}", flush=True)
    if args.out:
        args.out.write_text(json.dumps(blocks, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
