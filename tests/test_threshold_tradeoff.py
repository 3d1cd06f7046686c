"""neuralcol.metrics.threshold.tradeoff: accuracy and FNR per decision threshold, checked by hand-counted cases."""

import numpy as np
import pytest

from neuralcol.metrics.threshold import tradeoff


def test_tradeoff_counts_by_hand():
    prob = np.array([0.9, 0.6, 0.42, 0.3, 0.2, 0.7, 0.1, 0.48])
    y = np.array([1, 1, 1, 1, 0, 0, 0, 0], bool)
    a, b = tradeoff(prob, y, thresholds=(0.5, 0.4))
    # t=0.5: predicted 1 at 0.9, 0.6, 0.7 -> TP 2, FN 2 (0.42, 0.3), FP 1 (0.7), TN 3
    assert a == {"threshold": 0.5, "accuracy": pytest.approx(5 / 8), "fnr": pytest.approx(2 / 4)}
    # t=0.4: 0.42 and 0.48 join -> TP 3, FN 1, FP 2, TN 2
    assert b == {"threshold": 0.4, "accuracy": pytest.approx(5 / 8), "fnr": pytest.approx(1 / 4)}


def test_lower_threshold_never_raises_fnr():
    rng = np.random.default_rng(0)
    prob, y = rng.random(500), rng.random(500) < 0.4
    fnr = [p["fnr"] for p in tradeoff(prob, y)]
    assert fnr == sorted(fnr, reverse=True)
