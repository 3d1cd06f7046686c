"""The dask.distributed path of :class:`~neuralcol.collision.pool.LabelPool` (``executor="dask"``).

Imported only when a pool uses dask (``pip install "dask[distributed]"``). The pool connects a client to the
scheduler at ``scheduler`` (a cluster it never shuts down), or starts a ``LocalCluster`` of ``workers`` worker
processes with one thread each on this machine (loopback only, no dashboard; closed by ``LabelPool.close``).

* **The labeler is sent once**, as a worker plugin (:class:`_LabelerPlugin`): the scheduler keeps it and installs
  it on every worker, including the ones that join or are restarted later, so a worker that replaces a dead one
  has the labeler before it takes a task (data scattered with ``client.scatter`` would be lost with the last
  worker that held it). Each task carries only its chunk of meshes and the pool's token.
* **Order and values**: the same chunks and the same per-chunk function as the in-process path
  (:func:`~neuralcol.collision.pool_common.label_chunk`), reassembled by index: bit-identical labels.
* **Bounded memory**: at most ``2 x`` the cluster's thread count chunks are in flight (measured at each call).
* **A worker that dies** (``os._exit``, a segfault, SIGKILL, the OOM killer): dask's nanny restarts it and the
  scheduler resubmits the tasks it held, up to ``distributed.scheduler.allowed-failures`` deaths per task. If
  dask gives up on a chunk (``KilledWorker``), its meshes become suspects: relabelled one at a time with nothing
  else in flight, and a mesh whose task kills workers alone is reported (``"worker died (dask KilledWorker:
  ...)"``).
* **A chunk that hangs** (``timeout``): each task logs a start event (``Worker.log_event``) that the pool
  receives, so a chunk's clock starts when a worker thread takes it; past ``timeout`` the pool cancels the
  chunk, kills that worker process through its nanny (which starts a new one, as after a crash; without a nanny
  ``Client.restart_workers``) and its meshes become suspects; a mesh that times out alone is reported
  (``"timed out after 3 s"``).
* ``max_restarts`` counts the chunks dask gave up on and the hung workers killed, per call.
* **The scheduler connection is lost** (or someone cancels the pool's tasks): ``RuntimeError``; the cluster is
  not the pool's to restart.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import os
import queue
import signal
import uuid
import weakref
from concurrent.futures import CancelledError

import numpy as np
from distributed import Client, KilledWorker, LocalCluster, get_worker
from distributed.diagnostics.plugin import WorkerPlugin

from neuralcol.collision import pool_common as common

log = logging.getLogger(__name__)

IN_FLIGHT_PER_THREAD = 2  # chunks in flight per worker thread of the cluster (one running, one queued)
RESTART_TIMEOUT = 120.0  # seconds a hung worker may take to restart

# The labelers of the LabelPools using this worker process, by token (set by _LabelerPlugin; never set in the
# parent process), and the tokens whose labeler has labelled its rest mesh once (kernels loaded or compiled).
_LABELERS: dict[str, object] = {}
_WARM: set[str] = set()


class _LabelerPlugin(WorkerPlugin):
    """Keeps a LabelPool's labeler in every worker process of the cluster (the scheduler sends it to each worker,
    including the ones started later)."""

    idempotent = False

    def __init__(self, token: str, labeler):
        self.token = token
        self.name = f"neuralcol-labeler-{token}"
        self.labeler = labeler

    def setup(self, worker) -> None:
        _LABELERS[self.token] = self.labeler

    def teardown(self, worker) -> None:
        _LABELERS.pop(self.token, None)
        _WARM.discard(self.token)


class ClusterLost(RuntimeError):
    """The dask scheduler connection was lost, or the cluster cancelled the pool's tasks."""


def _topic(token: str) -> str:
    return f"neuralcol-label-start-{token}"


def _label_chunk_dask(token: str, tid: int, chunk: np.ndarray, log_start: bool,
                      clearance_limit: float | None = None) -> list:
    """A dask task: labels of a chunk (C, V, 3) float64 with the labeler the pool installed on this worker.

    Args:
        token: the pool's token (selects its labeler in :data:`_LABELERS`).
        tid: the task's number in the pool (named in the start event).
        chunk: (C, V, 3) float64 vertices.
        log_start: send a start event (``timeout``), after the labeler's warm-up.
        clearance_limit: None (full labels) or the clearance cap of labels for training.

    Returns:
        C entries: the mesh's Label, or a failure reason (see :func:`~neuralcol.collision.pool_common.label_chunk`).
    """
    labeler = _LABELERS.get(token)
    if labeler is None:
        raise RuntimeError("this dask worker has no labeler for the LabelPool (its worker plugin is not installed)")
    if token not in _WARM:  # label the rest mesh once, outside any chunk's timeout
        _WARM.add(token)
        common.warm_up(labeler)
    if log_start:
        worker = get_worker()
        worker.log_event(_topic(token), {"tid": tid, "worker": worker.address})
    return common.label_chunk(labeler, chunk, clearance_limit)


def _kill_worker_process(dask_worker) -> int:
    """Run on a worker's nanny (``Client.run(..., nanny=True)``): SIGKILL its worker process; the nanny then
    starts a new one, as after a crash."""
    pid = dask_worker.pid
    if not pid:
        raise RuntimeError("the nanny has no worker process")
    os.kill(pid, signal.SIGKILL)
    return pid


def _shutdown(client: Client, cluster: LocalCluster | None, plugin: str | None, topic: str | None) -> None:
    """Remove the pool's labeler from the workers, close the client and the LocalCluster the pool started."""
    try:
        if client.status == "running":
            if topic is not None:
                client.unsubscribe_topic(topic)
            if plugin is not None and cluster is None:  # a LocalCluster of our own goes away anyway
                client.unregister_worker_plugin(plugin)
    except Exception as exc:  # the scheduler may be gone; nothing to clean up there then
        log.debug("LabelPool: could not remove the labeler from the dask workers: %s", common.failure_reason(exc))
    for what, close in (("client", client.close), ("LocalCluster", cluster.close if cluster is not None else None)):
        if close is not None:
            try:
                close()
            except Exception as exc:  # closing must not raise (e.g. the scheduler is gone already)
                log.warning("LabelPool: closing the dask %s failed: %s", what, common.failure_reason(exc))


class DaskSession:
    """A dask client for one LabelPool, the LocalCluster it started (if any) and the labeler on every worker.

    Args:
        labeler: the exact labeler.
        scheduler: address of a running scheduler ("tcp://host:8786"), or None to start a LocalCluster.
        n_workers: worker processes of the LocalCluster (one thread each).
        timeout: chunk time limit of the pool (None: no start events are sent).
    """

    def __init__(self, labeler, scheduler: str | None, n_workers: int, timeout: float | None):
        self.cluster: LocalCluster | None = None
        try:
            if scheduler is None:
                # loopback only, no dashboard; the scheduler's small HTTP server (health, metrics) on any free port
                self.cluster = LocalCluster(n_workers=max(1, n_workers), threads_per_worker=1, processes=True,
                                            host="127.0.0.1", dashboard_address=None,
                                            scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})
                self.client = Client(self.cluster, set_as_default=False)
            else:
                self.client = Client(scheduler, set_as_default=False, timeout=60)
        except Exception as exc:
            if self.cluster is not None:
                self.cluster.close()
            where = f"the dask scheduler at {scheduler}" if scheduler else "a dask LocalCluster"
            raise RuntimeError(f"LabelPool: cannot start or reach {where} ({common.failure_reason(exc)})") from exc
        self.token = uuid.uuid4().hex
        self.topic = _topic(self.token) if timeout is not None else None
        self.plugin: str | None = None
        self._finalizer = weakref.finalize(self, _shutdown, self.client, self.cluster, None, None)
        try:
            self.client.wait_for_workers(1, timeout=common.STARTUP_TIMEOUT)
            plugin = _LabelerPlugin(self.token, labeler)
            self.client.register_plugin(plugin)
            self.plugin = plugin.name
        except Exception as exc:
            self.close()
            why = common.failure_reason(exc)
            raise RuntimeError(f"LabelPool: the dask workers did not take the labeler ({why})") from exc
        self._finalizer.detach()
        self._finalizer = weakref.finalize(self, _shutdown, self.client, self.cluster, self.plugin, self.topic)
        # start events of the chunks (timeout only): task number -> (self.clock() when received, worker address);
        # the clock leaves out time this process was stopped (kill -STOP, Ctrl-Z)
        self.clock = common.RunClock()
        self.started: dict[int, tuple[float, str]] = {}
        if self.topic is not None:
            self.client.subscribe_topic(self.topic, self._on_start)
        self._tid = 0

    def _on_start(self, event) -> None:  # runs in the client's event-loop thread
        msg = event[1]
        self.started[int(msg["tid"])] = (self.clock(), str(msg["worker"]))

    @property
    def address(self) -> str:
        return self.client.scheduler.address

    def threads(self) -> int:
        """Worker threads of the cluster now."""
        return int(sum(self.client.nthreads().values()))

    def submit(self, chunk: np.ndarray, clearance_limit: float | None = None):
        """Submit a chunk; returns (future, task number)."""
        self._tid += 1
        fut = self.client.submit(_label_chunk_dask, self.token, self._tid, chunk, self.topic is not None,
                                 clearance_limit,
                                 key=f"neuralcol-label-{self.token[:8]}-{self._tid}", pure=False)
        return fut, self._tid

    def kill_worker(self, address: str) -> bool:
        """Kill a (hung) worker process; its nanny starts a new one (as after a crash). Without a nanny, the
        scheduler is asked to restart (or remove) it. False if it could not be killed."""
        try:
            out = self.client.run(_kill_worker_process, workers=[address], nanny=True, on_error="return")
            if not isinstance(out.get(address), BaseException):
                return True
            why = common.failure_reason(out[address])
        except Exception as exc:
            why = common.failure_reason(exc)
        log.info("LabelPool: cannot kill the dask worker %s through its nanny (%s); asking the scheduler to "
                 "restart it", address, why)
        try:
            status = self.client.restart_workers([address], timeout=RESTART_TIMEOUT, raise_for_error=False)
            if status.get(address) in ("OK", "removed"):
                return True
            why = str(status.get(address))
        except Exception as exc:
            why = common.failure_reason(exc)
        log.warning("LabelPool: could not restart the hung dask worker %s (%s); its thread stays busy", address, why)
        return False

    def close(self) -> None:
        self._finalizer()


def run_dask(pool, session: DaskSession, v: np.ndarray, tasks: list[common.Task], batch: common.Batch) -> None:
    """Label ``tasks`` of ``v`` on the dask cluster of ``session``; faults handled as the module docstring says."""
    client = session.client
    limit = IN_FLIGHT_PER_THREAD * max(1, session.threads())
    timeout = pool.timeout
    normal = collections.deque(tasks)
    suspects: collections.deque[common.Task] = collections.deque()  # labelled alone, nothing else in flight
    in_flight: dict = {}  # future -> (task, task number)
    done_q: queue.Queue = queue.Queue()  # futures whose result is in (filled by dask's callback thread)
    restarts = 0

    def submit(q: collections.deque[common.Task]) -> None:
        task = q.popleft()
        fut, tid = session.submit(v[task.idx], batch.clearance_limit)
        in_flight[fut] = (task, tid)
        fut.add_done_callback(done_q.put)

    def restarted(reason: str) -> None:
        """Count a restart; past ``max_restarts``, report every mesh not labelled yet."""
        nonlocal restarts
        restarts += 1
        if restarts > pool.max_restarts and (normal or suspects):
            why = (f"not labelled: dask gave up on or restarted workers for {restarts} chunks in one call "
                   f"(max_restarts={pool.max_restarts}; last: {reason})")
            batch.give_up((normal, suspects), why)

    def lost(task: common.Task, reason: str) -> None:
        """A chunk killed its workers or hung: a suspect alone is the culprit, the others are relabelled alone."""
        if task.isolated:
            for i in task.idx:
                batch.fail(int(i), reason)
        else:
            log.info("%s: a chunk %s; its %d mesh(es) are relabelled one at a time", pool.desc, reason,
                     len(task.idx))
            suspects.extend(common.Task(np.array([i]), True) for i in task.idx)
        restarted(reason)

    def harvest(fut) -> None:
        task, tid = in_flight.pop(fut)
        session.started.pop(tid, None)
        status = fut.status
        if status == "finished":
            retries = batch.settle(task, fut.result())
        elif status == "error":
            exc = fut.exception()
            if isinstance(exc, KilledWorker):
                lost(task, f"worker died (dask KilledWorker: {exc.allowed_failures + 1} workers died running it)")
                return
            # the task itself failed (e.g. its result could not be pickled): charged like a raising mesh
            retries = [t for i in task.idx for t in batch.charge(int(i), common.failure_reason(exc), task.isolated)]
        else:  # cancelled, not by us: the scheduler connection was lost, or someone cancelled our work
            exc = getattr(getattr(fut, "_state", None), "exception", None)  # FutureCancelledError: the reason
            why = common.failure_reason(exc) if isinstance(exc, BaseException) else status
            raise ClusterLost(f"LabelPool: the dask cluster at {session.address} dropped a chunk ({why}); the "
                              "cluster is not the pool's to restart")
        for t in retries:
            (suspects if t.isolated else normal).append(t)

    def check_hung() -> None:
        """Cancel the chunks running for more than ``timeout`` seconds and restart their workers."""
        now = session.clock()
        workers = None
        for fut, (task, tid) in list(in_flight.items()):
            t0, address = session.started.get(tid, (None, None))
            if t0 is None or now - t0 <= timeout or fut.done():
                continue
            if workers is None:
                workers = set(client.scheduler_info()["workers"])
            if address not in workers:  # that worker died and dask resubmitted the chunk: wait for a new start
                session.started.pop(tid, None)
                continue
            del in_flight[fut]
            session.started.pop(tid, None)
            fut.cancel()
            log.info("%s: a chunk ran for more than %g s on %s; restarting that worker", pool.desc, timeout, address)
            session.kill_worker(address)
            workers = None
            lost(task, f"timed out after {timeout:g} s")

    poll = common.POLL_S if timeout is None else min(common.POLL_S, timeout / 4)  # the clock read at least this often
    try:
        while normal or suspects or in_flight:
            common.submit_ready(normal, suspects, in_flight, limit, submit)
            try:
                fut = done_q.get(timeout=poll)
            except queue.Empty:
                fut = None
            while fut is not None:
                if fut in in_flight:  # else a chunk cancelled after a timeout
                    harvest(fut)
                try:
                    fut = done_q.get_nowait()
                except queue.Empty:
                    fut = None
            if in_flight and client.status in ("closing", "closed"):
                raise ClusterLost(f"LabelPool: the dask cluster at {session.address} dropped a chunk (client "
                                  f"{client.status}); the cluster is not the pool's to restart")
            if timeout is not None and in_flight:
                check_hung()
    except BaseException as exc:
        for fut in in_flight:  # interrupted (or the cluster is gone): do not leave our chunks queued
            try:
                fut.cancel()
            except Exception:
                pass
        cancelled = isinstance(exc, (CancelledError, asyncio.CancelledError))  # a dask call found our work cancelled
        if not isinstance(exc, ClusterLost) and (cancelled or (isinstance(exc, Exception)
                                                                and client.status != "running")):
            # (a dask call can fail in other ways while the connection drops)
            raise ClusterLost(f"LabelPool: the dask cluster at {session.address} dropped a chunk "
                              f"({common.failure_reason(exc)}; client {client.status}); the cluster is not the "
                              "pool's to restart") from exc
        raise
    finally:
        session.started.clear()  # start events of this call's chunks
