"""Mesh smoothing (pure numpy)."""

from __future__ import annotations

import numpy as np


def taubin_smooth(verts: np.ndarray, faces: np.ndarray, iters: int, lam: float, mu: float) -> np.ndarray:
    """Taubin lambda/mu smoothing with the uniform (umbrella) Laplacian.

    Each iteration applies ``x <- x + f (mean of the edge neighbours - x)`` with f = ``lam`` and then f = ``mu``
    (``lam > 0 > mu``, ``|mu| > lam`` against shrinking).

    Args:
        verts: (V, D) float positions (every vertex must lie on an edge).
        faces: (F, 3) int triangles.
        iters: number of lambda/mu pairs.
        lam: positive smoothing factor.
        mu: negative inflation factor.

    Returns:
        (V, D) smoothed positions (a new array).
    """
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    e = np.unique(e, axis=0)
    deg = np.bincount(e.ravel(), minlength=len(verts)).astype(np.float64)[:, None]
    out = verts.copy()
    for _ in range(iters):
        for f in (lam, mu):
            s = np.zeros_like(out)
            np.add.at(s, e[:, 0], out[e[:, 1]])
            np.add.at(s, e[:, 1], out[e[:, 0]])
            out = out + f * (s / deg - out)
    return out
