"""Accuracy and FNR of the detector's verdict ``p > t`` as the decision threshold t moves
(docs/studies/decision_threshold.md; ``python -m research.threshold_tradeoff`` scores finished runs with it)."""

from __future__ import annotations

import numpy as np

THRESHOLDS = (0.5, 0.45, 0.4, 0.35, 0.3, 0.25)


def tradeoff(prob: np.ndarray, collides: np.ndarray, thresholds=THRESHOLDS) -> list[dict]:
    """Accuracy and FNR of ``prob > t`` against the labels, for each threshold t."""
    y = np.asarray(collides, bool)
    out = []
    for t in thresholds:
        pred = prob > t
        out.append({"threshold": float(t), "accuracy": float((pred == y).mean()),
                    "fnr": float((~pred & y).sum() / max(1, y.sum()))})
    return out
