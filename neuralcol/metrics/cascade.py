"""The certified cascade: the detector where it is confident, the exact labeler in a band of doubt.

The detector's logit ``l`` of a sample and a band ``[lo, hi)`` decide the verdict:

* ``l < lo``: "free", by the network;
* ``l >= hi``: "colliding", by the network;
* ``lo <= l < hi``: the exact label (the code decoded to a mesh, or the user's mesh itself, judged by the run's
  exact labeler).

The band is chosen on a calibration set (uniform codes from U(Z), labeled exactly, apart from the test set and
from D_c) to reach a target false negative rate with the fewest exact calls. With only the FNR constraint the
fewest-calls answer is degenerate (lower the threshold, no exact call, accuracy collapses), so an accuracy floor
comes with it. :func:`choose_band`, on N calibration samples with P colliding ones:

1. at most ``k = floor(target_fnr * P)`` colliding samples may lie below ``lo`` (calibration FNR <= target);
2. the cascade may make at most ``E`` errors on calibration, ``FN(l < lo) + FP(l >= hi) <= E`` (the band's
   rows are exact, so they are never wrong): ``min_accuracy="detector"`` (the default) takes ``E`` = the errors
   of the detector alone at its default threshold (``l > 0`` collides), i.e. the cascade is never less accurate
   than the detector alone on calibration; a float ``a`` in [0, 1] takes ``E = floor((1 - a) N)``;
3. among the bands meeting 1 and 2, the one with the fewest calibration samples inside ``[lo, hi)``; ties go to
   the fewest calibration errors, then to the largest ``lo``.

The thresholds are calibration logits (or +inf): a band is defined by which calibration rows fall on each side, and
``lo`` / ``hi`` are the largest values giving that split from above (``l >= t`` is the upper side), i.e. ``lo`` is
the (k+1)-th smallest colliding logit when the FNR constraint binds. The search is exact (every ``lo`` with, for
each, the smallest ``hi`` meeting 2; ``tests/test_cascade.py`` checks it against every pair enumerated).

When the accuracy floor does not bind, this is "the largest ``lo`` meeting the FNR target, then the smallest
``hi >= lo`` meeting the error budget"; the joint search also covers the cases where that two-step rule fails:
where the largest such ``lo`` already misses more colliding samples than the budget allows (a detector whose own
FNR is below the target: there the band is empty, ``lo == hi``, when the detector alone meets both) and where
a slightly lower ``lo`` needs fewer exact calls. ``min_accuracy=None``: no accuracy floor: no band at all
(``hi = lo`` = the largest ``lo`` meeting the FNR target; zero exact calls, the detector thresholded at ``lo``).

The floor of step 2 holds on the calibration set, where it is tight by construction: the search spends the budget,
turning the false negatives the band saves into false positives above ``hi < 0``, at the logits where calibration
happens to favour the trade; on other samples the cascade can fall below the detector alone (the runs report it).
``min_accuracy="pointwise"`` holds on every sample instead: ``lo`` = the largest threshold meeting the FNR target
that is <= 0 (the smallest logit if every one is > 0: nothing lies below it), ``hi`` = the smallest calibration
logit > 0 (and ``hi >= lo``), so outside the band the cascade answers what the detector alone answers (``l < lo <=
0``: free; ``l >= hi > 0``: colliding) and inside it the exact label: never less accurate than the detector on any
set, at the price of more exact calls.

The FNR guarantee holds on the calibration set; on other samples of the same distribution the FNR is near the target
(the runs report it on the U(Z) test set), on another distribution (the realistic meshes) it may not be.
Calibration without a colliding sample raises (the FNR is undefined). :func:`apply_band` applies a band, calling
the exact labeler for the band's rows only. docs/cascade.md has the API, docs/studies/cascade_band.md the
pipeline's measurements.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

DETECTOR = "detector"  # min_accuracy: the detector alone's accuracy at logit 0 on the calibration set
POINTWISE = "pointwise"  # min_accuracy: never a verdict the detector alone would get right and the cascade wrong


class Band(NamedTuple):
    """A band of doubt ``[lo, hi)`` on the detector's logit, and what it did on the calibration set.

    lo, hi: thresholds (``l < lo`` free, ``l >= hi`` colliding, exact between; +inf possible). calib_fnr,
    calib_accuracy: the cascade's FNR and accuracy on calibration (band rows counted right: they are exact).
    calib_exact_share: fraction of calibration samples inside the band (the exact calls).
    """

    lo: float
    hi: float
    calib_fnr: float
    calib_accuracy: float
    calib_exact_share: float


def _check(logits, collides) -> tuple[np.ndarray, np.ndarray]:
    logit = np.asarray(logits, np.float64)
    y = np.asarray(collides)
    if logit.ndim != 1 or y.shape != logit.shape:
        raise ValueError(f"logits {logit.shape} and collides {y.shape} must be equal 1-D shapes")
    if len(logit) == 0:
        raise ValueError("choose_band: empty calibration set")
    if not np.isfinite(logit).all():
        raise ValueError(f"choose_band: {int((~np.isfinite(logit)).sum())} non-finite calibration logits")
    return logit, y.astype(bool)


def error_budget(logits, collides, min_accuracy=DETECTOR) -> int | None:
    """Errors the cascade may make on the calibration set (None: no accuracy floor); see the module docstring."""
    logit, y = _check(logits, collides)
    if min_accuracy is None:
        return None
    if isinstance(min_accuracy, str):
        if min_accuracy not in (DETECTOR, POINTWISE):
            raise ValueError(f"min_accuracy={min_accuracy!r}; use {DETECTOR!r}, {POINTWISE!r}, a float in [0, 1] or "
                             "None")
        pred = logit > 0
        return int((pred != y).sum())  # (pointwise: the errors it cannot exceed, on calibration as anywhere)
    a = float(min_accuracy)
    if not 0.0 <= a <= 1.0:
        raise ValueError(f"min_accuracy={min_accuracy!r}; an accuracy floor lies in [0, 1]")
    return int(math.floor((1.0 - a) * len(y) + 1e-9))


def allowed_misses(n_pos: int, target_fnr: float, confidence: float | None = None) -> int:
    """Colliding calibration samples allowed below ``lo``. ``confidence`` None: ``floor(target_fnr * n_pos)`` (the
    calibration FNR <= target). A confidence ``c`` in (0, 1): the largest ``k`` whose one-sided Clopper-Pearson upper
    bound on the FNR at level ``c`` is <= target (``beta.ppf(c, k + 1, n_pos - k)``), so that a fresh sample's FNR
    exceeds the target with probability about ``1 - c`` at most; 0 when even ``k = 0`` cannot certify it (the
    calibration set has too few colliding samples: about ``ln(1 / (1 - c)) / target`` are needed)."""
    if confidence is None:
        return int(math.floor(float(target_fnr) * n_pos + 1e-9))
    c = float(confidence)
    if not 0.0 < c < 1.0:
        raise ValueError(f"confidence={confidence!r}; a confidence level lies in (0, 1)")
    from scipy.stats import beta

    k = np.arange(n_pos)
    ok = beta.ppf(c, k + 1, n_pos - k) <= float(target_fnr)
    return int(k[ok][-1]) if ok.any() else 0


def choose_band(logits, collides, target_fnr: float, min_accuracy=DETECTOR, confidence: float | None = None) -> Band:
    """The band ``[lo, hi)`` reaching ``target_fnr`` on the calibration set with the fewest exact calls.

    Args:
        logits: (N,) the detector's logits on the calibration samples (finite).
        collides: (N,) bool, their exact labels.
        target_fnr: the FNR allowed, in [0, 1).
        min_accuracy: ``"detector"`` (the cascade is at least as accurate as the detector alone at logit 0 on the
            calibration set), ``"pointwise"`` (on every sample: the band covers the detector's doubtful side of 0),
            a float accuracy floor in [0, 1], or None (no floor: ``hi = lo``, no exact call).
        confidence: None (the calibration FNR <= target) or a level in (0, 1) (:func:`allowed_misses`: the FNR
            on fresh samples <= target with about that probability).

    Returns:
        :class:`Band` (the rule: module docstring).

    Raises:
        ValueError: no colliding calibration sample, bad shapes or values.
    """
    logit, y = _check(logits, collides)
    t_fnr = float(target_fnr)
    if not 0.0 <= t_fnr < 1.0:
        raise ValueError(f"target_fnr={target_fnr!r}; an FNR target lies in [0, 1)")
    n, n_pos = len(y), int(y.sum())
    if n_pos == 0:
        raise ValueError(f"choose_band: none of the {n} calibration samples collides, so the FNR is undefined; "
                         "label a larger calibration set (detector.cascade.calibration_size)")
    budget = error_budget(logit, y, min_accuracy)
    k = allowed_misses(n_pos, t_fnr, confidence)  # colliding samples allowed below lo
    cand = np.append(np.unique(logit), np.inf)  # thresholds, ascending
    below = np.searchsorted(np.sort(logit), cand, side="left")  # rows with l < t
    fn = np.searchsorted(np.sort(logit[y]), cand, side="left")  # colliding rows with l < t
    fp_ge = (n - n_pos) - np.searchsorted(np.sort(logit[~y]), cand, side="left")  # free rows with l >= t
    i_max = int(np.flatnonzero(fn <= k)[-1])  # fn is non-decreasing; fn[0] = 0 <= k
    if budget is None:
        i = j = i_max
    elif min_accuracy == POINTWISE:
        at_most_0 = np.flatnonzero(cand[: i_max + 1] <= 0)
        i = int(at_most_0[-1]) if len(at_most_0) else 0  # (every logit > 0: lo = the smallest, nothing below it)
        j = max(i, int(np.searchsorted(cand, 0.0, side="right")))  # the smallest threshold > 0
    else:
        i_all = np.arange(i_max + 1)
        slack = budget - fn[i_all]
        ok = slack >= 0
        # smallest j with fp_ge[j] <= slack (fp_ge non-increasing, fp_ge[-1] = 0), then j >= i
        j_all = np.maximum(np.searchsorted(-fp_ge, -slack, side="left"), i_all)
        i_all, j_all = i_all[ok], j_all[ok]
        calls = below[j_all] - below[i_all]
        errors = fn[i_all] + fp_ge[j_all]
        best = np.lexsort((-i_all, errors, calls))[0]  # fewest calls, then fewest errors, then the largest lo
        i, j = int(i_all[best]), int(j_all[best])
    errors = int(fn[i] + fp_ge[j])
    return Band(lo=float(cand[i]), hi=float(cand[j]), calib_fnr=float(fn[i] / n_pos),
                calib_accuracy=(n - errors) / n, calib_exact_share=float(below[j] - below[i]) / n)


def band_mask(logits, band: Band) -> np.ndarray:
    """(N,) bool: the samples inside ``[band.lo, band.hi)``, the ones the exact labeler decides."""
    logit = np.asarray(logits, np.float64)
    return (logit >= band.lo) & (logit < band.hi)


def apply_band(logits, band: Band, exact_fn: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The cascade's verdicts: the network outside the band, ``exact_fn`` inside it.

    Args:
        logits: (N,) the detector's logits.
        band: from :func:`choose_band`.
        exact_fn: ``rows (M,) int -> (M,) bool`` "collides" of those rows (the exact labeler; called once, with
            every band row, and not at all when no row lies in the band).

    Returns:
        (verdict (N,) bool "collides", used_exact (N,) bool: the rows ``exact_fn`` decided).
    """
    logit = np.asarray(logits, np.float64)
    verdict = logit >= band.hi
    used = band_mask(logit, band)
    rows = np.flatnonzero(used)
    if len(rows):
        exact = np.asarray(exact_fn(rows)).astype(bool).reshape(-1)
        if exact.shape != rows.shape:
            raise ValueError(f"apply_band: exact_fn returned {exact.shape} verdicts for {len(rows)} rows")
        verdict[rows] = exact
    return verdict, used


def cascade_scores(logits, collides, band: Band) -> dict:
    """FNR, accuracy and exact share of the cascade on labeled samples, the band's rows taking their exact labels
    (what the exact labeler returns for them), with the sample count n. FNR is NaN without colliding samples."""
    y = np.asarray(collides, bool)
    verdict, used = apply_band(logits, band, lambda rows: y[rows])
    n, n_pos = len(y), int(y.sum())
    if n == 0:
        return {"fnr": float("nan"), "accuracy": float("nan"), "exact_share": float("nan"), "n": 0}
    return {"fnr": float((~verdict & y).sum() / n_pos) if n_pos else float("nan"),
            "accuracy": float((verdict == y).mean()), "exact_share": float(used.mean()), "n": int(n)}
