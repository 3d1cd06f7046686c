"""Exact boundary search (neuralcol.active.boundary_search) on analytic signed functions, and in the acquisition."""

from __future__ import annotations

import numpy as np
import pytest

from neuralcol.active.boundary_search import BracketSearch, nearest_opposite


def _run(f, za, zb, steps, illinois=True):
    bs = BracketSearch(za, f(za), zb, f(zb))
    for _ in range(steps):
        z = bs.propose()
        if not illinois:  # plain regula falsi: no halving (last is never "kept twice")
            bs.last[:] = 0
        bs.update(z, f(z))
    return bs


def test_a_plane_is_hit_in_one_step():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=5), 0.3
    f = lambda z: z @ a - b  # noqa: E731
    za = rng.normal(size=(50, 5))
    zb = za + np.outer(np.sign(b - za @ a) * 4 / np.linalg.norm(a) ** 2, a)  # the other side, along a
    assert np.all((f(za) > 0) != (f(zb) > 0))
    bs = _run(f, za, zb, 1)
    assert np.abs(bs.newest).max() < 1e-9


def test_illinois_converges_where_one_side_is_flat_and_plain_regula_falsi_stalls():
    """PD-like: a smooth penetration side, a capped clearance side (-cap far from contact)."""
    cap = 0.05
    f = lambda z: np.maximum(np.tanh(4 * (z[:, 0] - 0.3)) + 0.2 * z[:, 1] ** 2 - 0.1, -cap)  # noqa: E731
    rng = np.random.default_rng(1)
    za = np.column_stack([rng.uniform(-1.5, -1.0, 40), rng.uniform(-1, 1, 40)])  # free, deep in the cap
    zb = np.column_stack([rng.uniform(1.0, 1.5, 40), rng.uniform(-1, 1, 40)])  # colliding
    assert np.all(f(za) == -cap) and np.all(f(zb) > 0)
    illinois = _run(f, za, zb, 20)
    plain = _run(f, za, zb, 20, illinois=False)
    assert np.abs(illinois.newest).max() < 1e-6
    assert np.median(np.abs(plain.newest)) > 1e-3  # creeps: the flat end moves by little each step
    # the brackets stay valid and shrink around the boundary
    assert np.all((illinois.fa > 0) != (illinois.fb > 0))


def test_failed_labels_leave_their_bracket_and_bad_brackets_are_refused():
    f = lambda z: z[:, 0] - 0.5  # noqa: E731
    za, zb = np.zeros((3, 2)), np.ones((3, 2))
    bs = BracketSearch(za, f(za), zb, f(zb))
    z = bs.propose()
    bs.update(z, f(z) + np.array([0.0, 0.1, -0.1]), ok=np.array([True, False, True]))
    np.testing.assert_array_equal(bs.za[1], za[1])
    np.testing.assert_array_equal(bs.zb[1], zb[1])
    assert np.isnan(bs.newest[1]) and bs.newest[0] == 0.0
    with pytest.raises(ValueError, match="opposite sides"):
        BracketSearch(za, np.ones(3), zb, np.ones(3))


def test_nearest_opposite_matches_brute_force_in_box_units():
    rng = np.random.default_rng(2)
    lo, hi = np.array([-100.0, -1.0, 0.0]), np.array([100.0, 1.0, 10.0])
    ref = lo + rng.uniform(size=(300, 3)) * (hi - lo)
    ref_pd = rng.normal(size=300)
    z = lo + rng.uniform(size=(40, 3)) * (hi - lo)
    pd = rng.normal(size=40)
    got = nearest_opposite(z, pd, ref, ref_pd, lo, hi, chunk=7)
    n, rn = (z - lo) / (hi - lo), (ref - lo) / (hi - lo)
    for i in range(40):
        other = np.flatnonzero((ref_pd > 0) != (pd[i] > 0))
        assert got[i] == other[np.argmin(((rn[other] - n[i]) ** 2).sum(1))]
    assert np.all(nearest_opposite(z, np.ones(40), ref, np.ones(300), lo, hi) == -1)
