"""Where a detector or handler fails, and what it costs: per-bin rates and the Pareto front (pure functions).

Used by ``experiments.report`` (``failures.png``, ``pareto.png``). PD bins are in units of the run's
``pd_unit`` (the labeler's clearance cap: PD of collision-free meshes lies in ``[-pd_unit, 0]``). The edges
(:data:`PD_BIN_EDGES`) are fixed multiples so every method, seed and size is binned alike: collision-free
meshes with clearance above 0.25 pd_unit, free meshes within 0.25 pd_unit of touching, and three depths of
self-penetration (PD up to 1, 1 to 4, above 4 pd_unit). On the SCAPE test sets (seed 1000003) these hold
46-62 / 38-54 % of the free rows and about 30 / 45 / 24 % of the colliding rows; on proc_hand 90 / 10 % and
59 / 39 / 2 %.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

PD_BIN_EDGES = (-0.25, 0.0, 1.0, 4.0)  # in pd_unit; bins are right-closed: (-inf, -0.25], (-0.25, 0], ...
PD_BIN_NAMES = ("free, clearance > 0.25", "free, clearance ≤ 0.25", "PD ≤ 1", "1 < PD ≤ 4", "PD > 4")


class BinRates(NamedTuple):
    """Per-bin rates: rate (M,) float (NaN for an empty bin) and count (M,) int64 (rows in each bin)."""

    rate: np.ndarray
    count: np.ndarray


def pd_bins(pd: np.ndarray, pd_unit: float, edges=PD_BIN_EDGES) -> np.ndarray:
    """Bin index of each exact PD: bin i holds ``edges[i-1] * pd_unit < pd <= edges[i] * pd_unit``.

    Args:
        pd: (N,) float, exact PD (negative: clearance of a collision-free mesh).
        pd_unit: the unit of ``edges`` (> 0).
        edges: (M - 1,) increasing bin edges in units of ``pd_unit``.

    Returns:
        (N,) int64 in ``[0, M)``; PD 0 (touching, not colliding) falls in the bin ending at 0.
    """
    e = np.asarray(edges, np.float64)
    if not pd_unit > 0 or not np.isfinite(pd_unit):
        raise ValueError(f"pd_bins: pd_unit must be a positive number, got {pd_unit}")
    if e.ndim != 1 or (np.diff(e) <= 0).any():
        raise ValueError(f"pd_bins: edges must increase, got {list(edges)}")
    return np.searchsorted(e * pd_unit, np.asarray(pd, np.float64), side="left").astype(np.int64)


def rate_by_group(hit: np.ndarray, group: np.ndarray, n_groups: int) -> BinRates:
    """Fraction of ``hit`` within each group (accuracy per PD bin, recall per sub-domain, success per bin).

    Args:
        hit: (N,) bool, e.g. prediction == label.
        group: (N,) int in ``[0, n_groups)``.
        n_groups: M.

    Returns:
        :class:`BinRates` with rate (M,) (NaN where a group is empty) and count (M,).
    """
    hit, group = np.asarray(hit, bool), np.asarray(group, np.int64)
    if hit.shape != group.shape or hit.ndim != 1:
        raise ValueError(f"rate_by_group: hit {hit.shape} and group {group.shape} must be equal 1-D shapes")
    if len(group) and (group.min() < 0 or group.max() >= n_groups):
        raise ValueError(f"rate_by_group: groups must lie in [0, {n_groups}), got [{group.min()}, {group.max()}]")
    count = np.bincount(group, minlength=n_groups).astype(np.int64)
    hits = np.bincount(group, weights=hit.astype(np.float64), minlength=n_groups)
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = np.where(count > 0, hits / np.maximum(count, 1), np.nan)
    return BinRates(rate, count)


def deepest_subdomain(pd_sub: np.ndarray) -> np.ndarray:
    """The sub-domain with the largest PD of each row (ties: the lowest index; NaN entries are ignored).

    Args:
        pd_sub: (N, K) float, PD of each sub-domain.

    Returns:
        (N,) int64 in ``[0, K)``.
    """
    p = np.asarray(pd_sub, np.float64)
    if p.ndim != 2 or p.shape[1] == 0:
        raise ValueError(f"deepest_subdomain: pd_sub must be (N, K) with K >= 1, got {p.shape}")
    return np.argmax(np.where(np.isnan(p), -np.inf, p), axis=1).astype(np.int64)


def pareto_front(cost: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Points no other point beats: none has cost <= and value >= with one of them strict (lower cost and
    higher value are better). Points with a NaN are never on the front.

    Args:
        cost: (N,) float.
        value: (N,) float.

    Returns:
        (N,) bool, True on the front.
    """
    c, v = np.asarray(cost, np.float64), np.asarray(value, np.float64)
    if c.shape != v.shape or c.ndim != 1:
        raise ValueError(f"pareto_front: cost {c.shape} and value {v.shape} must be equal 1-D shapes")
    ok = np.isfinite(c) & np.isfinite(v)
    cc, vv = c[ok], v[ok]
    no_worse = (cc[None, :] <= cc[:, None]) & (vv[None, :] >= vv[:, None])  # (N, N): j at least as good as i
    better = (cc[None, :] < cc[:, None]) | (vv[None, :] > vv[:, None])
    front = np.zeros(len(c), bool)
    front[ok] = ~(no_worse & better).any(axis=1)
    return front


def mean_std(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, sample std (ddof 1; 0 for one value) and number of finite values over axis 0, ignoring NaN.

    Args:
        values: (S, M) float, one row per seed (NaN: the seed has no value there).

    Returns:
        mean (M,), std (M,), n (M,) int64; mean and std are NaN where no seed has a value.
    """
    v = np.asarray(values, np.float64)
    if v.ndim != 2:
        raise ValueError(f"mean_std: values must be (seeds, M), got {v.shape}")
    n = np.isfinite(v).sum(axis=0)
    total = np.where(np.isfinite(v), v, 0.0).sum(axis=0)
    mean = np.where(n > 0, total / np.maximum(n, 1), np.nan)
    sq = np.where(np.isfinite(v), (v - mean) ** 2, 0.0).sum(axis=0)
    std = np.where(n > 1, np.sqrt(sq / np.maximum(n - 1, 1)), np.where(n == 1, 0.0, np.nan))
    return mean, std, n.astype(np.int64)
