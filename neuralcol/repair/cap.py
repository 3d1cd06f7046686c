"""Capping a freed mesh's displacement: the smallest cap on the vertex moves (a fraction of the largest) that leaves
it free (:func:`cap_displacements`, :func:`cap_freed`), and the moves themselves (:func:`displacement_stats`)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def displacement_stats(v_user: np.ndarray, v_out: np.ndarray, diagonal: float) -> dict[str, np.ndarray]:
    """Per-mesh vertex displacement from the input, in mesh units and as a fraction of ``diagonal``.

    Returns ``{"median", "mean", "max"}`` each (B,) in mesh units (NaN where the output is non-finite) and the
    same divided by ``diagonal`` under ``"<key>_frac"``."""
    d = np.linalg.norm(np.asarray(v_out, np.float64) - np.asarray(v_user, np.float64), axis=-1)  # (B, V)
    out = {"median": np.median(d, axis=1), "mean": d.mean(1), "max": d.max(1)}
    out.update({f"{k}_frac": v / float(diagonal) for k, v in list(out.items())})
    return out


def cap_displacements(x: np.ndarray, result: np.ndarray, label: Callable[[np.ndarray], np.ndarray],
                      steps: int, collides: Callable[[np.ndarray], np.ndarray] | None = None,
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The smallest cap on each result's vertex displacements that leaves it collision-free.

    With ``d = result - x`` and ``m`` its largest vertex displacement, the capped mesh is
    ``x + d_i min(1, c m / |d_i|)`` (each vertex's move keeps its direction, its length clipped at ``c m``: a
    continuous field); bisection over ``steps`` steps finds the smallest ``c`` in (0, 1] at which the mesh is free.

    Args:
        label: meshes (m, V, 3) -> exact PD (m,) (NaN where the labeler failed).
        collides: meshes (m, V, 3) -> (m,) bool, the exact verdict (e.g. ``ExactLabeler.verdict``, far cheaper
            than the full label). With it the bisection asks the verdict and only the capped meshes kept get
            ``label`` (a capped mesh whose label is not free is dropped: its result kept); without it each step is
            one batched ``label``.

    Returns:
        (meshes (n, V, 3), pd (n,): the capped mesh's exact PD, NaN where the result was kept, c (n,): 1.0 where kept).
    """
    x, result = np.asarray(x, np.float64), np.asarray(result, np.float64)
    d = result - x
    norm = np.linalg.norm(d, axis=-1, keepdims=True)  # (n, V, 1)
    top = norm.max(1, keepdims=True)  # (n, 1, 1)

    def capped(c: np.ndarray) -> np.ndarray:
        return x + d * np.minimum(1.0, c[:, None, None] * top / np.maximum(norm, 1e-300))

    lo, hi = np.zeros(len(x)), np.ones(len(x))
    best_pd = np.full(len(x), np.nan)
    for _ in range(steps if len(x) else 0):
        c = 0.5 * (lo + hi)
        if collides is None:
            pd = label(capped(c))
            free = np.nan_to_num(pd, nan=np.inf) <= 0
            best_pd[free] = pd[free]
        else:
            free = ~np.asarray(collides(capped(c)), bool)
        hi[free] = c[free]
        lo[~free] = c[~free]
    kept = hi < 1
    if collides is not None and kept.any():  # the full label of what is kept
        rows = np.flatnonzero(kept)
        best_pd[rows] = label(capped(hi)[rows])
        bad = rows[~(np.nan_to_num(best_pd[rows], nan=np.inf) <= 0)]
        hi[bad], best_pd[bad], kept[bad] = 1.0, np.nan, False
    return np.where(kept[:, None, None], capped(hi), result), best_pd, hi


def cap_freed(x: np.ndarray, out: np.ndarray, pd_in: np.ndarray, pd_v: np.ndarray, label, steps: int,
              labeler) -> np.ndarray:
    """``repair.cap_steps``: the colliding inputs returned free by the exact label get :func:`cap_displacements`
    (bisection on ``labeler.verdict``; ``out`` and ``pd_v`` updated in place); returns the cap per input (NaN where
    not tried)."""
    cap = np.full(len(out), np.nan)
    rows = np.flatnonzero(~(pd_in <= 0) & (pd_v <= 0) & np.isfinite(pd_v))
    if steps and len(rows):
        kept, pd_c, cap[rows] = cap_displacements(x[rows], out[rows], label, steps,
                                                  lambda m: np.array([labeler.verdict(v) for v in m], bool))
        moved = cap[rows] < 1
        out[rows], pd_v[rows[moved]] = kept, pd_c[moved]
    return cap


# an input's depth below this share of its diagonal is a contact at round-off (a sliver crossing, a CAD seam): the move
# over it says nothing (1e12 and more), so it is not given
DEPTH_FLOOR = 1e-9


def move_to_depth(largest_move, pd_input, diagonal: float) -> np.ndarray:
    """Each input's largest vertex move over its exact PD: NaN where the input is free, or its depth is below
    :data:`DEPTH_FLOOR` of the diagonal."""
    pd = np.asarray(pd_input, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(pd > DEPTH_FLOOR * float(diagonal), np.asarray(largest_move, np.float64) / pd, np.nan)
