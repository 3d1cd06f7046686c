"""Labelling batches of meshes with one :class:`~neuralcol.collision.labeler.ExactLabeler` on several workers.

The labeler is deterministic and each mesh is labelled independently, so a batch is cut into chunks of
consecutive meshes, the chunks are labelled anywhere (this process, local worker processes, or any
:class:`concurrent.futures.Executor`, e.g. a dask cluster) and reassembled in input order: the result is
bit-identical for every choice of ``workers``, ``chunk_size`` and executor.

This module does not import torch; torch tensors are accepted through their ``.detach().cpu().numpy()``.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import weakref
from concurrent.futures.process import BrokenProcessPool

import numpy as np
from tqdm.auto import tqdm

from neuralcol.collision.labeler import ExactLabeler, Label, Labels

# The labeler of a worker process of a LabelPool, set once by `_init_worker` (the process's own state;
# never set in the parent process).
_WORKER_LABELER: ExactLabeler | None = None


def _init_worker(labeler: ExactLabeler) -> None:
    """Initializer of the pool's worker processes: keep the labeler, sent once per worker."""
    global _WORKER_LABELER
    _WORKER_LABELER = labeler


def _label_chunk(chunk: np.ndarray) -> list[Label]:
    """Labels of a chunk (C, V, 3) float64 with the labeler installed by :func:`_init_worker`."""
    if _WORKER_LABELER is None:
        raise RuntimeError("LabelPool worker has no labeler; _label_chunk must run in a pool made by LabelPool")
    return _label_chunk_with(_WORKER_LABELER, chunk)


def _label_chunk_with(labeler: ExactLabeler, chunk: np.ndarray) -> list[Label]:
    """Labels of a chunk (C, V, 3) float64 with the given labeler (self-contained task for any executor).

    Args:
        labeler: the exact labeler.
        chunk: (C, V, 3) float64 vertices.

    Returns:
        C labels in the order of ``chunk``.
    """
    return [labeler.label(v) for v in chunk]


class LabelPool:
    """Labels batches of meshes (B, V, 3) with one labeler on a pool of workers, results in input order.

    Three ways to run:

    * ``workers`` 0 or 1: in this process, no executor.
    * ``workers >= 2``: a :class:`~concurrent.futures.ProcessPoolExecutor` with ``workers`` processes, started
      (``mp_context``, default ``"spawn"``) at the first :meth:`label` call and reused until :meth:`close`.
      The labeler is sent once to each worker; each task carries only a chunk of ``chunk_size`` meshes.
      With ``"spawn"`` the workers re-import the caller's main module: guard scripts with
      ``if __name__ == "__main__":``.
    * ``executor``: any :class:`concurrent.futures.Executor` you own (a ``ThreadPoolExecutor``, a
      ``ProcessPoolExecutor``, dask's ``Client.get_executor()``...); ``workers`` is then ignored, each task
      carries the labeler together with its chunk, and :meth:`close` does not shut the executor down. To label
      on many machines with dask::

          from dask.distributed import Client

          client = Client("scheduler-address:8786")  # or Client() for a local cluster
          with LabelPool(labeler, executor=client.get_executor(), chunk_size=64) as pool:
              labels = pool.label(vertices)  # (B, V, 3)

      (The workers need ``neuralcol`` installed; scattering the labeler once is not needed for typical
      sizes, it is a few MB of numpy arrays.)

    The labels do not depend on ``workers``, ``chunk_size`` or the executor (bit-identical).

    Args:
        labeler: the exact labeler (holds only numpy arrays, so it pickles).
        workers: number of worker processes; 0 or 1 labels in this process.
        chunk_size: meshes per task (>= 1). Larger chunks cost less overhead, smaller ones balance better.
        executor: a user-owned executor to submit the tasks to (see above), or None.
        progress: show a tqdm bar over meshes on stderr.
        desc: label of the progress bar.
        mp_context: start method of the worker processes (``"spawn"``, ``"forkserver"``, ``"fork"``).
    """

    def __init__(self, labeler: ExactLabeler, workers: int = 0, chunk_size: int = 32,
                 executor: cf.Executor | None = None, progress: bool = False, desc: str = "labeling",
                 mp_context: str = "spawn"):
        if not isinstance(labeler, ExactLabeler):
            raise TypeError(f"LabelPool: labeler is a {type(labeler).__name__}; pass an ExactLabeler")
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 0:
            raise ValueError(f"LabelPool: workers={workers!r}; use an int >= 0 (0 or 1 label in this process)")
        if isinstance(chunk_size, bool) or not isinstance(chunk_size, (int, np.integer)) or chunk_size < 1:
            raise ValueError(f"LabelPool: chunk_size={chunk_size!r}; use an int >= 1")
        if executor is not None and not isinstance(executor, cf.Executor):
            raise TypeError(f"LabelPool: executor is a {type(executor).__name__}; pass a "
                            "concurrent.futures.Executor (e.g. dask's Client.get_executor()) or None")
        if mp_context not in multiprocessing.get_all_start_methods():
            raise ValueError(f"LabelPool: mp_context={mp_context!r} is not available here; use one of "
                             f"{multiprocessing.get_all_start_methods()}")
        self.labeler = labeler
        self.workers = int(workers)
        self.chunk_size = int(chunk_size)
        self.progress = bool(progress)
        self.desc = desc
        self.mp_context = mp_context
        self._user_executor = executor
        self._own_executor: cf.ProcessPoolExecutor | None = None
        self._finalizer: weakref.finalize | None = None

    # ------------------------------------------------------------------ lifecycle
    def _process_executor(self) -> cf.ProcessPoolExecutor:
        if self._own_executor is None:
            self._own_executor = cf.ProcessPoolExecutor(
                max_workers=self.workers, mp_context=multiprocessing.get_context(self.mp_context),
                initializer=_init_worker, initargs=(self.labeler,))
            # shut the workers down if the pool is dropped without close()
            self._finalizer = weakref.finalize(self, self._own_executor.shutdown, wait=False, cancel_futures=True)
        return self._own_executor

    def close(self) -> None:
        """Shut down the worker processes this pool started (a user executor is left running)."""
        if self._finalizer is not None:
            self._finalizer.detach()
            self._finalizer = None
        if self._own_executor is not None:
            executor, self._own_executor = self._own_executor, None
            executor.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> LabelPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        where = (f"executor={type(self._user_executor).__name__}" if self._user_executor is not None
                 else f"workers={self.workers}")
        return f"LabelPool({where}, chunk_size={self.chunk_size}, n_vertices={self.labeler.n_vertices})"

    # ------------------------------------------------------------------ labelling
    def _check(self, vertices) -> np.ndarray:
        if hasattr(vertices, "detach"):  # torch tensor, without importing torch
            vertices = vertices.detach().cpu().numpy()
        v = np.asarray(vertices)
        n = self.labeler.n_vertices
        if v.ndim != 3 or v.shape[1:] != (n, 3):
            raise ValueError(f"LabelPool.label: vertices have shape {v.shape}, expected (B, {n}, 3) for this "
                             f"labeler's mesh; add a batch axis for a single mesh (vertices[None])")
        if not np.issubdtype(v.dtype, np.number) or np.issubdtype(v.dtype, np.complexfloating):
            raise ValueError(f"LabelPool.label: vertices have dtype {v.dtype}, expected real floats")
        v = np.ascontiguousarray(v, dtype=np.float64)
        finite = np.isfinite(v).all(axis=(1, 2))  # (B,)
        if not finite.all():
            bad = np.flatnonzero(~finite)
            raise ValueError(f"LabelPool.label: meshes {bad[:10].tolist()}{' ...' if len(bad) > 10 else ''} of the "
                             "batch contain NaN or inf vertices; cannot label them")
        return v

    def label(self, vertices) -> Labels:
        """Labels of a batch of meshes, in input order.

        Args:
            vertices: (B, V, 3) float, numpy or a torch tensor (any device); V = ``labeler.n_vertices``.

        Returns:
            Labels with collides (B,) bool, n_pairs (B,) int64, pd (B,) float64, pd_sub (B, K) float64.

        Raises:
            ValueError: wrong shape or dtype, or non-finite vertices.
        """
        v = self._check(vertices)
        if len(v) == 0:
            return Labels.stack([], self.labeler.n_parts)
        starts = range(0, len(v), self.chunk_size)
        chunks = [v[s:s + self.chunk_size] for s in starts]  # each (C, V, 3) float64 contiguous
        results: list[list[Label] | None] = [None] * len(chunks)
        with tqdm(total=len(v), desc=self.desc, unit="mesh", disable=not self.progress) as bar:
            if self._user_executor is None and self.workers <= 1:
                for i, chunk in enumerate(chunks):
                    results[i] = _label_chunk_with(self.labeler, chunk)
                    bar.update(len(chunk))
            else:
                if self._user_executor is not None:
                    futures = {self._user_executor.submit(_label_chunk_with, self.labeler, c): i
                               for i, c in enumerate(chunks)}
                else:
                    executor = self._process_executor()
                    futures = {executor.submit(_label_chunk, c): i for i, c in enumerate(chunks)}
                try:
                    for fut in cf.as_completed(futures):
                        i = futures[fut]
                        results[i] = fut.result()
                        bar.update(len(chunks[i]))
                except BaseException as exc:
                    for fut in futures:
                        fut.cancel()
                    if isinstance(exc, BrokenProcessPool) and self._user_executor is None:
                        self.close()  # a worker died and broke the executor; the next call starts a new one
                    raise
        return Labels.stack([lb for chunk_labels in results for lb in chunk_labels], self.labeler.n_parts)
