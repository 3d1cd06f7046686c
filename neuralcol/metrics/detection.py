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


def proportion_interval(k: int, n: int, level: float = 0.95) -> tuple[float, float] | None:
    """Two-sided Clopper-Pearson interval of a binomial proportion ``k / n`` at ``level`` (exact: it covers the true
    proportion with probability >= ``level`` for every n); None when ``n`` is 0. An FNR's interval is that of its
    missed colliding meshes among the colliding ones."""
    k, n = int(k), int(n)
    if not 0 <= k <= n or not 0.0 < float(level) < 1.0:
        raise ValueError(f"proportion_interval: need 0 <= k <= n and 0 < level < 1 (got k={k}, n={n}, level={level})")
    if n == 0:
        return None
    from scipy.stats import beta

    a = 1.0 - float(level)
    lo = 0.0 if k == 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def fnr_interval(predicted: np.ndarray, actual: np.ndarray, level: float = 0.95) -> tuple[float, float] | None:
    """:func:`proportion_interval` of the FNR of boolean predictions against exact labels (None: nothing collides)."""
    a = np.asarray(actual, bool)
    return proportion_interval(int((~np.asarray(predicted, bool) & a).sum()), int(a.sum()), level)


def detection_report(predicted: np.ndarray, actual: np.ndarray) -> dict:
    """:func:`detection_metrics` with what a report reads beside them: ``skill`` (the share of the majority class's
    errors avoided, (accuracy - majority) / (1 - majority); NaN when one class is all), ``n_colliding`` and the FNR's
    95 % Clopper-Pearson interval ``fnr_ci95`` (None when nothing collides). No rows: ``{"n": 0}``."""
    a = np.asarray(actual, bool)
    if len(a) == 0:
        return {"n": 0}
    m = detection_metrics(predicted, a)
    maj = m["majority_accuracy"]
    ci = fnr_interval(predicted, a)
    return {**m, "skill": float((m["accuracy"] - maj) / (1.0 - maj)) if maj < 1.0 else float("nan"),
            "n_colliding": int(a.sum()), "fnr_ci95": None if ci is None else list(ci)}
