"""Stage: the certified cascade: per target FNR, the band of doubt and what it does on the test sets.

The rule (:mod:`neuralcol.metrics.cascade`): the detector's verdict where its logit lies outside a band
``[lo, hi)``, the exact labeler inside it; the band is chosen on a calibration set to reach the target FNR with the
fewest exact calls, never less accurate than the detector alone (``detector.cascade.min_accuracy``).

* Calibration set: ``detector.cascade.calibration_size`` uniform codes from U(Z) of their own seed
  (``calibration_seed``), decoded and labeled exactly, cached beside the shared test set
  (``<cache>/collision/<key>/calibration_s<seed>.h5``; apart from the test set and from D_c, whose pools use
  other seeds). The final detector's logits on it and the labels are saved as ``<run dir>/cascade.npz``, so a
  finished run computes the band of any target (``run.detect(x, certify=0.01)``).
* Test sets: the band of each target applied to the U(Z) test set and to the realistic set (its clear cases,
  ``|PD| >= clear_eps * eps``, as ``realistic.detection``; the latent detector judges the encoded mesh, the
  exact label is the mesh's own). Both sets carry exact labels already, so the exact calls are simulated by
  reading them: that is exactly what the exact labeler returns for those rows.
* Throughput, measured in this process side by side: the detector's µs per sample at batch 4096
  (:func:`~neuralcol.stages.detector.inference_us`, torch's threads as the run has them) and the exact path's ms
  per sample (``timing_samples`` test codes decoded by the latent space, then the run's labeler ``.label`` one
  mesh at a time, one thread). A cascade costs ``t_det + exact_share * t_exact`` per sample (its exact share on
  the U(Z) test set): ``samples_per_s = 1 / that``, ``speedup_vs_exact = t_exact / that``.

``metrics.json`` → ``cascade`` (docs/cascade.md has the schema).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from neuralcol.handler.resolve import detector_logits
from neuralcol.metrics.cascade import DETECTOR, POINTWISE, Band, cascade_scores, choose_band
from neuralcol.metrics.detection import detection_metrics
from neuralcol.samples.cache import calibration_set
from neuralcol.samples.oracle import LatentOracle
from neuralcol.utils.config import as_dict
from neuralcol.utils.files import atomic_path


def cascade_problems(cfg) -> list[str]:
    """Problems of ``detector.cascade`` in a composed run config, as ``key=value: rule`` strings (empty: fine;
    no such block: nothing to check)."""
    det = cfg.get("detector") if cfg is not None else None
    c = None if det is None else det.get("cascade")
    if c is None:
        return []
    c = as_dict(c)
    problems: list[str] = []
    is_int = lambda v: isinstance(v, int) and not isinstance(v, bool)  # noqa: E731
    key = "detector.cascade"
    if not isinstance(c.get("enabled"), bool):
        problems.append(f"{key}.enabled={c.get('enabled')!r}: must be true or false")
    targets = c.get("targets")
    try:
        good = isinstance(targets, list) and len(targets) > 0 and all(
            not isinstance(t, bool) and 0.0 <= float(t) < 1.0 for t in targets)
    except (TypeError, ValueError):
        good = False
    if not good:
        problems.append(f"{key}.targets={targets!r}: must be a non-empty list of FNR targets in [0, 1), e.g. "
                        "[0.01, 0.02, 0.05]")
    for name in ("calibration_size", "timing_samples"):
        v = c.get(name)
        if not (is_int(v) and v >= 1):
            problems.append(f"{key}.{name}={v!r}: must be an integer >= 1")
    seed = c.get("calibration_seed")
    if not (is_int(seed) and seed >= 0):
        problems.append(f"{key}.calibration_seed={seed!r}: must be an integer >= 0")
    elif seed == det.get("test_seed"):
        problems.append(f"{key}.calibration_seed={seed!r}: must differ from detector.test_seed (the calibration "
                        "set must not be the test set)")
    conf = c.get("confidence")
    if conf is not None and not (isinstance(conf, float) and 0.0 < conf < 1.0):
        problems.append(f"{key}.confidence={conf!r}: a confidence level in (0, 1), e.g. 0.9, or null (the calibration "
                        "FNR alone)")
    if not isinstance(c.get("handler", False), bool):
        problems.append(f"{key}.handler={c.get('handler')!r}: must be true or false")
    m = c.get("min_accuracy")
    ok = m is None or m in (DETECTOR, POINTWISE) or (isinstance(m, (int, float)) and not isinstance(m, bool)
                                                     and 0 <= m <= 1)
    if not ok:
        problems.append(f"{key}.min_accuracy={m!r}: use {DETECTOR} (never less accurate than the detector alone on "
                        f"the calibration set), {POINTWISE} (on every sample), an accuracy floor in [0, 1], or null "
                        "(no floor: no exact call)")
    return problems


def save_calibration(path: str | Path, logits: np.ndarray, collides: np.ndarray, seed: int) -> None:
    """``cascade.npz``: the final detector's logits (N,) float32 on the calibration set, its exact labels (N,)
    bool and the set's seed."""
    with atomic_path(Path(path)) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, logit=np.asarray(logits, np.float32), collides=np.asarray(collides, bool),
                                seed=np.int64(seed))


def load_calibration(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(logits (N,) float64, collides (N,) bool) saved by :func:`save_calibration`."""
    with np.load(path) as z:
        return z["logit"].astype(np.float64), z["collides"].astype(bool)


def exact_ms_per_sample(space, labeler, z: np.ndarray) -> float:
    """Milliseconds per sample of the exact path on codes ``z`` (M, D): decode them with the latent space, then the
    labeler's ``.verdict`` (all an exact call of the cascade needs: collides or not, with an early exit) one mesh
    at a time, on one thread (torch's thread count restored after). One warm-up first (numba compiles on first use
    in a process)."""
    z = torch.as_tensor(np.asarray(z, np.float32))
    if len(z) == 0:
        raise ValueError("exact_ms_per_sample: no codes")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        dev = space.box_lo.device
        with torch.no_grad():
            labeler.verdict(space.decode(z[:1].to(dev)).double().cpu().numpy()[0])  # warm-up
            t0 = time.perf_counter()
            verts = space.decode(z.to(dev)).double().cpu().numpy()
            for v in verts:
                labeler.verdict(v)
            seconds = time.perf_counter() - t0
    finally:
        torch.set_num_threads(threads)
    return 1e3 * seconds / len(z)


def choose_bands(logits: np.ndarray, collides: np.ndarray, targets, min_accuracy=DETECTOR,
                 confidence: float | None = None) -> dict[float, Band]:
    """``{target: band}`` for each target FNR (:func:`~neuralcol.metrics.cascade.choose_band`)."""
    return {float(t): choose_band(logits, collides, float(t), min_accuracy, confidence) for t in targets}


def cascade_report(bands: dict[float, Band], calib_collides: np.ndarray, calib_seed: int,
                   test_logits: np.ndarray, test_collides: np.ndarray, detector_us: float, exact_ms: float,
                   realistic: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """``metrics["cascade"]`` (schema: docs/cascade.md) from the bands, the test sets and the two timings.

    Args:
        bands: ``{target FNR: band}``.
        calib_collides: (N,) the calibration set's exact labels. calib_seed: its seed.
        test_logits, test_collides: the final detector's logits on the U(Z) test set and their exact labels.
        detector_us: the detector's µs per sample at batch 4096. exact_ms: the exact path's ms per sample.
        realistic: (logits, collides) of the realistic set's clear cases, or None (no realistic set).
    """
    t_det, t_exact = 1e-6 * float(detector_us), 1e-3 * float(exact_ms)
    y_cal = np.asarray(calib_collides, bool)
    targets = []
    for t, b in bands.items():
        test = cascade_scores(test_logits, test_collides, b)
        cost = t_det + test["exact_share"] * t_exact
        targets.append({
            "target_fnr": float(t), "lo": float(b.lo), "hi": float(b.hi),
            "calibration": {"fnr": b.calib_fnr, "accuracy": b.calib_accuracy, "exact_share": b.calib_exact_share},
            "test": test,
            "realistic": None if realistic is None or len(realistic[0]) == 0 else
            cascade_scores(realistic[0], realistic[1], b),
            "samples_per_s": 1.0 / cost, "speedup_vs_exact": t_exact / cost})
    alone = detection_metrics(np.asarray(test_logits) > 0, np.asarray(test_collides, bool))
    return {"calibration": {"n": int(len(y_cal)), "seed": int(calib_seed), "base_rate": float(y_cal.mean())},
            "exact_ms_per_sample": float(exact_ms), "detector_us_per_sample": float(detector_us),
            "targets": targets,
            "detector_alone": {"test": {"fnr": float(alone["fnr"]), "accuracy": float(alone["accuracy"])},
                               "samples_per_s": 1.0 / t_det}}


def calibrate(net: torch.nn.Module, oracle: LatentOracle, det_cfg, latent_key: str, cache_dir: str | Path,
              path: str | Path,
              log: Callable[[str], None] | None = None) -> tuple[dict[float, Band] | None, np.ndarray]:
    """Label (or read) the calibration set, save the final detector's logits on it to ``path`` (``cascade.npz``)
    and choose the band of each ``detector.cascade.targets``: (``{target: band}``, the calibration labels); no
    bands (None, with a line to ``log``) when no calibration sample collides."""
    c = as_dict(det_cfg)["cascade"]
    rows, _, _ = calibration_set(oracle, det_cfg, latent_key, cache_dir)
    logits, collides = detector_logits(net, rows.z), np.asarray(rows.collides, bool)
    save_calibration(path, logits, collides, int(c["calibration_seed"]))
    if not collides.any():  # e.g. a tiny run whose U(Z) hardly collides: no FNR to certify, the run goes on
        if log is not None:
            log(f"[cascade] none of the {len(collides)} calibration samples collides: no band (the FNR is undefined); "
                "a larger detector.cascade.calibration_size may find colliding ones")
        return None, collides
    return choose_bands(logits, collides, c["targets"], c.get("min_accuracy", POINTWISE), c.get("confidence")), collides


def cascade_stage(net: torch.nn.Module, space, labeler, test, bands: dict[float, Band], calib_collides: np.ndarray,
                  det_cfg, detector_us: float, realistic_arrays: dict | None = None) -> dict:
    """``metrics["cascade"]``: the bands on the U(Z) test set (``test``: its rows) and on the realistic set's clear
    cases (``realistic_arrays``: :func:`~neuralcol.stages.realistic.evaluate_realistic`'s arrays, or None), with
    the exact path's time per sample measured here, next to ``detector_us``, the detector's µs per sample at batch
    4096 measured just before in the same process (``inference_us(net, test.z, (4096,))["batch_4096"]`` of
    :mod:`neuralcol.stages.detector`)."""
    c = as_dict(det_cfg)["cascade"]
    test_logits = detector_logits(net, test.z)
    exact_ms = exact_ms_per_sample(space, labeler, test.z[: int(c["timing_samples"])])
    realistic = None
    if realistic_arrays is not None:
        pd = np.asarray(realistic_arrays["pd"], np.float64)
        keep = np.asarray(realistic_arrays["clear"], bool) & np.isfinite(pd)
        realistic = (np.asarray(realistic_arrays["logit"])[keep], pd[keep] > 0)
    return cascade_report(bands, calib_collides, int(c["calibration_seed"]), test_logits, test.collides, detector_us,
                          exact_ms, realistic)
