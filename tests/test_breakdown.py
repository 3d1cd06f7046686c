"""Pure pieces of the report's cost and failure charts, by hand: PD bins, rates per group, Pareto front."""

from __future__ import annotations

import numpy as np
import pytest

from neuralcol.metrics import breakdown as bd
from neuralcol.metrics.breakdown import PD_BIN_NAMES, deepest_subdomain, mean_std, pareto_front, pd_bins, rate_by_group


def test_pd_bins_are_right_closed_in_units_of_pd_unit():
    assert len(PD_BIN_NAMES) == len(bd.PD_BIN_EDGES) + 1
    u = 0.02
    pd = np.array([-0.02, -0.005, -0.0049, 0.0, 1e-9, 0.02, 0.0201, 0.08, 0.09])
    # edges -0.005, 0, 0.02, 0.08: touching (PD 0) is free; exactly 1 unit is still "PD <= 1"
    np.testing.assert_array_equal(pd_bins(pd, u), [0, 0, 1, 1, 2, 2, 3, 3, 4])
    with pytest.raises(ValueError, match="pd_unit"):
        pd_bins(pd, 0.0)
    with pytest.raises(ValueError, match="edges"):
        pd_bins(pd, u, edges=(0.0, -1.0))


def test_bin_accuracy_and_subdomain_recall_by_hand():
    pd = np.array([-0.9, -0.1, -0.2, 0.5, 0.7, 2.0, 5.0, 6.0])  # pd_unit 1
    collides = pd > 0
    pred = np.array([False, True, False, True, False, True, True, True])
    acc = rate_by_group(pred == collides, pd_bins(pd, 1.0), len(PD_BIN_NAMES))
    # bins: [-0.9] right; [-0.1 wrong, -0.2 right]; [0.5 right, 0.7 missed]; [2.0 right]; [5, 6 right]
    np.testing.assert_array_equal(acc.count, [1, 2, 2, 1, 2])
    np.testing.assert_allclose(acc.rate, [1.0, 0.5, 0.5, 1.0, 1.0])
    pd_sub = np.array([[0.5, 0.1, np.nan], [0.2, 0.7, 0.0], [1.0, 2.0, 2.0], [0.0, 0.0, 5.0], [np.nan, 6.0, 1.0]])
    deepest = deepest_subdomain(pd_sub)
    np.testing.assert_array_equal(deepest, [0, 1, 1, 2, 1])  # a tie goes to the lower index, NaN is skipped
    recall = rate_by_group(pred[collides], deepest, 4)  # sub-domain 3 has no colliding row
    np.testing.assert_array_equal(recall.count, [1, 3, 1, 0])
    np.testing.assert_allclose(recall.rate, [1.0, 2 / 3, 1.0, np.nan])
    with pytest.raises(ValueError, match=r"\[0, 2\)"):
        rate_by_group(pred, np.arange(8), 2)


def test_pareto_front_of_hand_made_points():
    #             a     b     c     d     e     f     g
    cost = np.array([1.0, 2.0, 2.0, 3.0, 4.0, 5.0, np.nan])
    acc = np.array([0.80, 0.85, 0.90, 0.88, 0.95, 0.95, 0.99])
    # b: c costs the same and is better; d: c is cheaper and better; f: e is cheaper and as good; g: no cost
    np.testing.assert_array_equal(pareto_front(cost, acc), [True, False, True, False, True, False, False])
    # equal points do not knock each other out
    np.testing.assert_array_equal(pareto_front(np.array([1.0, 1.0]), np.array([0.5, 0.5])), [True, True])
    assert pareto_front(np.zeros(0), np.zeros(0)).shape == (0,)


def test_mean_std_over_seeds_ignores_missing_values():
    v = np.array([[0.5, 1.0, np.nan, np.nan], [0.7, 1.0, 0.2, np.nan], [0.9, 1.0, np.nan, np.nan]])
    mean, std, n = mean_std(v)
    np.testing.assert_allclose(mean, [0.7, 1.0, 0.2, np.nan])
    np.testing.assert_allclose(std, [0.2, 0.0, 0.0, np.nan])
    np.testing.assert_array_equal(n, [3, 3, 1, 0])
