"""Labelling batches of meshes with one :class:`~neuralcol.collision.labeler.ExactLabeler` on several workers.

The labeler is deterministic and each mesh is labelled independently, so a batch is cut into chunks of
consecutive meshes, the chunks are labelled anywhere and reassembled in input order: the result is bit-identical
for every choice of ``workers``, ``chunk_size`` and executor. Where (``executor``, config
``labeling.pool.executor``):

* ``"local"`` (default): in this process (``workers`` 0 or 1) or on ``workers`` local worker processes.
* ``"dask"``: on a dask.distributed cluster (``pip install "dask[distributed]"``), the one whose scheduler runs
  at ``scheduler`` (``"tcp://host:8786"``; never shut down by the pool), or, with ``scheduler`` None, a
  ``LocalCluster`` of ``workers`` worker processes x 1 thread started on this machine at the first call and
  closed by :meth:`LabelPool.close`. The labeler is sent once, to every worker (a worker plugin, so workers
  that join or restart later get it too); at most 2 chunks per cluster thread are in flight. Details:
  :mod:`neuralcol.collision.pool_dask`.
* a :class:`concurrent.futures.Executor` object you own (e.g. a ``ThreadPoolExecutor``): each task carries the
  labeler with its chunk.

Worker faults (one bad mesh never loses the batch):

* **The labeler raises on a mesh** (e.g. a degenerate decoded mesh), or returns a non-finite PD: the worker
  catches it per mesh, the other meshes of the chunk keep their labels; the mesh is retried once, alone, and
  if it fails again it is reported as ``(index, "ExceptionType: message")``.
* **A worker process dies** (``os._exit``, a segfault, SIGKILL; pool-owned workers only): the pool starts new
  worker processes and resubmits the unfinished work. The meshes of the chunks that were in flight are
  suspects: they are labelled again one at a time, with nothing else running, so a mesh that kills its
  worker again is identified and reported (``"worker died (exit code 3)"``) while the innocent ones get
  their labels. On dask, the cluster's nannies restart dead workers and the scheduler runs their chunks
  again (up to ``distributed.scheduler.allowed-failures`` deaths per chunk, no label lost); a chunk dask gives
  up on (``KilledWorker``) has its meshes relabelled one at a time in the same way, and a mesh that kills the
  workers alone is reported (``"worker died (dask KilledWorker: 4 workers died running it)"``).
* **A chunk hangs** (``timeout`` seconds, pool-owned workers only): when a chunk has been running for
  ``timeout`` seconds the worker processes are killed (``ProcessPoolExecutor._processes``; if that private
  attribute is missing, the pids the workers reported at start-up are killed and the executor abandoned) and
  restarted, and the in-flight chunks become suspects as above; a mesh that times out again alone is
  reported (``"timed out after 3 s"``). At most ``workers`` chunks are in flight and new workers are probed
  before any chunk is sent, so a chunk's clock starts about when a worker takes it; time the labeling process
  was stopped (``kill -STOP``, Ctrl-Z) does not count (``RunClock``); only a mesh running alone is ever
  reported, so a slow worker start-up cannot get an innocent mesh reported. On dask, each chunk reports
  when a worker thread starts it; a chunk past ``timeout`` is cancelled, its worker process killed through its
  nanny (which starts a new one) and its meshes relabelled one at a time as above.
* **Non-finite input vertices** are reported as ``"non-finite vertices"`` without being labelled.
* At most ``max_restarts`` restarts per call: past that, every mesh not labelled yet is reported, so a
  broken environment (every mesh crashing its worker) never loops. Workers that cannot start at all raise
  ``RuntimeError`` (not a per-mesh fault).

API: :meth:`LabelPool.label` returns :class:`~neuralcol.collision.labeler.Labels` and raises
:class:`LabelingError` (listing the failed indices and reasons; its ``report`` holds the partial result)
if any mesh could not be labelled; non-finite vertices raise ``ValueError`` before any work, as before.
:meth:`LabelPool.label_report` never raises for per-mesh faults: it returns a :class:`LabelReport` with
the labels of all B rows (failed rows: ``collides`` False, ``n_pairs`` -1, ``pd`` and ``pd_sub`` NaN), the
``ok`` mask and the sorted list of :class:`LabelFailure` ``(index, reason)``, and logs one warning line
per batch naming the first 10 failures. The labels of the meshes that succeed are bit-identical to a
fault-free run. Labelling in this process (``workers`` 0 or 1) catches exceptions but cannot survive a
crash or interrupt a hang; with a user ``Executor`` object, exceptions are handled the same way, a broken
executor is re-raised (it is not ours to restart) and ``timeout`` is not available. On dask, a lost scheduler
connection is raised as ``RuntimeError``.

This module does not import torch; torch tensors are accepted through their ``.detach().cpu().numpy()``.
"""

from __future__ import annotations

import collections
import concurrent.futures as cf
import logging
import multiprocessing
import os
import pickle
import signal
import tempfile
import weakref
from concurrent.futures.process import BrokenProcessPool
from typing import NamedTuple

import numpy as np

from neuralcol.collision.labeler import ExactLabeler, Label, Labels, check_clearance_limit
from neuralcol.collision.pool_common import (
    POLL_S,
    STARTUP_TIMEOUT,
    Batch,
    RunClock,
    Task,
    checked_vertices,
    failure_reason,
    label_chunk,
    label_code_chunk,
    submit_ready,
    warm_up,
)
from neuralcol.utils.progress import progress_bar

log = logging.getLogger(__name__)

REPORTED_FAILURES = 10  # failures named in a warning line / error message

EXECUTORS = ("local", "dask")  # LabelPool(executor=...) by name; or a concurrent.futures.Executor object
DASK_INSTALL = 'pip install "dask[distributed]"'

# The labeler of a worker process of a LabelPool, set once by `_init_worker` (the process's own state;
# never set in the parent process).
_WORKER_LABELER: ExactLabeler | None = None
# The codes -> vertices decoder of label_codes_report a worker holds: (the file it was read from, the decoder). The
# pool pickles each new decoder once into a file of its scratch folder; a worker reads it at its first chunk of codes.
_WORKER_DECODER: tuple[str, object] | None = None


class LabelFailure(NamedTuple):
    """A mesh that could not be labelled: its index in the batch and why."""

    index: int
    reason: str


class LabelReport(NamedTuple):
    """Result of :meth:`LabelPool.label_report` for a batch of B meshes.

    Attributes:
        labels: labels of all B rows, in input order; failed rows have ``collides`` False, ``n_pairs`` -1,
            ``pd`` NaN and ``pd_sub`` NaN.
        ok: (B,) bool, True where the mesh was labelled.
        failures: the failed meshes, sorted by index.
    """

    labels: Labels
    ok: np.ndarray
    failures: list[LabelFailure]


class LabelingError(RuntimeError):
    """Some meshes of a batch could not be labelled; ``report`` is the :class:`LabelReport` (partial labels)."""

    def __init__(self, report: LabelReport, desc: str = "labeling"):
        self.report = report
        super().__init__(f"LabelPool.label ({desc}): {format_failures(report.failures, len(report.ok))}; "
                         "LabelPool.label_report() returns the labels of the other meshes")


def format_failures(failures: list[LabelFailure], n: int) -> str:
    """``"2 of 8 meshes could not be labelled: [3] ValueError: ...; [5] worker died (exit code 3)"``
    (the first :data:`REPORTED_FAILURES`)."""
    shown = "; ".join(f"[{f.index}] {f.reason}" for f in failures[:REPORTED_FAILURES])
    more = f"; ... ({len(failures) - REPORTED_FAILURES} more)" if len(failures) > REPORTED_FAILURES else ""
    return f"{len(failures)} of {n} meshes could not be labelled: {shown}{more}"


def _init_worker(labeler_file: str) -> None:
    """Initializer of the pool's worker processes: read the labeler the pool pickled into ``labeler_file``, keep it
    and warm it up (:func:`~neuralcol.collision.pool_common.warm_up`) before the worker takes a chunk, outside any
    chunk's timeout.

    The labeler travels by file, not as the initializer's argument: a spawned worker reads its arguments only after
    importing the parent's main module, and the parent's write of more than a pipe's 64 KB waits for that read, so
    the workers started one after another (8 s for two on 2 cores, 4 s together)."""
    global _WORKER_LABELER
    with open(labeler_file, "rb") as f:
        _WORKER_LABELER = pickle.load(f)
    warm_up(_WORKER_LABELER)


def require_distributed() -> None:
    """Raise ImportError (with the pip command) if dask.distributed is not installed."""
    import importlib.util

    if importlib.util.find_spec("distributed") is None:
        raise ImportError(f"LabelPool: executor='dask' (labeling.pool.executor=dask) needs dask.distributed, which "
                          f"is not installed; install it with: {DASK_INSTALL}")


def _ready() -> int:
    """Start-up probe of a worker process: its pid."""
    return os.getpid()


def _label_chunk(chunk: np.ndarray, clearance_limit: float | None = None) -> list[Label | str]:
    """Labels of a chunk (C, V, 3) float64 with the labeler installed by :func:`_init_worker` (``clearance_limit``:
    :func:`~neuralcol.collision.pool_common.label_chunk`)."""
    if _WORKER_LABELER is None:
        raise RuntimeError("LabelPool worker has no labeler; _label_chunk must run in a pool made by LabelPool")
    return label_chunk(_WORKER_LABELER, chunk, clearance_limit)


def _worker_decoder(path: str):
    """The decoder pickled at ``path`` (read once per worker and decoder, kept until another is asked for)."""
    global _WORKER_DECODER
    if _WORKER_DECODER is None or _WORKER_DECODER[0] != path:
        with open(path, "rb") as f:
            _WORKER_DECODER = (path, pickle.load(f))
    return _WORKER_DECODER[1]


def _label_code_chunk(codes: np.ndarray, clearance_limit: float | None, decoder_file: str) -> list[Label | str]:
    """Labels of a chunk of codes (C, D), decoded here by the decoder pickled at ``decoder_file``."""
    if _WORKER_LABELER is None:
        raise RuntimeError("LabelPool worker has no labeler; _label_code_chunk must run in a pool made by LabelPool")
    return label_code_chunk(_WORKER_LABELER, _worker_decoder(decoder_file), codes, clearance_limit)


def _death_reason(exit_codes: list[int | None]) -> str:
    """``"worker died (exit code 3)"`` from the exit codes of the worker processes after the pool broke (the
    executor terminates the survivors with SIGTERM, so the other codes name the dead worker)."""
    codes = [c for c in exit_codes if c not in (None, 0, -signal.SIGTERM)]
    if not codes:
        return "worker died"
    c = codes[0]
    if c > 0:
        return f"worker died (exit code {c})"
    try:
        return f"worker died (signal {signal.Signals(-c).name})"
    except ValueError:
        return f"worker died (exit code {c})"


class LabelPool:
    """Labels batches of meshes (B, V, 3) with one labeler on a pool of workers, results in input order.

    Four ways to run:

    * ``workers`` 0 or 1 (``executor="local"``): in this process.
    * ``workers >= 2`` (``executor="local"``): a :class:`~concurrent.futures.ProcessPoolExecutor` with
      ``workers`` processes, started (``mp_context``, default ``"spawn"``) at the first :meth:`label` call and
      reused until :meth:`close`. The labeler is pickled into the pool's scratch folder (removed by
      :meth:`close`) and read once by each worker as it starts; each task carries only a chunk of ``chunk_size``
      meshes. With ``"spawn"`` the workers re-import the caller's main module: guard scripts with
      ``if __name__ == "__main__":``.
    * ``executor="dask"``: a dask.distributed cluster, at ``scheduler`` or a ``LocalCluster`` of ``workers``
      processes x 1 thread started here (see the module docstring). The labeler is sent once to every worker;
      each task carries only its chunk. The workers need ``neuralcol`` (and whatever the labeler's class needs)
      importable::

          with LabelPool(labeler, executor="dask", scheduler="tcp://10.0.0.5:8786", chunk_size=32) as pool:
              labels = pool.label(vertices)  # (B, V, 3)

    * ``executor``: any :class:`concurrent.futures.Executor` object you own (a ``ThreadPoolExecutor``, a
      ``ProcessPoolExecutor``, dask's ``Client.get_executor()``...); ``workers`` is then ignored, each task
      carries the labeler together with its chunk (prefer ``executor="dask"`` on a dask cluster: it sends the
      labeler once and recovers from worker deaths), and :meth:`close` does not shut the executor down.

    The labels do not depend on ``workers``, ``chunk_size`` or the executor (bit-identical). Faults (a mesh
    that raises, a worker that dies or hangs) are handled as the module docstring describes.

    Args:
        labeler: the exact labeler (holds only numpy arrays, so it pickles).
        workers: number of worker processes; 0 or 1 labels in this process.
        chunk_size: meshes per task (>= 1). Larger chunks cost less overhead, smaller ones balance better.
        executor: ``"local"`` (None means the same), ``"dask"``, or a user-owned
            :class:`concurrent.futures.Executor` to submit the tasks to (see above).
        progress: report progress over meshes on stderr (a bar on a terminal, lines in a log file:
            :mod:`neuralcol.utils.progress`).
        desc: label of the progress bar (and of the warning lines).
        mp_context: start method of the worker processes (``"spawn"``, ``"forkserver"``, ``"fork"``).
        timeout: seconds a chunk may run on a worker process before the workers are killed and restarted
            (None: no limit). For ``workers >= 2`` and ``executor="dask"``: ignored in this process, refused
            with an ``Executor`` object.
        max_restarts: worker-process restarts allowed per call (then the meshes not labelled yet fail); on dask,
            the chunks dask gave up on plus the hung workers killed.
        scheduler: ``executor="dask"`` only: the scheduler's address (``"tcp://host:8786"``), or None to start
            a ``LocalCluster`` of ``workers`` worker processes (at least 1) on this machine.
    """

    def __init__(self, labeler: ExactLabeler, workers: int = 0, chunk_size: int = 32,
                 executor: str | cf.Executor | None = "local", progress: bool = False, desc: str = "labeling",
                 mp_context: str = "spawn", timeout: float | None = None, max_restarts: int = 10,
                 scheduler: str | None = None):
        missing = [a for a in ("label", "n_vertices", "n_parts") if not hasattr(labeler, a)]
        if missing:
            raise TypeError(f"LabelPool: labeler is a {type(labeler).__name__} without {', '.join(missing)}; pass an "
                            "ExactLabeler or another labeling backend (neuralcol.collision.backends)")
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 0:
            raise ValueError(f"LabelPool: workers={workers!r}; use an int >= 0 (0 or 1 label in this process)")
        if isinstance(chunk_size, bool) or not isinstance(chunk_size, (int, np.integer)) or chunk_size < 1:
            raise ValueError(f"LabelPool: chunk_size={chunk_size!r}; use an int >= 1")
        if executor is None:
            executor = "local"
        if isinstance(executor, str):
            if executor not in EXECUTORS:
                raise ValueError(f"LabelPool: executor={executor!r}; use 'local' (this process or local worker "
                                 "processes), 'dask' (a dask.distributed cluster) or a concurrent.futures.Executor")
        elif not isinstance(executor, cf.Executor):
            raise TypeError(f"LabelPool: executor is a {type(executor).__name__}; pass 'local', 'dask' or a "
                            "concurrent.futures.Executor (e.g. a ThreadPoolExecutor)")
        if scheduler is not None:
            if executor != "dask":
                raise ValueError(f"LabelPool: scheduler={scheduler!r} is only used with executor='dask' "
                                 f"(executor={executor if isinstance(executor, str) else type(executor).__name__})")
            if not isinstance(scheduler, str) or not scheduler.strip():
                raise ValueError(f"LabelPool: scheduler={scheduler!r}; use a dask scheduler address such as "
                                 "'tcp://host:8786', or None to start a LocalCluster of `workers` processes")
        if executor == "dask":
            require_distributed()
        if mp_context not in multiprocessing.get_all_start_methods():
            raise ValueError(f"LabelPool: mp_context={mp_context!r} is not available here; use one of "
                             f"{multiprocessing.get_all_start_methods()}")
        if timeout is not None:
            if isinstance(timeout, bool) or not isinstance(timeout, (int, float, np.number)) or not timeout > 0:
                raise ValueError(f"LabelPool: timeout={timeout!r}; use a number of seconds > 0, or None")
            if not isinstance(executor, str):
                raise ValueError("LabelPool: timeout needs the pool's own worker processes (it kills them); "
                                 "with a user executor use the executor's own time limits")
        if isinstance(max_restarts, bool) or not isinstance(max_restarts, (int, np.integer)) or max_restarts < 0:
            raise ValueError(f"LabelPool: max_restarts={max_restarts!r}; use an int >= 0")
        if getattr(labeler, "batched", False) and executor == "local":
            # a batched backend (the GPU labeler) labels whole chunks on its device: one process, large chunks
            if workers >= 2:
                log.info("LabelPool: %s labels batches on its device; labeling in this process, not in %d workers",
                         type(labeler).__name__, workers)
            workers = 0
            chunk_size = max(int(chunk_size), int(getattr(labeler, "max_batch", chunk_size)))
        self.labeler = labeler
        self.workers = int(workers)
        self.chunk_size = int(chunk_size)
        self.progress = bool(progress)
        self.desc = desc
        self.mp_context = mp_context
        self.timeout = None if timeout is None else float(timeout)
        self.max_restarts = int(max_restarts)
        self.executor = executor if isinstance(executor, str) else "user"
        self.scheduler = None if scheduler is None else scheduler.strip()
        self._user_executor = None if isinstance(executor, str) else executor
        self._dask = None  # pool_dask.DaskSession: the dask client (and LocalCluster) of executor="dask"
        self._own_executor: cf.ProcessPoolExecutor | None = None
        self._finalizer: weakref.finalize | None = None
        self._procs: list = []  # the worker processes of _own_executor (multiprocessing.Process)
        self._pids: set[int] = set()  # their pids, as reported by the start-up probes
        self._decoder = None  # the decoder of the last label_codes_report on worker processes
        self._decoder_file: str | None = None  # where it is pickled for the workers (in _scratch)
        self._decoders_shared = 0  # decoders pickled so far (each file's name)
        self._scratch: tempfile.TemporaryDirectory | None = None  # the pool's own folder, removed by close()

    # ------------------------------------------------------------------ lifecycle
    def _process_executor(self) -> cf.ProcessPoolExecutor:
        """The pool's executor, started (and every worker probed) if needed."""
        if self._own_executor is None:
            executor = cf.ProcessPoolExecutor(
                max_workers=self.workers, mp_context=multiprocessing.get_context(self.mp_context),
                initializer=_init_worker, initargs=(self._labeler_file(),))
            self._own_executor = executor
            # shut the workers down if the pool is dropped without close()
            self._finalizer = weakref.finalize(self, executor.shutdown, wait=False, cancel_futures=True)
            # one probe per worker: the executor spawns all of them now, and at least one is ready when the first
            # chunk is submitted (so a chunk's timeout does not count the start-up)
            probes = [executor.submit(_ready) for _ in range(self.workers)]
            done, not_done = cf.wait(probes, timeout=STARTUP_TIMEOUT)
            self._procs = list((getattr(executor, "_processes", None) or {}).values())
            errors = [f.exception() for f in done if f.exception() is not None]
            if not_done or errors:
                self._discard_executor(kill=True)
                why = failure_reason(errors[0]) if errors else f"not ready after {STARTUP_TIMEOUT:g} s"
                raise RuntimeError(f"LabelPool: the {self.workers} worker processes did not start ({why})")
            self._pids = {f.result() for f in done}
        return self._own_executor

    def _discard_executor(self, kill: bool) -> list[int | None]:
        """Drop the pool's executor (killing its workers first if ``kill``); returns the workers' exit codes.

        A broken executor (a worker died) is shut down without ``kill``: it has already terminated the other
        workers with SIGTERM, so the dead worker's own exit code stands out."""
        executor, self._own_executor = self._own_executor, None
        if self._finalizer is not None:
            self._finalizer.detach()
            self._finalizer = None
        procs, self._procs = self._procs, []
        pids, self._pids = self._pids, set()
        if executor is None:
            return []
        if kill:
            if procs:
                for p in procs:
                    if p.exitcode is None:
                        p.kill()
            else:  # fallback: ProcessPoolExecutor._processes was not available; kill the probed pids
                log.warning("LabelPool: cannot list the worker processes; killing the %d known pids and "
                            "abandoning the executor", len(pids))
                for pid in pids:
                    try:
                        os.kill(pid, signal.SIGKILL)
                    except OSError:
                        pass
        executor.shutdown(wait=bool(procs) or not kill, cancel_futures=True)
        for p in procs:
            p.join(timeout=10)
        # read after the executor joined its workers (reading earlier races with its waitpid and can miss a code)
        return [p.exitcode for p in procs]

    def _dask_session(self):
        """The pool's dask client (connected, or a LocalCluster started) with the labeler on every worker."""
        if self._dask is None:
            from neuralcol.collision.pool_dask import DaskSession

            self._dask = DaskSession(self.labeler, self.scheduler, self.workers, self.timeout)
        return self._dask

    def close(self) -> None:
        """Shut down the worker processes or the dask LocalCluster this pool started (a user executor and a
        dask cluster given by ``scheduler`` are left running; the pool's labeler is removed from its workers)."""
        self._discard_executor(kill=False)
        session, self._dask = self._dask, None
        if session is not None:
            session.close()
        scratch, self._scratch = self._scratch, None
        self._decoder = self._decoder_file = None
        if scratch is not None:
            scratch.cleanup()

    def _scratch_folder(self) -> str:
        """The pool's own temporary folder (made on first need, removed by :meth:`close`)."""
        if self._scratch is None:
            self._scratch = tempfile.TemporaryDirectory(prefix="neuralcol-pool-")
        return self._scratch.name

    def _pickle_to_scratch(self, obj, name: str) -> str:
        """Pickle ``obj`` into ``name`` in the scratch folder (written whole, then renamed: a starting worker never
        reads half a file); its path."""
        path = os.path.join(self._scratch_folder(), name)
        with open(path + ".tmp", "wb") as f:
            pickle.dump(obj, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(path + ".tmp", path)
        return path

    def _labeler_file(self) -> str:
        """The labeler pickled into the scratch folder (at every start: workers restarted later get the labeler of
        then), where the starting workers read it."""
        return self._pickle_to_scratch(self.labeler, "labeler.pkl")

    def _share_decoder(self, decoder) -> None:
        """Pickle ``decoder`` once into the pool's scratch folder, where the workers read it at their next chunk of
        codes (they keep running: a worker start costs seconds, a decoder's pickle milliseconds). Each decoder gets
        a new name, which is how a worker knows its own is stale."""
        old = self._decoder_file
        self._decoders_shared += 1
        self._decoder_file = self._pickle_to_scratch(decoder, f"{self._decoders_shared}.decoder.pkl")
        self._decoder = decoder
        if old is not None:  # every chunk of the previous call has finished: no worker reads it again
            os.unlink(old)

    def __enter__(self) -> LabelPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        if self._user_executor is not None:
            where = f"executor={type(self._user_executor).__name__}"
        elif self.executor == "dask":
            where = f"executor='dask', scheduler={self.scheduler!r}, workers={self.workers}"
        else:
            where = f"workers={self.workers}"
        return f"LabelPool({where}, chunk_size={self.chunk_size}, n_vertices={self.labeler.n_vertices})"

    # ------------------------------------------------------------------ labelling
    def _check(self, vertices, allow_non_finite: bool = False) -> np.ndarray:
        return checked_vertices(vertices, self.labeler.n_vertices, allow_non_finite)

    def label(self, vertices, clearance_limit: float | None = None) -> Labels:
        """Labels of a batch of meshes, in input order.

        Args:
            vertices: (B, V, 3) float, numpy or a torch tensor (any device); V = ``labeler.n_vertices``.
            clearance_limit: None: full labels; a length: clearances capped there (labels for training:
                :meth:`~neuralcol.collision.labeler.ExactLabeler.label_limited`).

        Returns:
            Labels with collides (B,) bool, n_pairs (B,) int64, pd (B,) float64, pd_sub (B, K) float64.

        Raises:
            ValueError: wrong shape or dtype, or non-finite vertices.
            LabelingError: some meshes could not be labelled (after the retries); lists them, and its
                ``report`` holds the labels of the others. Use :meth:`label_report` to get them directly.
        """
        report = self._run(self._check(vertices), clearance_limit=check_clearance_limit(clearance_limit))
        if report.failures:
            raise LabelingError(report, self.desc)
        return report.labels

    def label_report(self, vertices, clearance_limit: float | None = None) -> LabelReport:
        """Labels of a batch of meshes, in input order, with the meshes that could not be labelled.

        Per-mesh faults (the labeler raising, a worker dying or hanging, non-finite vertices) do not raise:
        the mesh is reported in ``failures`` (and ``ok`` is False for it), and one warning line names the
        first failures.

        Args:
            vertices: (B, V, 3) float, numpy or a torch tensor (any device); V = ``labeler.n_vertices``.
            clearance_limit: as :meth:`label`.

        Returns:
            :class:`LabelReport` (labels of all B rows, ``ok`` mask, failures sorted by index).

        Raises:
            ValueError: wrong shape or dtype.
            RuntimeError: the worker processes cannot start at all (not a per-mesh fault).
        """
        v = self._check(vertices, allow_non_finite=True)
        finite = np.isfinite(v).all(axis=(1, 2)) if len(v) else np.zeros(0, bool)
        report = self._run(v, skip={int(i): "non-finite vertices" for i in np.flatnonzero(~finite)},
                           clearance_limit=check_clearance_limit(clearance_limit))
        if report.failures:
            log.warning("%s: %s", self.desc, format_failures(report.failures, len(v)))
        return report

    def label_codes_report(self, codes, decoder, clearance_limit: float | None = None) -> LabelReport:
        """:meth:`label_report` of the meshes ``decoder`` makes of latent codes, decoded where they are labeled:
        on the pool's worker processes (``workers`` >= 2; a new decoder is pickled once into the pool's scratch
        folder and each worker reads it at its first chunk, without restarting), chunk by chunk in this process
        (``workers`` 0 or 1), or here before the chunks leave (dask, a user executor). Non-finite decoded meshes are
        reported as ``"non-finite vertices"``.

        Args:
            codes: (B, D) float array.
            decoder: picklable callable, codes (C, D) -> vertices (C, V, 3); the same object on every call is
                pickled once (e.g. :class:`~neuralcol.samples.oracle.SpaceDecoder`).
            clearance_limit: as :meth:`label`.
        """
        codes = np.ascontiguousarray(np.asarray(codes, dtype=np.float32))
        if codes.ndim != 2:
            raise ValueError(f"LabelPool.label_codes_report: codes have shape {codes.shape}, expected (B, D)")
        limit = check_clearance_limit(clearance_limit)
        if self.executor != "local":  # dask or the user's executor: vertices travel, as in label_report
            return self.label_report(decoder(codes) if len(codes) else np.zeros((0, self.labeler.n_vertices, 3)),
                                     clearance_limit=limit)
        if self.workers >= 2 and decoder is not self._decoder:
            self._share_decoder(decoder)
        report = self._run(codes, clearance_limit=limit, decoder=decoder)
        if report.failures:
            log.warning("%s: %s", self.desc, format_failures(report.failures, len(codes)))
        return report

    def _run(self, v: np.ndarray, skip: dict[int, str] | None = None, clearance_limit: float | None = None,
             decoder=None) -> LabelReport:
        """Label every mesh of ``v`` (B, V, 3) float64 except ``skip`` (index -> reason, reported as is); with
        ``decoder``, ``v`` holds codes (B, D) that are decoded where each chunk is labeled."""
        n, k = len(v), self.labeler.n_parts
        todo = np.setdiff1d(np.arange(n), np.fromiter(skip or {}, dtype=np.int64, count=len(skip or {})))
        # chunks of consecutive meshes to label (the skipped ones are left out)
        tasks = [Task(todo[s:s + self.chunk_size], False) for s in range(0, len(todo), self.chunk_size)]
        with progress_bar(total=n, desc=self.desc, unit="mesh", disable=not self.progress) as bar:
            batch = Batch(n, bar, clearance_limit)
            for i, why in (skip or {}).items():
                batch.fail(i, why)
            if self.executor == "local" and self.workers <= 1:
                queue = collections.deque(tasks)
                while queue:
                    task = queue.popleft()
                    chunk = v[task.idx]
                    out = (label_chunk(self.labeler, chunk, clearance_limit) if decoder is None else
                           label_code_chunk(self.labeler, decoder, chunk, clearance_limit))
                    queue.extend(batch.settle(task, out))
            elif self.executor == "dask":
                from neuralcol.collision.pool_dask import run_dask

                if tasks:
                    run_dask(self, self._dask_session(), v, tasks, batch)
            else:
                self._run_executor(v, tasks, batch, decoder)
        for i in np.flatnonzero([r is None and i not in batch.failures for i, r in enumerate(batch.results)]):
            batch.failures[int(i)] = "not labelled"  # cannot happen; never report a missing label as a success
        ok = np.array([r is not None for r in batch.results], dtype=bool)
        nan_row = np.full(k, np.nan)
        rows = [r if r is not None else Label(False, -1, float("nan"), nan_row) for r in batch.results]
        labels = Labels.stack(rows, k)
        failures = [LabelFailure(i, batch.failures[i]) for i in sorted(batch.failures)]
        return LabelReport(labels, ok, failures)

    def _run_executor(self, v: np.ndarray, tasks: list[Task], batch: Batch, decoder=None) -> None:
        """Label ``tasks`` on the pool's worker processes (at most ``workers`` chunks in flight, faults handled
        as the module docstring says) or on the user's executor (all submitted at once)."""
        own = self._user_executor is None
        limit = self.workers if own else max(len(tasks), 1)
        timeout = self.timeout if own else None
        normal = collections.deque(tasks)
        suspects: collections.deque[Task] = collections.deque()  # labelled alone, nothing else in flight
        in_flight: dict[cf.Future, tuple[Task, float]] = {}  # future -> (task, clock() when submitted)
        clock = RunClock()  # time stopped (kill -STOP, Ctrl-Z) is not a chunk's running time
        restarts = 0

        def submit(queue: collections.deque[Task]) -> None:
            """Submit the first task of ``queue`` (taken off it only once submitted)."""
            task = queue[0]
            chunk = v[task.idx]
            if own:
                executor = self._process_executor()
                fut = (executor.submit(_label_chunk, chunk, batch.clearance_limit) if decoder is None else
                       executor.submit(_label_code_chunk, chunk, batch.clearance_limit, self._decoder_file))
            else:
                fut = self._user_executor.submit(label_chunk, self.labeler, chunk, batch.clearance_limit)
            in_flight[fut] = (queue.popleft(), clock())

        def harvest(fut: cf.Future) -> bool:
            """Record a finished future's result; False if it failed with BrokenProcessPool."""
            task = in_flight[fut][0]
            exc = fut.exception()
            if isinstance(exc, BrokenProcessPool):
                return False
            del in_flight[fut]
            if exc is None:
                retries = batch.settle(task, fut.result())
            elif isinstance(exc, Exception):  # the task itself failed (e.g. results could not be pickled)
                retries = [t for i in task.idx for t in batch.charge(int(i), failure_reason(exc), task.isolated)]
            else:
                raise exc
            for t in retries:
                (suspects if t.isolated else normal).append(t)
            return True

        def fault(kind: str) -> None:
            """The pool broke (``kind`` "died") or a chunk ran out of time ("timeout"): restart, isolate."""
            nonlocal restarts
            for fut in [f for f in in_flight if f.done()]:
                harvest(fut)  # chunks that finished before the fault keep their labels
            if not own:  # the user's executor broke; not ours to restart
                raise next(f.exception() for f in in_flight if isinstance(f.exception(), BrokenProcessPool))
            codes = self._discard_executor(kill=kind == "timeout")
            reason = f"timed out after {timeout:g} s" if kind == "timeout" else _death_reason(codes)
            lost = [task for task, _ in in_flight.values()]
            in_flight.clear()
            log.info("%s: %s; worker processes restarted, the %d mesh(es) in flight are relabelled one at a time",
                     self.desc, "a chunk " + reason if kind == "timeout" else reason,
                     sum(len(t.idx) for t in lost))
            if len(lost) == 1 and lost[0].isolated:  # faulted again, alone: it is the culprit
                for i in lost[0].idx:
                    batch.fail(int(i), reason)
            else:
                suspects.extend(Task(np.array([i]), True) for task in lost for i in task.idx)
            restarts += 1
            if restarts > self.max_restarts and (normal or suspects):
                why = (f"not labelled: the worker processes were restarted {restarts} times in one call "
                       f"(max_restarts={self.max_restarts}; last: {reason})")
                batch.give_up((normal, suspects), why)

        try:
            while normal or suspects or in_flight:
                try:
                    submit_ready(normal, suspects, in_flight, limit, submit)
                except BrokenProcessPool:
                    if not own:
                        raise
                    fault("died")
                    continue
                wait = None
                if timeout is not None:  # slices of POLL_S, so the clock sees when this process was stopped
                    oldest = min(t0 for _, t0 in in_flight.values())
                    wait = min(POLL_S, max(0.0, oldest + timeout - clock()))
                done, _ = cf.wait(in_flight, timeout=wait, return_when=cf.FIRST_COMPLETED)
                broken = [fut for fut in done if not harvest(fut)]
                if broken:
                    fault("died")
                elif not done and timeout is not None and clock() - oldest >= timeout:
                    fault("timeout")
        except BaseException:
            for fut in in_flight:
                fut.cancel()
            if own:  # interrupted (or an unexpected error): do not leave chunks running in the workers
                self._discard_executor(kill=True)
            raise
