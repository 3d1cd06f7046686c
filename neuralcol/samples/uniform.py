"""Labeled samples from U(Z), cached on disk and shared between runs.

Two uses: the fixed test set of every method and seed (paper sec. 5: samples from U(Z) unseen in training),
and the pool of uniform training samples of one seed (the baselines' D_c at every size, the bootstrap set and
the uniform half of each active round), so methods are compared on common random samples.

Code ``i`` of a seed's sequence is a pure function of ``(seed, i)``: codes are drawn in blocks of :data:`BLOCK`
rows, each from its own generator seeded by ``(seed, block)``. Row ``i`` of a store is the ``i``-th code of the
sequence that could be labeled: a code the labeler fails on (a NaN/inf decoded mesh, an exception, a worker
that dies or hangs on it: :mod:`neuralcol.collision.pool`) is dropped, counted (file attribute
``n_label_failures``) and replaced by the next codes, so a store always holds the rows asked for. The file
attribute ``n_codes`` is how many codes of the sequence were consumed (rows + failures). Without failures
(the normal case) row ``i`` is code ``i``. Growing a store from 2000 to 4000 rows therefore gives the same 4000
rows as labeling 4000 at once (as long as the failures are deterministic, e.g. not a one-off crash), and an
interrupted labeling loses at most one chunk.

Stores are HDF5 files (:class:`~neuralcol.samples.store.CollisionStore`) guarded by a file lock, so
concurrent runs (a Hydra multirun with a parallel launcher) extend and read them safely.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from filelock import FileLock

from neuralcol.nn.latent_space import LatentSpace
from neuralcol.samples.oracle import LatentOracle
from neuralcol.samples.store import CollisionRows, CollisionStore, Origin, StoreCorruptedError
from neuralcol.utils import sitting

BLOCK = 1024
LABEL_CHUNK = 2048  # rows labeled and committed together


def uniform_codes(space: LatentSpace, seed: int, start: int, stop: int) -> torch.Tensor:
    """Rows ``start:stop`` of the seed's sequence of codes from U(Z), (stop - start, D) float32 (CPU)."""
    if not 0 <= start <= stop:
        raise ValueError(f"uniform_codes: need 0 <= start <= stop, got {start}, {stop}")
    lo, hi = space.box_lo.detach().cpu().float(), space.box_hi.detach().cpu().float()
    out = []
    for block in range(start // BLOCK, (stop + BLOCK - 1) // BLOCK):
        state = np.random.SeedSequence([int(seed), block]).generate_state(2, dtype=np.uint32)
        gen = torch.Generator().manual_seed(int(state[0]) << 32 | int(state[1]))
        u = torch.rand(BLOCK, space.dim, generator=gen)
        a, b = max(start, block * BLOCK) - block * BLOCK, min(stop, (block + 1) * BLOCK) - block * BLOCK
        out.append(lo + u[a:b] * (hi - lo))
    return torch.cat(out) if out else torch.zeros(0, space.dim)


class UniformRows(NamedTuple):
    """Result of :func:`uniform_rows`: the rows, seconds spent labeling now, rows labeled now, and codes
    dropped now because they could not be labeled."""

    rows: CollisionRows
    seconds: float
    labeled: int
    n_failed: int


def labeled_uniform_rows(path: str | os.PathLike, oracle: LatentOracle, n: int, seed: int,
                         desc: str = "labeling U(Z)") -> tuple[CollisionRows, float, int]:
    """The first ``n`` rows of the cached store at ``path``, labeling the missing ones.

    Args:
        path: the store (``.h5``; created if missing; ``<path>.lock`` guards it).
        oracle: decodes and labels codes.
        n: rows wanted.
        seed: the sequence's seed (stored in the file; a mismatch is an error).
        desc: progress-bar label.

    Returns:
        (rows, seconds spent labeling now, number of rows labeled now); :func:`uniform_rows` also gives the
        number of codes dropped because they could not be labeled.
    """
    rows, seconds, labeled, _ = uniform_rows(path, oracle, n, seed, desc)
    return rows, seconds, labeled


def uniform_rows(path: str | os.PathLike, oracle: LatentOracle, n: int, seed: int,
                 desc: str = "labeling U(Z)") -> UniformRows:
    """:func:`labeled_uniform_rows` with the number of codes that failed to label now (dropped, replaced by
    further codes of the sequence; never written to the store).

    Raises:
        RuntimeError: more than half of the codes labeled in this call (plus 8) failed: a broken labeler or
            decoder, not isolated faults; the rows labeled so far are kept.
    """
    path = Path(path)
    space = oracle.space
    seconds, labeled, failed, consumed = 0.0, 0, 0, 0
    path.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(str(path) + ".lock"), CollisionStore(path, space.dim, space.n_parts) as store:
        if "seed" not in store.attrs:
            store.attrs["seed"] = int(seed)
        elif int(store.attrs["seed"]) != int(seed):
            raise StoreCorruptedError(f"{path}: holds the uniform samples of seed {int(store.attrs['seed'])}, "
                                      f"not {seed}; delete it or point paths.cache_dir elsewhere")
        limit = getattr(oracle, "clearance_limit", None)
        limit = -1.0 if limit is None else float(limit)  # -1: full labels
        if "clearance_limit" not in store.attrs:
            if len(store) and limit != -1.0:
                raise StoreCorruptedError(f"{path}: holds full labels (written by an older version), not labels with "
                                          f"clearances capped at {limit:g}; delete it or point paths.cache_dir "
                                          "elsewhere")
            store.attrs["clearance_limit"] = limit
        elif float(store.attrs["clearance_limit"]) != limit:
            held = float(store.attrs["clearance_limit"])
            raise StoreCorruptedError(f"{path}: holds labels with clearance limit {held:g} (-1: full), not {limit:g}; "
                                      "delete it or point paths.cache_dir elsewhere")
        if "n_codes" not in store.attrs:  # a new store, or one written before failures were counted
            store.attrs["n_codes"], store.attrs["n_label_failures"] = len(store), 0
        n_codes, n_fail = int(store.attrs["n_codes"]), int(store.attrs["n_label_failures"])
        if len(store) > n_codes - n_fail:  # died between committing rows and counting their codes: relabel them
            store.truncate(n_codes - n_fail)
        elif len(store) < n_codes - n_fail:
            raise StoreCorruptedError(f"{path}: {len(store)} rows but {n_codes} codes consumed with {n_fail} "
                                      "failures; delete it to label it again")
        while len(store) < n:
            a = n_codes
            b = a + min(LABEL_CHUNK, n - len(store))
            have = len(store)
            lab = oracle(uniform_codes(space, seed, a, b), desc=f"{desc} [rows {have}:{have + b - a} of {n}]")
            good = lab.without_failures()
            store.append(good.z, good.pd, good.pd_sub, good.collides, good.subset, 0, Origin.UNIFORM)
            n_codes, n_fail = b, n_fail + lab.n_failed
            store.attrs["n_codes"], store.attrs["n_label_failures"] = n_codes, n_fail
            seconds += lab.seconds
            labeled += len(good.z)
            failed += lab.n_failed
            consumed += b - a
            if failed > 8 + consumed // 2:
                raise RuntimeError(f"{path}: {failed} of the {consumed} codes labeled now could not be labeled "
                                   "(see the warnings above); the labeler or the decoder is broken")
            if len(store) < n:  # a committed batch: a safe point of a time-budgeted sitting (max_minutes)
                sitting.check(f"labeling {path.name} ({len(store)} of {n} rows)")
        return UniformRows(store.read(slice(0, n)), seconds, labeled, failed)
