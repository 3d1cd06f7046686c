"""Realistic meshes: the kind of meshes a user brings, for evaluation beside U(Z).

The paper measures everything on U(Z), codes drawn from the latent box and decoded. A user brings meshes
instead. This module builds, per data set, meshes nobody trained on, each derived from the data set's own
poses so they are plausible for its topology:

* ``heldout``: the autoencoder's held-out meshes themselves;
* ``acap_interp``: ACAP-feature interpolations ``(1 - t) f_i + t f_j`` between two data set meshes, decoded, with
  ``t`` in ``t_range`` (slightly beyond the pair on both sides); ACAP makes these plausible poses;
* ``vertex_interp``: vertex interpolations ``(1 - t) v_i + t v_j`` (limbs shorten where the poses differ: the
  kind of blend a user gets from a naive animation tool);
* ``perturbed``: held-out meshes moved a little along the difference of two other poses,
  ``f_h + s (f_j - f_k)`` with ``|s| <= perturb_scale``, decoded.

:func:`make_realistic_meshes` is pure (seeded, no labels); :func:`clear_mask` picks the clear cases (exact PD
at least ``clear_eps`` boundary widths away from 0 on either side), on which the acceptance numbers are read.
Collisions are rare among plain interpolations (proc_hand: 1-2 % for ``t`` in [0, 1], 20-30 % near ``t = -0.6`` or
``1.6``), so the candidates span wide ranges and :func:`balanced_selection` keeps as many clear colliding as clear
free meshes: accuracy on the set then weighs missed and false collisions alike (its majority class is ~0.5).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

KINDS = ("heldout", "acap_interp", "vertex_interp", "perturbed")


class RealisticMeshes(NamedTuple):
    """M meshes built from a data set.

    Attributes:
        vertices: (M, V, 3) float64.
        kind: (M,) int8 index into :data:`KINDS`.
        source: (M, 3) int64 data set meshes each is made from (i, j, k; -1 where unused).
        t: (M,) float64 interpolation parameter (interpolations), perturbation step ``s`` (perturbed), 0
            (held out).
    """

    vertices: np.ndarray
    kind: np.ndarray
    source: np.ndarray
    t: np.ndarray


def _pairs(rng: np.random.Generator, n_meshes: int, n: int) -> np.ndarray:
    """(n, 2) random ordered pairs of distinct mesh indices."""
    i = rng.integers(0, n_meshes, n)
    j = (i + rng.integers(1, n_meshes, n)) % n_meshes
    return np.stack([i, j], 1)


def make_realistic_meshes(vertices, features, acap, heldout, n_acap_interp: int, n_vertex_interp: int,
                          n_perturbed: int, t_range=(-0.25, 1.25), perturb_scale: float = 0.25, seed: int = 0,
                          batch: int = 64) -> RealisticMeshes:
    """Build the realistic meshes of a data set (no labels).

    Args:
        vertices: (N, V, 3) the data set's meshes (N >= 2).
        features: (N, V, 9) their raw ACAP features (``acap.encode(vertices)``).
        acap: the :class:`~neuralcol.geometry.acap.ACAP` transform the features belong to.
        heldout: indices of the autoencoder's held-out meshes (may be empty: then the perturbations start from
            any mesh).
        n_acap_interp, n_vertex_interp, n_perturbed: how many of each kind.
        t_range: interpolation parameters are drawn uniformly from it.
        perturb_scale: the largest ``|s|`` of a perturbation.
        seed: seeds every draw.
        batch: meshes decoded together.

    Returns:
        :class:`RealisticMeshes`, the held-out meshes first, then the kinds in the order of :data:`KINDS`.
    """
    v = torch.as_tensor(np.asarray(vertices), dtype=torch.float64)
    f = torch.as_tensor(np.asarray(features), dtype=torch.float64)
    n = len(v)
    if n < 2 or f.shape[:2] != v.shape[:2]:
        raise ValueError(f"make_realistic_meshes: need >= 2 meshes with features of the same shape, got vertices "
                         f"{tuple(v.shape)} and features {tuple(f.shape)}")
    lo, hi = (float(x) for x in t_range)
    if not lo < hi:
        raise ValueError(f"t_range={t_range}: need lo < hi")
    held = np.asarray(heldout, dtype=np.int64).reshape(-1)
    if held.size and (held.min() < 0 or held.max() >= n):
        raise ValueError(f"heldout indices must lie in [0, {n})")
    rng = np.random.default_rng(seed)
    out_v, kinds, sources, ts = [], [], [], []

    def add(verts: torch.Tensor, kind: str, src: np.ndarray, t: np.ndarray) -> None:
        out_v.append(verts.numpy())
        kinds.append(np.full(len(t), KINDS.index(kind), np.int8))
        sources.append(np.asarray(src, np.int64))
        ts.append(np.asarray(t, np.float64))

    def decode(make_feats, m: int) -> torch.Tensor:
        """Decode ``m`` feature rows made ``batch`` at a time by ``make_feats(rows)``: the features of all candidates
        at once would take 9 doubles per vertex per mesh (2.2 GB for 12 000 meshes of 2 500 vertices)."""
        with torch.no_grad():
            return torch.cat([acap.decode(make_feats(slice(i, i + batch))) for i in range(0, m, batch)]) if m \
                else v[:0]

    add(v[torch.as_tensor(held)], "heldout", np.stack([held, -np.ones_like(held), -np.ones_like(held)], 1),
        np.zeros(len(held)))
    pairs = _pairs(rng, n, int(n_acap_interp))
    t = rng.uniform(lo, hi, len(pairs))
    tt = torch.as_tensor(t)[:, None, None]
    add(decode(lambda r: (1 - tt[r]) * f[pairs[r, 0]] + tt[r] * f[pairs[r, 1]], len(pairs)), "acap_interp",
        np.concatenate([pairs, -np.ones((len(pairs), 1), np.int64)], 1), t)
    pairs = _pairs(rng, n, int(n_vertex_interp))
    t = rng.uniform(lo, hi, len(pairs))
    tt = torch.as_tensor(t)[:, None, None]
    add((1 - tt) * v[pairs[:, 0]] + tt * v[pairs[:, 1]], "vertex_interp",
        np.concatenate([pairs, -np.ones((len(pairs), 1), np.int64)], 1), t)
    base = rng.choice(held if held.size else np.arange(n), int(n_perturbed))
    jk = _pairs(rng, n, int(n_perturbed))
    s = rng.uniform(-perturb_scale, perturb_scale, len(base))
    ss = torch.as_tensor(s)[:, None, None]
    add(decode(lambda r: f[base[r]] + ss[r] * (f[jk[r, 0]] - f[jk[r, 1]]), len(base)), "perturbed",
        np.concatenate([base[:, None], jk], 1), s)
    return RealisticMeshes(np.concatenate(out_v).astype(np.float64, copy=False), np.concatenate(kinds),
                           np.concatenate(sources), np.concatenate(ts))


def clear_mask(pd: np.ndarray, eps: float, clear_eps: float) -> np.ndarray:
    """(M,) bool: labeled (finite PD) and clear of the boundary, ``|PD| >= clear_eps * eps``."""
    pd = np.asarray(pd, np.float64)
    return np.isfinite(pd) & (np.abs(pd) >= float(clear_eps) * float(eps))


def out_of_box(z: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray) -> np.ndarray:
    """(M,) bool: the code leaves the latent box Z in at least one entry."""
    z = np.asarray(z, np.float64)
    return ((z < np.asarray(box_lo)[None]) | (z > np.asarray(box_hi)[None])).any(-1)


def balanced_selection(kind: np.ndarray, pd: np.ndarray, eps: float, clear_eps: float, per_class: int | None,
                       seed: int = 0) -> np.ndarray:
    """Indices of an evaluation set with as many clear colliding as clear free meshes.

    Every held-out mesh is kept (labeled or not, clear or not: they are the data set's own poses). Of the
    others, only clear cases are kept: ``min(per_class, #colliding, #free)`` of each class drawn at random
    (``per_class`` None: as many as the smaller class has).

    Args:
        kind: (M,) kinds (:data:`KINDS` indices). pd: (M,) exact PD (NaN: unlabeled).
        eps, clear_eps: clear cases have ``|PD| >= clear_eps * eps``.
        per_class: the most meshes kept per class.
        seed: seeds the draw.

    Returns:
        (S,) sorted int64 indices.
    """
    kind = np.asarray(kind)
    pd = np.asarray(pd, np.float64)
    held = np.flatnonzero(kind == KINDS.index("heldout"))
    clear = clear_mask(pd, eps, clear_eps) & (kind != KINDS.index("heldout"))
    pos, neg = np.flatnonzero(clear & (pd > 0)), np.flatnonzero(clear & (pd < 0))
    k = min(len(pos), len(neg)) if per_class is None else min(int(per_class), len(pos), len(neg))
    rng = np.random.default_rng(seed)
    keep = [held, rng.choice(pos, k, replace=False), rng.choice(neg, k, replace=False)]
    return np.sort(np.concatenate(keep).astype(np.int64))
