"""The operating threshold: the logit at which a trained detector says "collides".

The paper decides at p > 0.5 (logit 0). neuralcol's runs decide where the detector misses at most
``detector.operating_fnr`` of the colliding meshes of a calibration set, because a user cares about the collisions a
detector lets through on the meshes they bring, not on codes drawn from the latent box. This module holds that rule in
one place; training (:func:`neuralcol.stages.detector.operating_point`), recalibrating a finished run
(:mod:`neuralcol.api.recalibrate`) and checking a run's configuration (:mod:`neuralcol.pipeline.validate`) all use it:

* where the threshold is measured: :data:`OPERATING_SETS`, :func:`choose_set` (what ``auto`` becomes) and
  :func:`needs_calibration_meshes` (whether a run must draw the realistic calibration set);
* the threshold itself: :func:`fnr_threshold` (one set), :func:`mean_fnr_threshold` (several sets weighing the
  same), :func:`threshold_for` (either);
* what is reported about it: :func:`calibration_record`, :func:`score`;
* folding it into the detector so that logit 0 means the threshold: :func:`fold_into` (a network in memory),
  :func:`fold_into_file` (a saved ``detector.pt``);
* the configuration's rules: :func:`config_problems`.

The study behind the defaults: ``docs/studies/operating_threshold.md``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

#: where ``detector.operating_fnr`` is measured (``detector.operating_set``):
#: ``realistic_calibration``: a realistic set drawn like the realistic test set with its own seed, never a row of D_c;
#: ``realistic``: the realistic training meshes among D_c's validation rows (a detector over code and mesh);
#: ``calibration``: the cascade's calibration set of uniform U(Z) codes;
#: ``both``: the mean of the FNRs of ``realistic`` and ``calibration``;
#: ``auto``: ``realistic_calibration`` where the run draws realistic sets, else ``realistic`` where D_c holds such
#: rows, else ``calibration``.
OPERATING_SETS = ("auto", "calibration", "realistic", "both", "realistic_calibration")

#: how a run's summary names the set its threshold was set on (``auto`` never appears: it is resolved first)
SET_NAMES = {"realistic": "realistic calibration meshes", "calibration": "U(Z) calibration codes",
             "both": "realistic calibration meshes and U(Z) calibration codes",
             "realistic_calibration": "realistic calibration meshes apart from D_c"}


def choose_set(where: str, has_calibration_meshes: bool, has_realistic_rows: bool) -> str:
    """What ``detector.operating_set`` means for a run: ``auto`` resolved (see :data:`OPERATING_SETS`), any other
    value as given.

    Raises:
        ValueError: ``where`` is not one of :data:`OPERATING_SETS`.
    """
    if where not in OPERATING_SETS:
        raise ValueError(f"detector.operating_set={where!r}; use one of {', '.join(OPERATING_SETS)}")
    if where != "auto":
        return where
    return "realistic_calibration" if has_calibration_meshes else "realistic" if has_realistic_rows else "calibration"


def needs_calibration_meshes(det: dict, realistic_enabled: bool) -> bool:
    """Whether a run with detector settings ``det`` must draw the realistic calibration set: an operating FNR is
    asked, the run draws realistic sets, and ``operating_set`` is ``auto`` or ``realistic_calibration``."""
    return det.get("operating_fnr") is not None and bool(realistic_enabled) \
        and det.get("operating_set", "calibration") in ("auto", "realistic_calibration")


def fnr_threshold(logits: np.ndarray, collides: np.ndarray, target: float) -> float:
    """The largest logit threshold ``t`` at which ``logit > t`` misses at most ``target`` of the colliding rows:
    with k = floor(target * n_colliding), halfway between the colliding rows' k-th and (k+1)-th smallest logits
    (k = 0: just below the smallest).

    Raises:
        ValueError: ``target`` outside [0, 1) or no colliding row.
    """
    if not 0.0 <= float(target) < 1.0:
        raise ValueError(f"target FNR {target} must lie in [0, 1)")
    pos = np.sort(np.asarray(logits, np.float64)[np.asarray(collides, bool)])
    if len(pos) == 0:
        raise ValueError("no colliding row: the FNR of a threshold is undefined")
    k = int(np.floor(float(target) * len(pos) + 1e-9))
    if k == 0:
        return float(pos[0] - 1e-3 * max(1.0, abs(pos[0])))
    return float(0.5 * (pos[k - 1] + pos[k]))


def mean_fnr_threshold(sets: list[tuple[np.ndarray, np.ndarray]], target: float) -> float:
    """The largest logit threshold ``t`` at which the **mean** over ``sets`` of each set's FNR (``logit > t`` missing
    its colliding rows) is at most ``target``: every set weighs the same whatever its size. One set: exactly
    :func:`fnr_threshold`. Used by ``detector.operating_set: both`` (realistic rows and calibration codes).

    Args:
        sets: ``[(logits (N_j,), collides (N_j,) bool), ...]``; a set without colliding rows is skipped.
        target: in [0, 1).

    Raises:
        ValueError: ``target`` outside [0, 1) or no colliding row in any set.
    """
    if not 0.0 <= float(target) < 1.0:
        raise ValueError(f"target FNR {target} must lie in [0, 1)")
    pos = [np.asarray(lg, np.float64)[np.asarray(y, bool)] for lg, y in sets]
    pos = [p for p in pos if len(p)]
    if not pos:
        raise ValueError("no colliding row: the FNR of a threshold is undefined")
    if len(pos) == 1:
        return fnr_threshold(pos[0], np.ones(len(pos[0]), bool), target)
    logit = np.concatenate(pos)
    weight = np.concatenate([np.full(len(p), 1.0 / (len(p) * len(pos))) for p in pos])
    order = np.argsort(logit, kind="stable")
    logit, cum = logit[order], np.cumsum(weight[order])
    k = int(np.searchsorted(cum, float(target) + 1e-12, side="right"))  # rows that may fall at or below t
    while 0 < k < len(logit) and logit[k - 1] == logit[k]:  # ties move together
        k -= 1
    if k == 0:
        return float(logit[0] - 1e-3 * max(1.0, abs(logit[0])))
    return float(0.5 * (logit[k - 1] + logit[k]))


def threshold_for(sets: list[tuple[np.ndarray, np.ndarray]], target: float) -> float:
    """The operating threshold on ``sets`` ``[(logits, collides), ...]``: :func:`fnr_threshold` of a single set,
    :func:`mean_fnr_threshold` of several."""
    if len(sets) == 1:
        return fnr_threshold(sets[0][0], sets[0][1], target)
    return mean_fnr_threshold(sets, target)


def calibration_record(sets: list[tuple[np.ndarray, np.ndarray]], threshold: float) -> dict:
    """What a run reports of the set its threshold was set on (``operating_point.calibration``): ``n`` and
    ``n_colliding`` (the sets pooled), ``accuracy``, ``fnr``, ``fpr`` at ``threshold``; one set: also ``fnr_ci95``
    (the FNR's 95 % Clopper-Pearson interval, None when nothing collides); several: ``fnr`` is the mean of their
    FNRs (the quantity :func:`mean_fnr_threshold` bounds) and no interval."""
    from neuralcol.metrics.detection import detection_metrics, fnr_interval

    logit = np.concatenate([np.asarray(s[0], np.float64) for s in sets])
    y = np.concatenate([np.asarray(s[1], bool) for s in sets])
    m = detection_metrics(logit > threshold, y)
    out = {"n": int(len(y)), "n_colliding": int(y.sum()), **{k: m[k] for k in ("accuracy", "fnr", "fpr")}}
    if len(sets) > 1:
        out["fnr"] = float(np.mean([np.mean(np.asarray(lg)[np.asarray(yy, bool)] <= threshold) for lg, yy in sets
                                    if np.asarray(yy, bool).any()]))
    else:
        ci = fnr_interval(logit > threshold, y)
        out["fnr_ci95"] = None if ci is None else list(ci)
    return out


def score(logit: np.ndarray, collides: np.ndarray, threshold: float) -> dict:
    """A detector's figures on a labeled set when it decides at ``logit > threshold``
    (:func:`~neuralcol.metrics.detection.detection_report`: accuracy, FNR, FPR, balanced accuracy, base rate, the
    majority class's accuracy, ``skill`` against it, ``n``, ``n_colliding`` and the FNR's 95 % interval)."""
    from neuralcol.metrics.detection import detection_report

    return detection_report(np.asarray(logit, np.float64) > threshold, np.asarray(collides, bool))


def fold_into(net, threshold: float) -> None:
    """Make ``net`` (a :class:`~neuralcol.nn.detector.CollisionDetector`) decide at ``logit > threshold`` with
    its logit 0: its output bias minus ``threshold``, so that p > 0.5, the handler's constraint and the cascade's
    bands all mean the operating point afterwards."""
    net.shift_decision(float(threshold))


def fold_into_file(path: str | Path, threshold: float) -> None:
    """:func:`fold_into` for a saved ``detector.pt``: its output bias minus ``threshold``, everything else in the
    file as it was (written atomically)."""
    import torch

    from neuralcol.nn.detector import load_detector
    from neuralcol.utils.files import atomic_path
    from neuralcol.utils.safe_files import read_torch_file

    net, _ = load_detector(path)
    bias = net.output_bias
    name = next(k for k, p in net.named_parameters() if p is bias)
    blob = read_torch_file(path, "cpu")
    blob["state"][name] = blob["state"][name] - float(threshold)
    with atomic_path(Path(path)) as tmp:
        torch.save(blob, tmp)


def config_problems(get: Callable[[str], object]) -> list[str]:
    """Problems of a run configuration's operating-threshold settings, as ``key=value: rule`` strings (empty: fine).

    Args:
        get: ``key -> value`` of the composed configuration (None where the key is absent).
    """
    problems = []
    target, where = get("detector.operating_fnr"), get("detector.operating_set")
    if target is not None:
        try:
            fine = 0 <= float(target) < 1
        except (TypeError, ValueError):
            fine = False
        if not fine:
            problems.append(f"detector.operating_fnr={target!r}: must lie in [0, 1) (null: the paper's p > 0.5)")
    if where is None:
        return problems
    if where not in OPERATING_SETS:
        problems.append(f"detector.operating_set={where!r}: use {', '.join(OPERATING_SETS[:-1])} or "
                        f"{OPERATING_SETS[-1]}")
        return problems
    if target is None:
        return problems
    if where == "realistic_calibration" and not get("realistic.enabled"):
        problems.append("detector.operating_set='realistic_calibration': needs realistic.enabled=true (its "
                        "calibration set is drawn like the realistic set); use detector.operating_set=calibration")
    if where in ("realistic", "both") and get("detector.inputs") != "code_and_mesh":
        problems.append(f"detector.operating_set={where!r}: needs detector.inputs=code_and_mesh (the realistic "
                        "training meshes are rows of its D_c only); use detector.operating_set=calibration")
    return problems
