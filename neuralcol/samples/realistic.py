"""Realistic mesh sets: meshes a user brings, built from a data set's own meshes and labeled exactly once, then read
from the cache beside the U(Z) test set (``<cache>/collision/<key>/<tag>_<hash>.npz``; the hash is of the build
settings, :func:`realistic_set`).

A run builds up to three of them, each a different set (other source meshes or another seed), each built and
labeled once per latent space and labeler:

* the realistic **test** set (``realistic``, tag ``realistic``): from every data set mesh, with the autoencoder's
  held-out meshes among the candidates; judged beside U(Z) by :mod:`neuralcol.stages.realistic`;
* the realistic **calibration** set (``realistic.calibration``, tag ``realistic_calibration``; only with
  ``detector.operating_set=realistic_calibration``): drawn like the test set with another seed and more
  candidates, its held-out meshes left out; the detector's operating point is set on it (:func:`calibration_meshes`);
* the realistic **training** meshes (``detector.geometry.train_set``, tag ``realistic_train``; a detector over code
  and mesh with ``detector.geometry.realistic_rows``): from the autoencoder's training meshes only, labeled in full
  (PD_i per sub-domain too) as rows of D_c (:func:`realistic_rows`).

The candidates (ACAP and vertex interpolations, perturbations) come from :mod:`neuralcol.data.realistic`. The sets
share no mesh except the data set's held-out poses, candidates of both the test and the calibration set (kept in the
first, left out of the second): on an empty cache those few meshes (the autoencoder's ``val_index``) are labeled once
for each set. The training meshes are labeled once, in full (:func:`realistic_rows`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from neuralcol.data.realistic import KINDS, RealisticMeshes, balanced_selection, clear_mask, make_realistic_meshes
from neuralcol.errors import UserInputError
from neuralcol.utils.config import as_dict
from neuralcol.utils.files import atomic_path
from neuralcol.utils.hashing import content_key, settings_key

BUILD_KEYS = ("seed", "n_acap_interp", "n_vertex_interp", "n_perturbed", "t_range", "perturb_scale", "clear_eps",
              "per_class")
LABEL_CLEARANCES = ("clear", "full")  # realistic.label_clearance


def pool_pd(pool, vertices: np.ndarray, desc: str | None = None, clearance_limit: float | None = None) -> np.ndarray:
    """Exact PD (n,) of meshes through a label pool; NaN where the labeler failed. ``clearance_limit``: free meshes'
    clearances measured only up to this length (PD >= -limit; :meth:`~neuralcol.collision.labeler.ExactLabeler.
    label_limited`); None: in full."""
    return _pd_of(_label_report(pool, vertices, desc, clearance_limit))


def _label_report(pool, vertices: np.ndarray, desc: str | None, clearance_limit: float | None):
    """The pool's label report of ``vertices`` (None when there are none)."""
    if len(vertices) == 0:
        return None
    if desc is not None:
        pool.desc = desc
    return pool.label_report(np.asarray(vertices, np.float64), clearance_limit=clearance_limit)


def _pd_of(report) -> np.ndarray:
    return np.zeros(0) if report is None else np.where(report.ok, report.labels.pd, np.nan)


def evaluation_limit(cfg, eps: float) -> float | None:
    """The clearance the realistic test and calibration sets (and their round trips) are labeled to:
    ``clear_eps * eps`` with ``label_clearance: clear``, the most that the clear-case rule and the verdicts read
    (a free mesh farther than that is clear either way; colliding meshes' PD is unchanged); None with ``full``
    or ``clear_eps: 0``. Labeling free meshes to the whole ``clearance_cap`` costs 1.4x (SCAPE) to 2.5x (anny_body)
    as much (docs/studies/operating_threshold.md)."""
    c = as_dict(cfg)
    how = str(c.get("label_clearance", "full"))
    if how not in LABEL_CLEARANCES:
        raise UserInputError(f"realistic.label_clearance={how!r}; use {' or '.join(LABEL_CLEARANCES)}")
    limit = float(c["clear_eps"]) * float(eps)
    return limit if how == "clear" and limit > 0 else None


def realistic_set(vertices, features, acap, heldout, pool, cfg, folder: str | Path, eps: float,
                  tag: str = "realistic", sources=None, clearance_limit: float | None = None,
                  keep_full_labels: bool = False) -> tuple[RealisticMeshes, np.ndarray, bool]:
    """The realistic meshes of a data set and their exact PD, built and labeled once, then read from the cache.

    The candidates (``n_acap_interp`` + ``n_vertex_interp`` + ``n_perturbed`` and the held-out meshes) are
    labeled, then :func:`~neuralcol.data.realistic.balanced_selection` keeps the held-out meshes and up to
    ``per_class`` clear colliding and as many clear free ones.

    Args:
        vertices, features, acap: the data set's meshes (N, V, 3), raw ACAP features (N, V, 9), ACAP transform.
        heldout: the autoencoder's held-out mesh indices.
        pool: label pool (its labeler's partition gives nothing here: only PD is kept).
        cfg: the ``realistic`` config (sizes, seed, ranges).
        folder: cache folder (the latent space's samples folder).
        eps: the labeler's boundary width (``clear_eps`` is in its units).
        tag: the cache file's prefix. sources: the data set rows ``vertices`` were taken from (recorded in the
            cache key; None: all).
        clearance_limit: the candidates' clearances are measured up to this length (:func:`evaluation_limit`;
            recorded in the cache key); None: in full.
        keep_full_labels: when the candidates are labeled now and in full, also save the kept meshes' full labels
            (PD_i per sub-domain too) where :func:`full_labels` reads them, so they are not labeled a second time.

    Returns:
        (meshes, pd (M,) float64 with NaN where the labeler failed, read from the cache).
    """
    c = as_dict(cfg)
    settings = {k: c[k] for k in BUILD_KEYS}
    settings["heldout"] = [int(i) for i in np.asarray(heldout).reshape(-1)]
    settings["eps"] = float(eps)
    if sources is not None:
        settings["sources"] = [int(i) for i in np.asarray(sources).reshape(-1)]
    if clearance_limit is not None:
        settings["clearance_limit"] = float(clearance_limit)
    key = settings_key(settings)
    path = Path(folder) / f"{tag}_{key}.npz"
    if path.is_file():
        with np.load(path) as z:
            return RealisticMeshes(z["vertices"], z["kind"], z["source"], z["t"]), z["pd"], True
    meshes = make_realistic_meshes(vertices, features, acap, heldout, int(c["n_acap_interp"]),
                                   int(c["n_vertex_interp"]), int(c["n_perturbed"]), tuple(c["t_range"]),
                                   float(c["perturb_scale"]), int(c["seed"]))
    report = _label_report(pool, meshes.vertices, "labeling realistic candidates", clearance_limit)
    pd = _pd_of(report)
    keep = balanced_selection(meshes.kind, pd, eps, float(c["clear_eps"]),  # clear_eps 0: every labeled mesh
                              None if c["per_class"] is None else int(c["per_class"]), int(c["seed"]))
    meshes, pd = RealisticMeshes(*(a[keep] for a in meshes)), pd[keep]
    if keep_full_labels and clearance_limit is None and report is not None:
        _save_full_labels(_full_labels_path(folder, meshes.vertices), np.asarray(report.ok, bool)[keep],
                          np.asarray(report.labels.pd, np.float64)[keep],
                          np.asarray(report.labels.pd_sub, np.float64)[keep])
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            # uncompressed: float64 vertices shrink by ~8 % under zlib, which took 7 s a set (0.25 s raw)
            np.savez(fh, **meshes._asdict(), pd=pd, settings=json.dumps(settings))
    return meshes, pd, False


def calibration_settings(cfg) -> dict:
    """The ``realistic`` config of the calibration set: ``seed + calibration.seed_offset``, the candidate counts
    times ``calibration.scale``, ``per_class = calibration.per_class``; everything else as the test set's."""
    c = as_dict(cfg)
    cal = dict(c.get("calibration") or {})
    missing = {"seed_offset", "scale", "per_class"} - set(cal)
    if missing:
        raise UserInputError(f"realistic.calibration: missing {sorted(missing)}; give seed_offset, scale and per_class "
                             "(conf/realistic/default.yaml)")
    per_class = cal["per_class"]
    if not (int(cal["seed_offset"]) != 0 and float(cal["scale"]) > 0 and (per_class is None or int(per_class) >= 1)):
        raise UserInputError(f"realistic.calibration={cal}: need seed_offset != 0 (another draw than the test set's), "
                             "scale > 0 and per_class >= 1 or null (every clear colliding mesh)")
    out = {**c, "seed": int(c["seed"]) + int(cal["seed_offset"]),
           "per_class": None if per_class is None else int(per_class)}
    for key in ("n_acap_interp", "n_vertex_interp", "n_perturbed"):
        out[key] = int(round(float(cal["scale"]) * int(c[key])))
    return out


def calibration_meshes(vertices, features, acap, heldout, pool, cfg, folder: str | Path,
                       eps: float) -> tuple[np.ndarray, np.ndarray]:
    """The realistic calibration set's clear meshes and exact verdicts, ``(vertices (C, V, 3), collides (C,))``:
    :func:`realistic_set` with :func:`calibration_settings` (cached as ``realistic_calibration_<key>.npz``), the
    held-out poses and unclear cases left out (the operating point is set and judged on clear cases)."""
    c = calibration_settings(cfg)
    meshes, pd, _ = realistic_set(vertices, features, acap, heldout, pool, c, folder, eps, tag="realistic_calibration",
                                  clearance_limit=evaluation_limit(c, eps))
    keep = np.isfinite(pd) & clear_mask(pd, eps, float(c["clear_eps"])) & (meshes.kind != KINDS.index("heldout"))
    return meshes.vertices[keep], pd[keep] > 0


class RealisticRows(NamedTuple):
    """M labeled realistic training meshes as D_c rows: z (M, D) float32 = encode(mesh), pd (M,), pd_sub (M, K),
    collides (M,), subset (M,) int8, vertices (M, V, 3) float64."""

    z: np.ndarray
    pd: np.ndarray
    pd_sub: np.ndarray
    collides: np.ndarray
    subset: np.ndarray
    vertices: np.ndarray


def encode_in_blocks(space, vertices: np.ndarray, block: int = 512) -> np.ndarray:
    """Meshes (M, V, 3) -> codes (M, D) float32, ``block`` meshes at a time."""
    out = [space.encode(torch.as_tensor(vertices[i:i + block], dtype=torch.float64)).detach().cpu().float()
           for i in range(0, len(vertices), block)]
    return torch.cat(out).numpy() if out else np.zeros((0, space.dim), np.float32)


def realistic_rows(space, vertices: np.ndarray, features: np.ndarray, acap, train_index, pool, train_set_cfg,
                   samples_dir: str | Path, eps: float) -> RealisticRows:
    """The realistic training meshes of the autoencoder's training meshes ``train_index``, labeled in full by
    ``pool`` (PD_i per sub-domain too) and encoded; meshes the labeler failed on or with PD exactly 0 are left out.

    Args:
        space: the latent space. vertices, features, acap: the data set's meshes, raw ACAP features, transform.
        train_index: the autoencoder's training meshes (the only sources). pool: label pool of the run's sample
            labeler. train_set_cfg: how many of each kind (``detector.geometry.train_set``). samples_dir: the latent
            space's samples cache. eps: the labeler's boundary width.
    """
    idx = np.asarray(train_index, dtype=np.int64)
    # labeled in full once: the candidates' labels of the kept meshes are their full labels (keep_full_labels)
    real, _, _ = realistic_set(np.asarray(vertices)[idx], np.asarray(features)[idx], acap, [], pool, train_set_cfg,
                               samples_dir, eps, tag="realistic_train", sources=idx, keep_full_labels=True)
    v = np.asarray(real.vertices, np.float64)
    if len(v) == 0:
        k = space.n_parts
        return RealisticRows(np.zeros((0, space.dim), np.float32), np.zeros(0), np.zeros((0, k)),
                             np.zeros(0, bool), np.zeros(0, np.int8), v)
    ok, pd, pd_sub = full_labels(pool, v, samples_dir)
    keep = ok & (np.nan_to_num(pd) != 0)
    pd = pd[keep]
    return RealisticRows(encode_in_blocks(space, v[keep]), pd, pd_sub[keep], pd > 0,
                         pool.labeler.subsets(pd).astype(np.int8), v[keep])


def full_labels(pool, vertices: np.ndarray, samples_dir: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The full exact labels (``ok`` (M,), PD (M,), PD_i (M, K)) of the realistic training meshes ``vertices``,
    labeled by ``pool`` once and then read from ``samples_dir`` (keyed by the labeler's settings, as that folder
    is, and by the meshes' bytes): every later run of the same latent space and settings skips the labeling
    (on anny_body ~0.4 s per mesh)."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    path = _full_labels_path(samples_dir, v)
    if path.is_file():
        with np.load(path, allow_pickle=False) as f:
            return f["ok"].astype(bool), f["pd"].astype(np.float64), f["pd_sub"].astype(np.float64)
    pool.desc = "labeling realistic training meshes"
    report = pool.label_report(v)
    ok = np.asarray(report.ok, bool)
    pd = np.asarray(report.labels.pd, np.float64)
    pd_sub = np.asarray(report.labels.pd_sub, np.float64)
    _save_full_labels(path, ok, pd, pd_sub)
    return ok, pd, pd_sub


def _full_labels_path(samples_dir: str | Path, vertices: np.ndarray) -> Path:
    """``realistic_train_full_<key>.npz``, keyed by the meshes' bytes and shape."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    return Path(samples_dir) / f"realistic_train_full_{content_key([v.tobytes(), str(v.shape).encode()])}.npz"


def _save_full_labels(path: Path, ok: np.ndarray, pd: np.ndarray, pd_sub: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, ok=ok, pd=pd, pd_sub=pd_sub)
