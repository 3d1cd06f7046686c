"""How well projected samples land on the true collision boundary (paper sec. 4.2, the risk-seeking step).

The Newton projector pulls codes onto the detector's 0.5 level set; what active learning gains depends on
how close those codes are to the *true* boundary ``PD = 0`` and on how they got there. These are the numbers
recorded for every active-learning round (``metrics.json`` -> ``rounds[i].projection``, TensorBoard
``projection/*``) and charted by ``experiments.report`` (docs/diagnosis.md).
"""

from __future__ import annotations

import numpy as np


def boundary_shares(pd: np.ndarray, eps: float, clearance_limit: float | None = None) -> dict[str, float]:
    """Shares of samples near the true boundary: ``|PD| <= eps`` and ``|PD| <= 2 eps``, and colliding.

    Args:
        pd: (B,) exact signed penetration depths of the samples.
        eps: the labeler's boundary threshold (``D_b = {0 <= PD <= eps}``, paper eq. 1).
        clearance_limit: the labels' clearance limit (labels for training; None: full labels). A
            share whose width reaches it is NaN: a free sample's clearance beyond the limit is not known.
    """
    pd = np.asarray(pd, np.float64)
    if eps <= 0:
        raise ValueError(f"eps={eps} must be > 0")
    nan = float("nan")
    if len(pd) == 0:
        return {"within_eps": nan, "within_2eps": nan, "colliding": nan}
    a = np.abs(pd)
    lim = np.inf if clearance_limit is None else float(clearance_limit)
    return {"within_eps": float(np.mean(a <= eps)) if eps < lim else nan,
            "within_2eps": float(np.mean(a <= 2 * eps)) if 2 * eps < lim else nan,
            "colliding": float(np.mean(pd > 0))}


def projection_quality(z0: np.ndarray, z: np.ndarray, pd: np.ndarray, pd_start: np.ndarray | None, eps: float,
                       box_lo: np.ndarray, box_hi: np.ndarray, n_level1: int,
                       clearance_limit: float | None = None) -> dict:
    """Statistics of one round of projected samples.

    Args:
        z0: (B, D) starting codes (drawn from D_c).
        z: (B, D) projected codes.
        pd: (B,) exact PD of the projected codes.
        pd_start: (B,) exact PD of the starting codes (known: they are D_c rows), or None.
        eps: boundary threshold of D_b.
        box_lo, box_hi: (D,) the latent box.
        n_level1: K = |Z_0|; columns ``[:K]`` are level 1, the rest level 2.
        clearance_limit: of the labels ``pd`` and ``pd_start`` (:func:`boundary_shares`).

    Returns:
        ``n``; ``within_eps``, ``within_2eps``, ``colliding`` (projected samples); the same for the starting
        codes under ``start`` (when their PD is known); the acquisition adds them for the round's uniform samples
        under ``uniform``; ``on_face_level1`` / ``on_face_level2`` (share of coordinates on a box face,
        within 1e-6 of the side); ``moved_level1`` / ``moved_level2`` (mean |z - z0| in units of each axis'
        half-range); ``moved_ratio`` (level 1 over level 2: ~1 when both levels move alike).
    """
    z0, z = np.asarray(z0, np.float64), np.asarray(z, np.float64)
    lo, hi = np.asarray(box_lo, np.float64), np.asarray(box_hi, np.float64)
    if z.shape != z0.shape or z.ndim != 2 or z.shape[1] != len(lo):
        raise ValueError(f"z0 {z0.shape} and z {z.shape} must both be (B, {len(lo)})")
    k = int(n_level1)
    half = (hi - lo) / 2
    out = {"n": int(len(z)), **boundary_shares(pd, eps, clearance_limit)}
    if pd_start is not None:
        out["start"] = boundary_shares(pd_start, eps, clearance_limit)
    nan = float("nan")
    if len(z) == 0:
        return {**out, "on_face_level1": nan, "on_face_level2": nan, "moved_level1": nan, "moved_level2": nan,
                "moved_ratio": nan}
    face = (np.abs(z - lo) <= 1e-6 * 2 * half) | (np.abs(z - hi) <= 1e-6 * 2 * half)  # (B, D)
    moved = np.abs(z - z0) / half  # (B, D) box units
    l2 = slice(k, None) if z.shape[1] > k else None
    out["on_face_level1"] = float(face[:, :k].mean())
    out["on_face_level2"] = float(face[:, l2].mean()) if l2 is not None else nan
    out["moved_level1"] = float(moved[:, :k].mean())
    out["moved_level2"] = float(moved[:, l2].mean()) if l2 is not None else nan
    out["moved_ratio"] = out["moved_level1"] / out["moved_level2"] if l2 is not None and out["moved_level2"] > 0 \
        else nan
    return out
