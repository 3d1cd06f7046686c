"""The exact oracle of the active-learning loop: latent codes -> decoded meshes -> exact labels.

``I_c*(Z_all) = [PD(ACAP^-1(Z_all)) > 0]`` (paper sec. 4): each code is decoded by the latent space, the
mesh is labeled by the exact labeler through a :class:`~neuralcol.collision.pool.LabelPool`, and the PD
values are split into D_p / D_n / D_b (paper eq. 1) with the labeler's ``eps``.
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
import time
from typing import NamedTuple

import numpy as np
import torch

from neuralcol.collision.labeler import split_subsets
from neuralcol.collision.pool import LabelPool
from neuralcol.nn.latent_space import LatentSpace


class OracleLabels(NamedTuple):
    """Labels of B codes: z (B, D) float32, pd (B,), pd_sub (B, K), collides (B,) bool, subset (B,) int8
    (0 D_p, 1 D_n, 2 D_b); seconds spent decoding and labeling.

    Codes that could not be labeled (the decoded mesh has NaN/inf vertices, the labeler raised on it twice,
    its worker died or hung: see :mod:`neuralcol.collision.pool`) keep their row with ``ok`` False, ``pd`` and
    ``pd_sub`` NaN, ``collides`` False and ``subset`` -1, and are listed in ``failures`` as ``(index, reason)``.
    Such rows must never reach D_c: :meth:`without_failures` drops them. ``ok`` None means every row is
    labeled (e.g. an analytic test oracle).
    """

    z: np.ndarray
    pd: np.ndarray
    pd_sub: np.ndarray
    collides: np.ndarray
    subset: np.ndarray
    seconds: float
    ok: np.ndarray | None = None
    failures: tuple = ()

    @property
    def n_failed(self) -> int:
        """Number of codes that could not be labeled."""
        return len(self.failures) if self.ok is None else int(len(self.ok) - np.count_nonzero(self.ok))

    def without_failures(self) -> OracleLabels:
        """The labeled rows only (``failures`` is kept, with the indices of the original rows)."""
        if self.ok is None or self.ok.all():
            return self
        keep = np.asarray(self.ok, bool)
        return self._replace(z=self.z[keep], pd=self.pd[keep], pd_sub=self.pd_sub[keep],
                             collides=self.collides[keep], subset=self.subset[keep], ok=None)


class SpaceDecoder:
    """A latent space's decoder as the label pool's workers run it (:meth:`~neuralcol.collision.pool.LabelPool.
    label_codes_report`): codes (C, D) -> vertices (C, V, 3) float64, without gradients, on one torch thread per
    process (two workers on two cores). A chunk of one code is decoded as two rows and the first kept, so every
    code goes through the same batched product as in a chunk (a single row takes torch's matrix-vector path,
    which rounds differently)."""

    def __init__(self, space: LatentSpace):
        self.space = space
        self._pid = None

    def __call__(self, codes) -> np.ndarray:
        if self._pid != os.getpid():  # first call in this process: a pool's worker decodes on one thread
            self._pid = os.getpid()
            if multiprocessing.parent_process() is not None:
                torch.set_num_threads(1)
        z = torch.as_tensor(np.asarray(codes, np.float32)).to(self.space.box_lo)
        one = len(z) == 1
        if one:
            z = z.repeat(2, 1)
        with torch.no_grad():
            v = self.space.decode(z).cpu().numpy().astype(np.float64)
        return v[:1] if one else v

    def __getstate__(self):
        # the space as plain pickle bytes: multiprocessing's pickler would send its tensors through torch's shared
        # memory, and workers started with such tensors crashed in their first numba call (SIGSEGV)
        return {"space_bytes": pickle.dumps(self.space)}

    def __setstate__(self, state):
        self.space = pickle.loads(state["space_bytes"])
        self._pid = None


def training_clearance_limit(cap: float, pd_floor: float) -> float:
    """The clearance limit of labels for training: ``-pd_floor * cap`` grown by 1e-9 of itself, so that a capped
    clearance ``-limit`` divided by ``cap`` lands below ``pd_floor`` in floating point (clipped to it exactly)."""
    return -float(pd_floor) * float(cap) * (1.0 + 1e-9)


class LatentOracle:
    """Exact labels of latent codes.

    Args:
        space: the latent space (decoder, box, partition into sub-domains).
        pool: a label pool whose labeler uses ``space.partition`` (so ``pd_sub`` has K columns).
        decode_batch: codes decoded per batch by :meth:`decode` (the labels' codes are decoded chunk by chunk
            where they are labeled, :class:`SpaceDecoder`).
        clearance_limit: None: full labels; a length: clearances capped there, the labels for training whose
            clipped targets equal the full label's (:meth:`for_training`).
    """

    def __init__(self, space: LatentSpace, pool: LabelPool, decode_batch: int = 256,
                 clearance_limit: float | None = None, decoder: SpaceDecoder | None = None):
        if pool.labeler.n_parts != space.n_parts:
            raise ValueError(f"the pool's labeler has {pool.labeler.n_parts} parts but the latent space has "
                             f"{space.n_parts} sub-domains; build the labeler with partition=space.partition")
        self.space = space
        self.pool = pool
        self.decode_batch = int(decode_batch)
        self.clearance_limit = None if clearance_limit is None else float(clearance_limit)
        self.decoder = SpaceDecoder(space) if decoder is None else decoder  # run where the labels are made

    def for_training(self, pd_floor: float | None) -> LatentOracle:
        """This oracle's labels for training: clearances capped just beyond ``-pd_floor`` caps (the detector's
        targets are ``clip(pd / cap, pd_floor, pd_clip)``, so they are the full label's bit for bit while a free
        mesh costs about half; ``docs/studies/training_labels.md``). ``pd_floor`` None (targets without a lower
        bound): this oracle, full labels. Same pool, same space."""
        if pd_floor is None:
            return self
        if not float(pd_floor) < 0:
            raise ValueError(f"pd_floor={pd_floor} must be < 0 (detector.targets.pd_floor)")
        limit = training_clearance_limit(float(self.pool.labeler.cap), float(pd_floor))
        return LatentOracle(self.space, self.pool, self.decode_batch, clearance_limit=limit, decoder=self.decoder)

    @property
    def eps(self) -> float:
        return float(self.pool.labeler.eps)

    def decode(self, z: torch.Tensor) -> np.ndarray:
        """(B, D) codes -> (B, V, 3) float64 vertices."""
        with torch.no_grad():
            parts = [self.space.decode(c.to(self.space.box_lo)).cpu() for c in z.split(self.decode_batch)]
        return torch.cat(parts).numpy().astype(np.float64) if parts else np.zeros((0, 0, 3))

    def __call__(self, z: torch.Tensor, desc: str | None = None) -> OracleLabels:
        """Label (B, D) codes; ``desc`` names the progress bar. Every code keeps its row; the ones that could
        not be labeled have ``ok`` False (see :class:`OracleLabels`), and one warning line names them."""
        t0 = time.perf_counter()
        if desc is not None:
            self.pool.desc = desc
        z = torch.as_tensor(z, dtype=torch.float32)
        if len(z) == 0:
            k = self.space.n_parts
            return OracleLabels(np.zeros((0, self.space.dim), np.float32), np.zeros(0), np.zeros((0, k)),
                                np.zeros(0, bool), np.zeros(0, np.int8), 0.0, np.zeros(0, bool), ())
        # decoded where they are labeled (the pool's workers); NaN/inf decoded meshes are reported, not labeled
        report = self.pool.label_codes_report(z.numpy(), self.decoder, clearance_limit=self.clearance_limit)
        labels = report.labels
        subset = split_subsets(labels.pd, self.eps)
        subset[~report.ok] = -1
        return OracleLabels(z.cpu().numpy(), labels.pd, labels.pd_sub, labels.collides, subset,
                            time.perf_counter() - t0, report.ok, tuple(report.failures))
