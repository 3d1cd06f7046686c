"""D_c as a LightningDataModule: an append-only HDF5 store served as in-memory tensors.

The module owns the store (:class:`~neuralcol.samples.store.CollisionStore`): rows are appended
between training epochs (:meth:`CollisionDataModule.append`), the tensors are re-read, and the trainer picks
the new data up at the next epoch (``reload_dataloaders_every_n_epochs=1``). The train/validation split is
the store's id-based 80/20 split, so it stays stable as D_c grows.

Targets handed to the model: ``z`` (B, D), ``pd`` (B,) and ``pd_sub`` (B, K) in units of ``pd_unit`` (the
labeler's clearance cap, so collision-free depths lie in [-1, 0]) clipped to ``[pd_floor, pd_clip]``, and the
subset code (B,) (0 D_p, 1 D_n, 2 D_b). With ``use_boundary_set=False`` (the ``supv`` baseline) there is no
D_b: colliding rows are D_p and the others D_n.
"""

from __future__ import annotations

import os

import lightning as L
import numpy as np
import torch
from torch.utils.data import BatchSampler, DataLoader, Sampler, SequentialSampler, TensorDataset

from neuralcol.collision.labeler import SUBSET_NEGATIVE, SUBSET_POSITIVE
from neuralcol.samples.store import CollisionRows, CollisionStore


def detector_targets(rows: CollisionRows, pd_unit: float, pd_clip: float,
                     use_boundary_set: bool = True, pd_floor: float | None = None) -> tuple[torch.Tensor, ...]:
    """Rows -> (z (B, D) float32, pd (B,), pd_sub (B, K), subset (B,) long) tensors (see the module doc).

    ``pd_floor < 0 < pd_clip`` bound the scaled PD targets (``pd_floor=None``: no lower bound; the labeler's
    free depths are >= -1, the cap, anyway). A narrow band (e.g. +-0.25) keeps the regression terms about the
    boundary, where the sign is decided (docs/studies/diagnosis_scape.md, cause 5)."""
    if pd_unit <= 0 or pd_clip <= 0 or (pd_floor is not None and pd_floor >= 0):
        raise ValueError(f"pd_unit={pd_unit} and pd_clip={pd_clip} must be > 0 and pd_floor={pd_floor} < 0")
    low = -np.inf if pd_floor is None else float(pd_floor)
    pd = np.clip(np.asarray(rows.pd, np.float64) / pd_unit, low, pd_clip)
    pd_sub = np.clip(np.asarray(rows.pd_sub, np.float64) / pd_unit, low, pd_clip)
    subset = np.asarray(rows.subset, np.int64)
    if not use_boundary_set:
        subset = np.where(np.asarray(rows.collides, bool), SUBSET_POSITIVE, SUBSET_NEGATIVE)
    return (torch.as_tensor(np.asarray(rows.z, np.float32)), torch.as_tensor(pd, dtype=torch.float32),
            torch.as_tensor(pd_sub, dtype=torch.float32), torch.as_tensor(subset, dtype=torch.long))


class EpochShuffle(Sampler[int]):
    """Random order of ``n`` rows drawn from ``(seed, epoch())`` when iteration starts, so the order of an epoch
    does not depend on when the loader was built (a resumed fit builds it before its first epoch starts)."""

    def __init__(self, n: int, seed: int, epoch):
        self.n, self.seed, self.epoch = int(n), int(seed), epoch

    def __len__(self) -> int:
        return self.n

    def __iter__(self):
        gen = torch.Generator().manual_seed(self.seed * 1_000_003 + int(self.epoch()))
        return iter(torch.randperm(self.n, generator=gen).tolist())


def batched_loader(tensors: tuple[torch.Tensor, ...], sampler: Sampler[int], batch_size: int) -> DataLoader:
    """The batches of ``DataLoader(TensorDataset(*tensors), batch_size, sampler=sampler)``, each taken with one
    index per tensor instead of row by row and collated (same values and order; row by row cost about 30 % of a
    SCAPE training round: 42.5 s against 28-31 s at 12 000 rows)."""
    return DataLoader(TensorDataset(*tensors), batch_size=None,
                      sampler=BatchSampler(sampler, int(batch_size), drop_last=False))


class CollisionDataModule(L.LightningDataModule):
    """D_c for the detector.

    Args:
        path: HDF5 file of D_c (created if missing; an existing one is continued).
        latent_dim: D = |Z_all|.
        n_parts: K = |Z_0|.
        batch_size: training batch size (may be changed between epochs, e.g. 512 -> 1024 when fine-tuning).
        pd_unit: length that PD targets are divided by (> 0).
        pd_clip: upper clip of the scaled PD targets.
        pd_floor: lower clip of the scaled PD targets (< 0), or None for none.
        use_boundary_set: keep D_b (``supv_bd``, ``active``) or fold it into D_p (``supv``).
        n_pairs: P, the contact pairs whose features each row keeps (0: none; a detector that reads codes only).
        seed: shuffling seed (the order of epoch e depends on ``(seed, e)`` only, so resumed runs replay it).
        val_batch_size: validation batch size; None (default): the training batch size at the time, so the
            validation losses are those of the batches training sees (the ranking term compares the rows of one
            batch: at 8192 rows, the earlier size, it made validation 8x slower than at 1024 on SCAPE and
            most of a paper-scale epoch; the accuracy does not depend on it).
        featurize: ``codes (B, D) -> pair features (B, P, 3)`` of the meshes they decode to, computed for rows
            appended without features (the labeled samples of every round), so training never decodes.
    """

    def __init__(self, path: str | os.PathLike, latent_dim: int, n_parts: int, batch_size: int, pd_unit: float,
                 pd_clip: float, use_boundary_set: bool = True, seed: int = 0, val_batch_size: int | None = None,
                 pd_floor: float | None = None, n_pairs: int = 0, featurize=None):
        super().__init__()
        if batch_size < 1:
            raise ValueError(f"batch_size={batch_size} must be >= 1")
        if val_batch_size is not None and val_batch_size < 1:
            raise ValueError(f"val_batch_size={val_batch_size} must be >= 1 (or None: the training batch size)")
        self.store = CollisionStore(path, latent_dim, n_parts, n_pairs)
        self.batch_size = int(batch_size)
        self.val_batch_size = None if val_batch_size is None else int(val_batch_size)
        self.pd_unit = float(pd_unit)
        self.pd_clip = float(pd_clip)
        self.pd_floor = None if pd_floor is None else float(pd_floor)
        self.use_boundary_set = bool(use_boundary_set)
        self.seed = int(seed)
        self.featurize = featurize
        self._train: tuple[torch.Tensor, ...] | None = None
        self._val: tuple[torch.Tensor, ...] | None = None

    def __len__(self) -> int:
        return len(self.store)

    def append(self, z, pd, pd_sub, collides, subset, round_: int, origin, geometry=None) -> np.ndarray:
        """Append labeled rows (with their pair features in a store that keeps them) to D_c (crash-safe) and
        reload the tensors; returns the new row ids. Rows without features get ``featurize``'s of their codes."""
        if geometry is None and self.featurize is not None:
            geometry = self.featurize(np.asarray(z, np.float32))
        ids = self.store.append(z, pd, pd_sub, collides, subset, round_, origin, geometry)
        self.refresh()
        return ids

    def refresh(self) -> None:
        """Re-read the committed rows into the train and validation tensors."""
        rows = self.store.read()
        val = self.store.split_mask()
        tensors = detector_targets(rows, self.pd_unit, self.pd_clip, self.use_boundary_set, self.pd_floor)
        if rows.geometry is not None:  # batches become (z, pd, pd_sub, subset, pair features)
            tensors = (*tensors, torch.as_tensor(rows.geometry, dtype=torch.float32))
        self._train = tuple(t[torch.as_tensor(~val)] for t in tensors)
        self._val = tuple(t[torch.as_tensor(val)] for t in tensors)

    def setup(self, stage: str | None = None) -> None:
        self.refresh()

    @property
    def n_train(self) -> int:
        return 0 if self._train is None else len(self._train[0])

    def train_dataloader(self) -> DataLoader:
        if self._train is None:
            self.refresh()
        if self.n_train == 0:
            raise RuntimeError(f"{self.store.path}: D_c has no training rows yet")
        sampler = EpochShuffle(self.n_train, self.seed,
                               lambda: self.trainer.current_epoch if self.trainer is not None else 0)
        return batched_loader(self._train, sampler, self.batch_size)

    def val_dataloader(self) -> DataLoader:
        if self._val is None:
            self.refresh()
        size = self.batch_size if self.val_batch_size is None else self.val_batch_size
        return batched_loader(self._val, SequentialSampler(range(len(self._val[0]))), size)

    def close(self) -> None:
        self.store.close()
