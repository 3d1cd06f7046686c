"""An operating threshold rule read against its criteria (docs/studies/operating_threshold.md), from its deciding
runs (``research/threshold/rule_runs.sh v1|v2``):

    .venv/bin/python -m research.threshold.rule_summary [--dir outputs/threshold/rule_v2] [--out FILE]

Per run: the threshold the rule set (on the realistic calibration set apart from D_c) and today's rule's on the same
run (FNR <= target on D_c's realistic validation rows, recomputed offline from the run's detector), and what each
gives on the run's grown realistic test set (clear cases): FNR with its exact 95 % interval, accuracy. Per data set:
the thresholds' std across seeds. Then criteria (a)-(c) of the rule, each met or missed.

What of the thresholds' spread the calibration set's size explains: per run, the std of the rule's threshold over
bootstrap draws of as many colliding meshes as its calibration set holds, taken from its test set's colliding logits
(the test set is drawn like the calibration set); what this leaves of the across-seed std is the networks' own spread.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SETS = ("make_run", "scape", "proc_cloth", "anny_body")


def score(logit: np.ndarray, y: np.ndarray, t: float) -> dict:
    from neuralcol.metrics.detection import detection_metrics, fnr_interval

    m = detection_metrics(logit > t, y)
    return {"fnr": m["fnr"], "fnr_ci95": fnr_interval(logit > t, y), "accuracy": m["accuracy"],
            "n_colliding": int(y.sum())}


def sampling_std(pos_logits: np.ndarray, n: int, target: float, draws: int = 2000, seed: int = 0) -> float:
    """Std of :func:`~neuralcol.operating.fnr_threshold` over ``draws`` bootstrap sets of ``n`` colliding
    logits drawn from ``pos_logits``: the threshold's spread from the calibration set's size alone."""
    from neuralcol.operating import fnr_threshold

    rng = np.random.default_rng(seed)
    ones = np.ones(n, bool)
    return float(np.std([fnr_threshold(rng.choice(pos_logits, n), ones, target) for _ in range(draws)], ddof=1))


def read_run(run_dir: Path, target: float) -> dict:
    """Both rules' thresholds and test-set figures for one finished run (thresholds absolute: before folding)."""
    from neuralcol.api import load_run
    from neuralcol.operating import fnr_threshold
    from research.operating_rerun import realistic_validation_logits

    op = json.loads((run_dir / "metrics.json").read_text())["detector"]["operating_point"]
    with np.load(run_dir / "realistic_predictions.npz") as z:
        clear = z["clear"].astype(bool) & np.isfinite(z["pd"])
        logit, y = z["logit"][clear].astype(np.float64), z["pd"][clear] > 0
    val_logit, val_y = realistic_validation_logits(load_run(run_dir))
    t_today = fnr_threshold(val_logit, val_y, target)  # relative to the folded threshold
    noise = sampling_std(logit[y], int(op["calibration"]["n_colliding"]), target)
    return {"run": run_dir.name, "rule": {"threshold": op["threshold"], **score(logit, y, 0.0),
                                          "calibration": op["calibration"], "sampling_std": noise},
            "today": {"threshold": op["threshold"] + t_today, **score(logit, y, t_today),
                      "calibration_colliding": int(val_y.sum())}}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m research.threshold.rule_summary")
    ap.add_argument("--dir", type=Path, default=ROOT / "outputs" / "threshold" / "rule_v2")
    ap.add_argument("--target", type=float, default=0.1)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    out = {"runs": {}, "sets": {}}
    print("| run | threshold: rule / today | test FNR at the rule [95 %] | at today's | accuracy: rule / today |")
    print("|---|---:|---:|---:|---:|")
    for name in SETS:
        rows = []
        for s in range(3):
            d = a.dir / f"{name}_s{s}"
            if not (d / "metrics.json").is_file():
                continue
            r = read_run(d, a.target)
            rows.append(r)
            ru, to = r["rule"], r["today"]
            ci = ru["fnr_ci95"] or (float("nan"), float("nan"))
            print(f"| {d.name} | {ru['threshold']:+.3f} / {to['threshold']:+.3f} | {ru['fnr']:.3f} [{ci[0]:.3f}, "
                  f"{ci[1]:.3f}] of {ru['n_colliding']} | {to['fnr']:.3f} | {ru['accuracy']:.3f} / "
                  f"{to['accuracy']:.3f} |")
        out["runs"][name] = rows
        if rows:
            th = np.array([r["rule"]["threshold"] for r in rows])
            th0 = np.array([r["today"]["threshold"] for r in rows])
            a_ok = [abs(r["rule"]["fnr"] - a.target) <= 0.02 if r["rule"]["n_colliding"] >= 800 else
                    (r["rule"]["fnr_ci95"][0] <= a.target <= r["rule"]["fnr_ci95"][1]) for r in rows]
            out["sets"][name] = {
                "seeds": len(rows), "threshold_std": float(th.std(ddof=1)) if len(rows) > 1 else None,
                "threshold_std_today": float(th0.std(ddof=1)) if len(rows) > 1 else None,
                "sampling_std": float(np.sqrt(np.mean([r["rule"]["sampling_std"] ** 2 for r in rows]))),
                "a_fnr_on_target": a_ok,
                "accuracy_change": float(np.mean([r["rule"]["accuracy"] - r["today"]["accuracy"] for r in rows]))}
    print()
    for name, s in out["sets"].items():
        std = "-" if s["threshold_std"] is None else f"{s['threshold_std']:.2f}"
        std0 = "-" if s["threshold_std_today"] is None else f"{s['threshold_std_today']:.2f}"
        print(f"{name}: {s['seeds']} seeds; (a) FNR on target {sum(s['a_fnr_on_target'])}/{s['seeds']}; (b) threshold "
              f"std {std} (today's rule {std0}; of it the calibration set's size {s['sampling_std']:.2f}); "
              f"(c) accuracy {100 * s['accuracy_change']:+.2f} points")
    if a.out:
        a.out.write_text(json.dumps(out, indent=1, default=float))
    return out


if __name__ == "__main__":
    main()
