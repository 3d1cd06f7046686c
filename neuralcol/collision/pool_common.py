"""What both executors of :class:`~neuralcol.collision.pool.LabelPool` share (the local worker processes in
:mod:`neuralcol.collision.pool` and the dask cluster in :mod:`neuralcol.collision.pool_dask`): the per-chunk
labelling function, the warm-up of a worker's labeler, the bookkeeping of one call (:class:`Batch`) and the
one-line failure reasons."""

from __future__ import annotations

import collections
import threading
import time
from typing import NamedTuple

import numpy as np

from neuralcol.collision.labeler import ExactLabeler, Label, limit_clearance
from neuralcol.utils.faults import fault_point

STARTUP_TIMEOUT = 900.0  # seconds the workers may take to start (import, unpickle the labeler, load/compile kernels)
MAX_REASON = 300  # characters of an exception message kept in a failure reason
POLL_S = 1.0  # longest wait between two readings of a chunk timeout's RunClock


class RunClock:
    """Seconds of this process's running time for chunk timeouts: ``time.monotonic()`` less the time the process
    was stopped (``kill -STOP``, Ctrl-Z, a paused container or VM), so pausing a long labeling does not pass for
    a hung chunk when it goes on. The caller reads it at least every :data:`POLL_S` seconds while it waits; a
    gap between two readings longer than ``max_gap`` counts, less ``POLL_S``, as stopped time. A gap from a
    slow restart of the workers counts too: that only delays a timeout, never causes one. Thread-safe (the dask
    pool reads it from its event thread)."""

    def __init__(self, max_gap: float = 2 * POLL_S):
        self.max_gap = float(max_gap)
        self._lock = threading.Lock()
        self._last = time.monotonic()
        self._stopped = 0.0

    def __call__(self) -> float:
        with self._lock:
            now = time.monotonic()
            if now - self._last > self.max_gap:
                self._stopped += now - self._last - POLL_S
            self._last = now
            return now - self._stopped


def failure_reason(exc: BaseException) -> str:
    """One line: ``"ExceptionType: message"`` (message shortened)."""
    msg = " ".join(str(exc).split())
    if len(msg) > MAX_REASON:
        msg = msg[:MAX_REASON - 3] + "..."
    return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__


def warm_up(labeler) -> None:
    """Label the labeler's rest mesh once, so its compiled kernels are loaded (or compiled) before a worker takes
    a chunk, outside any chunk's timeout. Only a warm-up: an exception is ignored (a real problem shows on the
    chunks)."""
    rest = getattr(labeler, "rest", None)
    if rest is not None:
        try:
            labeler.label(rest)
        except Exception:
            pass


def _label_limited(labeler):
    """The labeler's ``label_limited``, or None if it has none or a subclass overrides ``label`` below the class
    that defines it (that label is the one to honor: its result is capped instead)."""
    fn = getattr(labeler, "label_limited", None)
    if fn is None:
        return None
    mro = type(labeler).__mro__
    owner = {name: next((c for c in mro if name in vars(c)), None) for name in ("label", "label_limited")}
    return fn if mro.index(owner["label_limited"]) <= mro.index(owner["label"]) else None


def label_chunk(labeler: ExactLabeler, chunk: np.ndarray, clearance_limit: float | None = None) -> list[Label | str]:
    """Labels of a chunk (C, V, 3) float64 with the given labeler (self-contained task for any executor).

    Args:
        labeler: the exact labeler.
        chunk: (C, V, 3) float64 vertices.
        clearance_limit: None: the full label; a length: clearances capped there (labels for training,
            :meth:`~neuralcol.collision.labeler.ExactLabeler.label_limited`; a labeler without that method caps
            its full label, same values).

    Returns:
        C entries in the order of ``chunk``: the mesh's Label, or a failure reason (str) if the labeler raised
        an exception or returned a non-finite PD.
    """
    out: list[Label | str] = []
    if getattr(labeler, "batched", False) and len(chunk) > 1:
        # a batched backend (e.g. the GPU labeler) labels the whole chunk at once; if that raises, every mesh is
        # labelled alone below, so one bad mesh still fails alone
        try:
            labels = labeler.label_batch(chunk)
        except Exception:
            labels = None
        if labels is not None:
            for i in range(len(chunk)):
                lb = Label(bool(labels.collides[i]), int(labels.n_pairs[i]), float(labels.pd[i]), labels.pd_sub[i])
                lb = limit_clearance(lb, clearance_limit)
                ok = np.isfinite(lb.pd) and np.isfinite(lb.pd_sub).all()
                out.append(lb if ok else f"non-finite label (pd={lb.pd})")
            return out
    limited = _label_limited(labeler) if clearance_limit is not None else None
    for v in chunk:
        try:
            if clearance_limit is None:
                lb = labeler.label(v)
            elif limited is not None:
                lb = limited(v, clearance_limit)
            else:
                lb = limit_clearance(labeler.label(v), clearance_limit)
        except Exception as exc:  # one bad mesh must not lose the chunk
            out.append(failure_reason(exc))
            continue
        if not (np.isfinite(lb.pd) and np.isfinite(lb.pd_sub).all()):
            out.append(f"non-finite label (pd={lb.pd})")
        else:
            out.append(lb)
    return out


def label_code_chunk(labeler: ExactLabeler, decoder, codes: np.ndarray,
                     clearance_limit: float | None = None) -> list[Label | str]:
    """Labels of the meshes that ``decoder`` makes of a chunk of latent codes (C, D): :func:`label_chunk` on the
    finite ones, ``"non-finite vertices"`` for the others. ``decoder``: codes (C, D) -> vertices (C, V, 3) float64
    (e.g. :class:`~neuralcol.samples.oracle.SpaceDecoder`), run where the chunk is labeled (a pool's worker)."""
    try:
        v = np.asarray(decoder(codes), dtype=np.float64)
    except Exception as exc:  # the decoder itself failed: every code of the chunk reports it
        return [failure_reason(exc)] * len(codes)
    finite = np.isfinite(v).all(axis=(1, 2))
    out: list[Label | str] = ["non-finite vertices"] * len(codes)
    labeled = label_chunk(labeler, v[finite], clearance_limit) if finite.any() else []
    for i, lb in zip(np.flatnonzero(finite), labeled):
        out[i] = lb
    return out


def checked_vertices(vertices, n: int, allow_non_finite: bool = False) -> np.ndarray:
    """A batch of meshes (B, n, 3) (numpy or a torch tensor) as contiguous float64; ValueError naming the problem
    (wrong shape or dtype; non-finite vertices unless ``allow_non_finite``)."""
    if hasattr(vertices, "detach"):  # torch tensor, without importing torch
        vertices = vertices.detach().cpu().numpy()
    v = np.asarray(vertices)
    if v.ndim != 3 or v.shape[1:] != (n, 3):
        raise ValueError(f"LabelPool.label: vertices have shape {v.shape}, expected (B, {n}, 3) for this "
                         f"labeler's mesh; add a batch axis for a single mesh (vertices[None])")
    if not np.issubdtype(v.dtype, np.number) or np.issubdtype(v.dtype, np.complexfloating):
        raise ValueError(f"LabelPool.label: vertices have dtype {v.dtype}, expected real floats")
    v = np.ascontiguousarray(v, dtype=np.float64)
    if not allow_non_finite:
        finite = np.isfinite(v).all(axis=(1, 2))  # (B,)
        if not finite.all():
            bad = np.flatnonzero(~finite)
            raise ValueError(f"LabelPool.label: meshes {bad[:10].tolist()}{' ...' if len(bad) > 10 else ''} "
                             "of the batch contain NaN or inf vertices; cannot label them")
    return v


def submit_ready(normal, suspects, in_flight, limit: int, submit) -> None:
    """Submit what may run now: a suspect alone, once nothing else is in flight; else tasks of ``normal`` until
    ``limit`` are in flight. ``submit(queue)`` submits the first task of a deque of :class:`Task` and takes it off."""
    if suspects:
        if not in_flight:
            submit(suspects)
    else:
        while normal and len(in_flight) < limit:
            submit(normal)


class Task(NamedTuple):
    """Meshes (global indices) labelled together; ``isolated``: a suspect running alone (the module docstring of
    :mod:`neuralcol.collision.pool`)."""

    idx: np.ndarray
    isolated: bool


class Batch:
    """Bookkeeping of one call: labels and failures by index, exception retries, the progress bar, the call's
    ``clearance_limit`` (None: full labels)."""

    def __init__(self, n: int, bar, clearance_limit: float | None = None):
        self.clearance_limit = clearance_limit  # every chunk of the call is labeled with it (label_chunk)
        self.results: list[Label | None] = [None] * n
        self.failures: dict[int, str] = {}
        self.raised: collections.Counter = collections.Counter()  # exceptions per mesh
        self.bar = bar

    def fail(self, i: int, reason: str) -> None:
        self.failures[int(i)] = reason
        self.bar.update(1)

    def give_up(self, queues, reason: str) -> None:
        """Report every mesh of the tasks still in ``queues`` (deques of Task) as failed and empty them."""
        for q in queues:
            for task in q:
                for i in task.idx:
                    self.fail(int(i), reason)
            q.clear()

    def settle(self, task: Task, out: list[Label | str]) -> list[Task]:
        """Record a task's result; returns the retries (meshes that raised for the first time, each alone)."""
        retry = []
        done = 0
        for i, r in zip(task.idx, out):
            if isinstance(r, str):
                retry += self.charge(int(i), r, task.isolated)
            else:
                self.results[int(i)] = r
                done += 1
        if done:
            self.bar.update(done)  # once per chunk (the main process shares the cores with the workers)
        fault_point("label_chunk")  # crash tests (neuralcol.utils.faults): a chunk is labelled
        return retry

    def charge(self, i: int, reason: str, isolated: bool) -> list[Task]:
        """A mesh raised: retried once (alone), then reported."""
        self.raised[i] += 1
        if self.raised[i] >= 2:
            self.fail(i, reason)
            return []
        return [Task(np.array([i]), isolated)]
