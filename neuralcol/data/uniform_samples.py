"""Labeled samples from U(Z), cached on disk and shared between runs.

Two uses: the fixed test set of every method and seed (paper sec. 5: samples from U(Z) unseen in training),
and the pool of uniform training samples of one seed (the baselines' D_c at every size, the bootstrap set and
the uniform half of each active round), so methods are compared on common random samples.

Row ``i`` of a store is a pure function of ``(seed, i)``: codes are drawn in blocks of :data:`BLOCK` rows, each
from its own generator seeded by ``(seed, block)``. Growing a store from 2000 to 4000 rows therefore gives the
same 4000 rows as labeling 4000 at once, and an interrupted labeling loses at most one chunk.

Stores are HDF5 files (:class:`~neuralcol.data.collision_store.CollisionStore`) guarded by a file lock, so
concurrent runs (a Hydra multirun with a parallel launcher) extend and read them safely.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from filelock import FileLock

from neuralcol.active.oracle import LatentOracle
from neuralcol.data.collision_store import ORIGIN_UNIFORM, CollisionRows, CollisionStore, StoreCorruptedError
from neuralcol.nn.latent_space import LatentSpace

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
        (rows, seconds spent labeling now, number of rows labeled now)
    """
    path = Path(path)
    space = oracle.space
    seconds, labeled = 0.0, 0
    path.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(str(path) + ".lock"), CollisionStore(path, space.dim, space.n_parts) as store:
        if "seed" not in store.attrs:
            store.attrs["seed"] = int(seed)
        elif int(store.attrs["seed"]) != int(seed):
            raise StoreCorruptedError(f"{path}: holds the uniform samples of seed {int(store.attrs['seed'])}, "
                                      f"not {seed}; delete it or point paths.cache_dir elsewhere")
        have = len(store)
        for a in range(have, n, LABEL_CHUNK):
            b = min(n, a + LABEL_CHUNK)
            lab = oracle(uniform_codes(space, seed, a, b), desc=f"{desc} [rows {a}:{b} of {n}]")
            store.append(lab.z, lab.pd, lab.pd_sub, lab.collides, lab.subset, 0, ORIGIN_UNIFORM)
            seconds += lab.seconds
            labeled += b - a
        return store.read(slice(0, n)), seconds, labeled
