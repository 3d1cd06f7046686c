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


def fnr_threshold(logits: np.ndarray, collides: np.ndarray, target: float) -> float:
    """The largest logit threshold ``t`` at which ``logit > t`` misses at most ``target`` of the colliding rows:
    with k = floor(target * n_colliding), halfway between the colliding rows' k-th and (k+1)-th smallest logits
    (k = 0: just below the smallest). The operating point of a detector set on a calibration set.

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


def mean_fnr_threshold(sets: list[tuple[np.ndarray, np.ndarray]], target: float) -> float:
    """The largest logit threshold ``t`` at which the **mean** over ``sets`` of each set's FNR (``logit > t`` missing
    its colliding rows) is at most ``target``: every set weighs the same whatever its size. One set: exactly
    :func:`fnr_threshold`. Used by ``detector.operating_set: both`` (realistic rows and calibration codes).

    Args:
        sets: ``[(logits (N_j,), collides (N_j,) bool), ...]``; a set without colliding rows is skipped.
        target: in [0, 1).

    Raises:
        ValueError: ``target`` outside [0, 1) or no colliding row in any set.
    """
    if not 0.0 <= float(target) < 1.0:
        raise ValueError(f"target FNR {target} must lie in [0, 1)")
    pos = [np.asarray(lg, np.float64)[np.asarray(y, bool)] for lg, y in sets]
    pos = [p for p in pos if len(p)]
    if not pos:
        raise ValueError("no colliding row: the FNR of a threshold is undefined")
    if len(pos) == 1:
        return fnr_threshold(pos[0], np.ones(len(pos[0]), bool), target)
    logit = np.concatenate(pos)
    weight = np.concatenate([np.full(len(p), 1.0 / (len(p) * len(pos))) for p in pos])
    order = np.argsort(logit, kind="stable")
    logit, cum = logit[order], np.cumsum(weight[order])
    k = int(np.searchsorted(cum, float(target) + 1e-12, side="right"))  # rows that may fall at or below t
    while 0 < k < len(logit) and logit[k - 1] == logit[k]:  # ties move together
        k -= 1
    if k == 0:
        return float(logit[0] - 1e-3 * max(1.0, abs(logit[0])))
    return float(0.5 * (logit[k - 1] + logit[k]))
