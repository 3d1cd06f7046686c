"""D_c on disk: an append-only HDF5 store of labeled latent codes (paper sec. 4, D_c = D_p u D_n u D_b).

Columns (N rows): ``id`` int64 (0, 1, 2, ... in append order), ``z`` (N, D) float32, ``pd`` float32,
``pd_sub`` (N, K) float32, ``collides`` int8, ``subset`` int8 (0 D_p, 1 D_n, 2 D_b), ``round`` int16 (the
active-learning round that added the row; 0 = bootstrap), ``origin`` int8 (0 uniform sample from U(Z),
1 projected onto the detector's boundary); for a detector that reads the mesh too, ``geometry``
(N, P, 3) float32: the contact-pair features of each row's mesh, computed when the row is labeled, so training never
decodes again (a store is created with or without it; the file attribute ``geometry_pairs`` is P).

Integrity: every column is stored with HDF5's fletcher32 checksum per chunk, so a corrupted or truncated
file fails on open or read with :class:`StoreCorruptedError` naming it.

Crash safety: rows are written past the committed length, flushed, and only then is the file attribute
``committed`` advanced and flushed again. A reader sees exactly the committed rows, so a crash in the middle
of an append leaves every earlier round intact (the partial rows are overwritten by the next append).

The train/validation split is a pure function of the row id (``id % 5 == 4`` -> validation, 20%), so it
stays stable as the store grows.
"""

from __future__ import annotations

import os
from enum import IntEnum
from pathlib import Path
from typing import NamedTuple

import numpy as np

from neuralcol.errors import UserInputError
from neuralcol.utils.faults import fault_point


class Origin(IntEnum):
    """Where a D_c row came from (the store's ``origin`` column, int8)."""

    UNIFORM = 0  # a uniform sample of the box Z
    PROJECTED = 1  # picked by the active acquisition (projected or most uncertain)
    REALISTIC = 2  # a realistic training mesh: code = encode(mesh), pair features of the mesh itself


VAL_EVERY = 5  # row ids with id % 5 == 4 are validation rows (20 %)


class CollisionRows(NamedTuple):
    """A block of D_c rows (any length B): z (B, D), pd (B,), pd_sub (B, K), collides (B,), subset (B,),
    round (B,), origin (B,), id (B,)."""

    z: np.ndarray
    pd: np.ndarray
    pd_sub: np.ndarray
    collides: np.ndarray
    subset: np.ndarray
    round: np.ndarray
    origin: np.ndarray
    id: np.ndarray
    geometry: np.ndarray | None = None  # (B, P, 3) pair features, stores with geometry only

    def select(self, index) -> CollisionRows:
        """The rows ``index`` (a slice, mask or indices) of every column (``geometry`` stays None if absent)."""
        return CollisionRows(*(None if col is None else col[index] for col in self))


_COLUMNS = {"z": np.float32, "pd": np.float32, "pd_sub": np.float32, "collides": np.int8, "subset": np.int8,
            "round": np.int16, "origin": np.int8, "id": np.int64}


class StoreCorruptedError(UserInputError):
    """The HDF5 file of D_c cannot be read or is inconsistent; the message names it."""


class CollisionStore:
    """Append-only HDF5 store of D_c.

    Args:
        path: the ``.h5`` file (created if missing).
        latent_dim: D.
        n_parts: K.
        n_pairs: P, the contact pairs whose features each row keeps (a store created with P > 0 has the
            ``geometry`` column); 0: none; None: whatever an existing store holds (readers).
    """

    def __init__(self, path: str | os.PathLike, latent_dim: int, n_parts: int, n_pairs: int | None = 0):
        import h5py

        self.path = Path(path)
        self.latent_dim = int(latent_dim)
        self.n_parts = int(n_parts)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._h5 = h5py.File(self.path, "a")
        except OSError as exc:
            raise StoreCorruptedError(f"{self.path}: cannot be opened as HDF5 ({exc}); move it away to start "
                                      "a new D_c, or restore it from a backup") from exc
        if "z" not in self._h5:
            for name, dtype in _COLUMNS.items():
                shape = {"z": (0, self.latent_dim), "pd_sub": (0, self.n_parts)}.get(name, (0,))
                maxshape = (None,) + shape[1:]
                chunks = (4096,) + shape[1:]
                # fletcher32: a checksum per chunk, so corrupted bytes fail the read instead of passing as data
                self._h5.create_dataset(name, shape=shape, maxshape=maxshape, dtype=dtype, chunks=chunks,
                                        fletcher32=True)
            if n_pairs:
                self._h5.create_dataset("geometry", shape=(0, int(n_pairs), 3), maxshape=(None, int(n_pairs), 3),
                                        dtype=np.float32, chunks=(256, int(n_pairs), 3), fletcher32=True)
            self._h5.attrs["geometry_pairs"] = int(n_pairs or 0)
            self._h5.attrs["committed"] = 0
            self._h5.flush()
        self.n_pairs = int(self._h5.attrs.get("geometry_pairs", 0))
        if n_pairs is not None and int(n_pairs) != self.n_pairs:
            self.close()
            raise StoreCorruptedError(
                f"{self.path}: keeps the features of {self.n_pairs} contact pairs per row, expected {int(n_pairs)}; "
                "it belongs to another detector (move it away to start a new D_c)")
        self._check()

    def _check(self) -> None:
        h5 = self._h5
        missing = [c for c in _COLUMNS if c not in h5]
        if missing or "committed" not in h5.attrs:
            raise StoreCorruptedError(f"{self.path}: not a D_c store (missing {missing or ['committed']})")
        if h5["z"].shape[1] != self.latent_dim or h5["pd_sub"].shape[1] != self.n_parts:
            raise StoreCorruptedError(
                f"{self.path}: holds codes of size {h5['z'].shape[1]} and {h5['pd_sub'].shape[1]} parts, expected "
                f"{self.latent_dim} and {self.n_parts}; it belongs to another latent space")
        n = int(h5.attrs["committed"])
        short = [c for c in self._columns() if h5[c].shape[0] < n]
        if short:
            raise StoreCorruptedError(f"{self.path}: columns {short} are shorter than the committed {n} rows "
                                      "(truncated file)")

    @property
    def attrs(self):
        """The HDF5 file's attributes (e.g. what the rows are: ``kind``, ``seed``); write JSON-able scalars."""
        return self._h5.attrs

    def __len__(self) -> int:
        return int(self._h5.attrs["committed"])

    def _columns(self) -> dict:
        return {**_COLUMNS, "geometry": np.float32} if self.n_pairs else _COLUMNS

    def append(self, z, pd, pd_sub, collides, subset, round_: int, origin, geometry=None) -> np.ndarray:
        """Append B labeled rows (with their pair features ``geometry`` (B, P, 3) in a store that keeps them);
        returns their ids (B,). Crash-safe (see the module docstring)."""
        z = np.asarray(z, dtype=np.float32)
        b = len(z)
        if z.shape != (b, self.latent_dim):
            raise ValueError(f"z has shape {z.shape}, expected (B, {self.latent_dim})")
        cols = {"z": z, "pd": np.asarray(pd), "pd_sub": np.asarray(pd_sub), "collides": np.asarray(collides),
                "subset": np.asarray(subset), "round": np.full(b, round_),
                "origin": np.broadcast_to(np.asarray(origin), (b,))}
        if cols["pd_sub"].shape != (b, self.n_parts):
            raise ValueError(f"pd_sub has shape {cols['pd_sub'].shape}, expected ({b}, {self.n_parts})")
        for name in ("pd", "collides", "subset"):
            if cols[name].shape != (b,):
                raise ValueError(f"{name} has shape {cols[name].shape}, expected ({b},)")
        if (geometry is None) != (self.n_pairs == 0):
            raise ValueError(f"{self.path}: " + ("this store keeps no pair features" if geometry is not None else
                                                 f"every row needs its pair features ({b}, {self.n_pairs}, 3)"))
        if geometry is not None:
            cols["geometry"] = np.asarray(geometry)
            if cols["geometry"].shape != (b, self.n_pairs, 3):
                raise ValueError(f"geometry has shape {cols['geometry'].shape}, expected ({b}, {self.n_pairs}, 3)")
        start = len(self)
        ids = np.arange(start, start + b, dtype=np.int64)
        cols["id"] = ids
        for name, dtype in self._columns().items():
            ds = self._h5[name]
            if ds.shape[0] < start + b:
                ds.resize(start + b, axis=0)
            ds[start:start + b] = np.asarray(cols[name], dtype=dtype)
        self._h5.flush()
        fault_point("store_append")  # crash tests: rows on disk, not yet committed
        self._h5.attrs["committed"] = start + b
        self._h5.flush()
        return ids

    def truncate(self, n: int) -> None:
        """Forget every row past the first ``n`` committed ones (resume after a crash: rows appended after the
        last checkpoint are dropped; their space is reused by the next append)."""
        if not 0 <= n <= len(self):
            raise ValueError(f"{self.path}: cannot truncate {len(self)} rows to {n}")
        self._h5.attrs["committed"] = int(n)
        self._h5.flush()

    def read(self, index=None) -> CollisionRows:
        """Committed rows (all, or ``index`` into them)."""
        n = len(self)
        try:
            cols = {name: self._h5[name][:n] for name in self._columns()}
        except OSError as exc:
            raise StoreCorruptedError(f"{self.path}: its data is corrupted ({exc}); restore it from a backup, or "
                                      "move it away to start a new D_c (a run then restarts from round 0)") from exc
        if index is not None:
            cols = {k: v[index] for k, v in cols.items()}
        return CollisionRows(**cols)

    def column(self, name: str) -> np.ndarray:
        """One committed column (``z``, ``origin``, ...), read alone (D_c's ``geometry`` can be GBs at the paper's
        sizes; the other columns are small)."""
        if name not in self._columns():
            raise KeyError(f"{self.path}: no column {name!r} (has {sorted(self._columns())})")
        try:
            return self._h5[name][:len(self)]
        except OSError as exc:
            raise StoreCorruptedError(f"{self.path}: its data is corrupted ({exc}); restore it from a backup, or "
                                      "move it away to start a new D_c (a run then restarts from round 0)") from exc

    def read_rows(self, rows) -> CollisionRows:
        """The committed rows ``rows`` (indices or a boolean mask over the committed rows), read from the file
        row by row selection (not the whole store), in increasing order."""
        rows = np.asarray(rows)
        idx = np.flatnonzero(rows) if rows.dtype == bool else np.unique(rows.astype(np.int64))
        if len(idx) and (idx[0] < 0 or idx[-1] >= len(self)):
            raise IndexError(f"{self.path}: rows outside the {len(self)} committed ones")
        try:
            cols = {name: self._h5[name][idx] if len(idx) else self._h5[name][:0] for name in self._columns()}
        except OSError as exc:
            raise StoreCorruptedError(f"{self.path}: its data is corrupted ({exc}); restore it from a backup, or "
                                      "move it away to start a new D_c (a run then restarts from round 0)") from exc
        return CollisionRows(**cols)

    def split_mask(self) -> np.ndarray:
        """(N,) bool, True for validation rows (stable as the store grows)."""
        return (np.arange(len(self)) % VAL_EVERY) == VAL_EVERY - 1

    def close(self) -> None:
        if self._h5.id.valid:
            self._h5.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
