"""When to stop adding data: the elbow of accuracy vs data set size (paper sec. 5, Kneedle)."""

from __future__ import annotations

import warnings

import numpy as np


def kneedle(x, y, curve: str, direction: str, sensitivity: float = 1.0) -> float | None:
    """The x of the knee of the curve (x, y) by Kneedle (Satopaa et al. 2011, the ``kneed`` package), or None if
    it has none: fewer than 3 points, a non-finite or flat y, or no knee found. ``curve``: concave | convex;
    ``direction``: increasing | decreasing (as ``kneed.KneeLocator``)."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    if len(x) < 3 or not np.isfinite(y).all() or np.ptp(y) == 0:
        return None
    from kneed import KneeLocator

    with warnings.catch_warnings():  # kneed warns when no knee is found; None says the same
        warnings.simplefilter("ignore")
        knee = KneeLocator(x, y, S=sensitivity, curve=curve, direction=direction).knee
    return None if knee is None else float(knee)


def accuracy_elbow(sizes, accuracies, sensitivity: float = 1.0) -> float | None:
    """The data set size at the elbow of the (increasing, concave) accuracy curve, or None if the curve has none
    (yet): :func:`kneedle`."""
    return kneedle(sizes, accuracies, "concave", "increasing", sensitivity)


def should_stop(sizes, accuracies, min_points: int, sensitivity: float = 1.0) -> tuple[bool, float | None]:
    """Stop once at least ``min_points`` rounds are measured and the curve has an elbow before its last point
    (the rounds after the elbow added little). Returns (stop, elbow size or None)."""
    if len(sizes) < max(3, min_points):
        return False, None
    knee = accuracy_elbow(sizes, accuracies, sensitivity)
    return (knee is not None and knee < float(sizes[-1])), knee
