"""Metrics of a collision detector against exact labels (positive = self-colliding)."""

from __future__ import annotations

import numpy as np


def detection_metrics(predicted: np.ndarray, actual: np.ndarray) -> dict[str, float]:
    """Confusion-matrix metrics of boolean predictions.

    Args:
        predicted: (N,) bool, the detector says "collides".
        actual: (N,) bool, the exact label.

    Returns:
        accuracy; fnr = FN / (TP + FN) (colliding meshes predicted free); fpr = FP / (FP + TN);
        balanced_accuracy = 1 - (fnr + fpr) / 2; base_rate = fraction colliding; majority_accuracy (the
        accuracy of always answering the majority class); n. Rates of an empty class are NaN.
    """
    p = np.asarray(predicted, bool)
    a = np.asarray(actual, bool)
    if p.shape != a.shape or p.ndim != 1:
        raise ValueError(f"predicted {p.shape} and actual {a.shape} must be equal 1-D shapes")
    n = len(a)
    if n == 0:
        raise ValueError("detection_metrics: no samples")
    tp, fn = int((p & a).sum()), int((~p & a).sum())
    fp, tn = int((p & ~a).sum()), int((~p & ~a).sum())
    fnr = fn / (tp + fn) if tp + fn else float("nan")
    fpr = fp / (fp + tn) if fp + tn else float("nan")
    base = (tp + fn) / n
    return {"accuracy": (tp + tn) / n, "fnr": fnr, "fpr": fpr, "balanced_accuracy": 1.0 - (fnr + fpr) / 2,
            "base_rate": base, "majority_accuracy": max(base, 1.0 - base), "n": n}


def fnr_threshold(logits: np.ndarray, collides: np.ndarray, target: float) -> float:
    """The largest logit threshold ``t`` at which ``logit > t`` misses at most ``target`` of the colliding rows:
    with k = floor(target * n_colliding), halfway between the colliding rows' k-th and (k+1)-th smallest logits
    (k = 0: just below the smallest). The operating point of a detector set on a calibration set (issue 41).

    Raises:
        ValueError: ``target`` outside [0, 1) or no colliding row.
    """
    if not 0.0 <= float(target) < 1.0:
        raise ValueError(f"target FNR {target} must lie in [0, 1)")
    pos = np.sort(np.asarray(logits, np.float64)[np.asarray(collides, bool)])
    if len(pos) == 0:
        raise ValueError("no colliding row: the FNR of a threshold is undefined")
    k = int(np.floor(float(target) * len(pos) + 1e-9))
    if k == 0:
        return float(pos[0] - 1e-3 * max(1.0, abs(pos[0])))
    return float(0.5 * (pos[k - 1] + pos[k]))
