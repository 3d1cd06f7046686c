"""The FNR's exact binomial interval (against scipy's binomtest) and how a run's summary reports its decision
threshold and the realistic FNR against the operating target."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binomtest

from experiments.reporting.summary import operating_point_line, operating_verdict, round_rows
from neuralcol.metrics.detection import fnr_interval, proportion_interval


@pytest.mark.parametrize("k,n", [(0, 1), (0, 10), (3, 10), (10, 10), (15, 150), (89, 892), (1, 2000)])
def test_proportion_interval_is_clopper_pearson(k, n):
    ref = binomtest(k, n).proportion_ci(0.95, method="exact")
    lo, hi = proportion_interval(k, n)
    assert lo == pytest.approx(ref.low, abs=1e-9) and hi == pytest.approx(ref.high, abs=1e-9)
    assert lo <= k / n <= hi


def test_interval_edge_cases():
    assert proportion_interval(0, 0) is None
    with pytest.raises(ValueError, match="0 <= k <= n"):
        proportion_interval(3, 2)
    with pytest.raises(ValueError, match="level"):
        proportion_interval(1, 2, level=1.0)
    pred = np.array([True, False, False, True, False])
    truth = np.array([True, True, False, False, False])  # 1 of 2 colliding missed
    assert fnr_interval(pred, truth) == proportion_interval(1, 2)
    assert fnr_interval(pred, np.zeros(5, bool)) is None  # nothing collides: no FNR


def test_operating_point_line_names_the_set_its_size_and_the_interval():
    op = {"threshold": -1.87, "operating_fnr": 0.1, "operating_set": "realistic",
          "calibration": {"n": 72, "n_colliding": 30, "fnr": 0.1, "fnr_ci95": [0.021, 0.265]}}
    line = operating_point_line(op)
    assert "logit > -1.870" in line and "72 realistic calibration meshes (30 colliding)" in line
    assert "FNR 0.100 [0.021, 0.265] there" in line
    old = {**op, "operating_set": "calibration", "calibration": {"n": 2000, "fnr": 0.1}}  # a run before the interval
    assert "2000 U(Z) calibration codes:" in operating_point_line(old)


def test_round_rows_put_the_last_round_at_logit_0():
    keys = {"dataset_size": 10, "fpr": 0.1, "balanced_accuracy": 0.8}
    rounds = [{**keys, "accuracy": 0.7, "fnr": 0.3},
              {**keys, "dataset_size": 20, "accuracy": 0.8, "fnr": 0.05,  # at the operating point
               "at_logit_0": {"accuracy": 0.88, "fnr": 0.28, "fpr": 0.04, "balanced_accuracy": 0.84}}]
    rows = round_rows(rounds)
    assert rows[0] == rounds[0] and (rows[1]["accuracy"], rows[1]["fnr"]) == (0.88, 0.28)
    assert rounds[1]["accuracy"] == 0.8  # the metrics themselves unchanged
    assert round_rows(rounds[:1]) == rounds[:1]  # no operating point: as recorded


def test_operating_verdict_reads_the_interval():
    assert "missed" in operating_verdict({"fnr_ci95": [0.12, 0.2]}, 0.1)
    assert "more cautious" in operating_verdict({"fnr_ci95": [0.01, 0.08]}, 0.1)
    assert "consistent" in operating_verdict({"fnr_ci95": [0.06, 0.16]}, 0.1)
    assert operating_verdict({"fnr_ci95": None}, 0.1) == "" and operating_verdict({"fnr_ci95": [0, 1]}, None) == ""
