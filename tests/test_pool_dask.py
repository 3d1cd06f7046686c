"""LabelPool on a dask.distributed cluster (executor="dask"): the same labels as in this process, in input order,
and the pool's fault guarantees: a worker killed mid-batch loses no label, a mesh that kills every worker it runs
on (or hangs) is reported alone, a mesh that raises is retried then reported.

One LocalCluster of 2 worker processes x 1 thread (loopback, no dashboard) serves the file; its scheduler allows
one worker death per task (``distributed.scheduler.allowed-failures`` 1, dask's default is 3) so the fault tests
need fewer worker restarts. The faults come from tests/fault_labelers.py. The whole file takes ~40 s.
"""

from __future__ import annotations

import importlib.util
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from fault_labelers import EXIT, EXIT_ONCE, HANG, NAN, RAISE, FaultLabeler, mark, two_spheres
from omegaconf import OmegaConf

distributed = pytest.importorskip(
    "distributed", reason='dask.distributed is not installed (pip install "dask[distributed]")')

import dask  # noqa: E402

from neuralcol.collision.labeler import ExactLabeler, Labels, limit_clearance  # noqa: E402
from neuralcol.collision.pool import LabelPool  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OFFSETS = [1.5, 2.6, 1.9, 3.0, 1.2, 2.05, 1.99, 4.0, 1.7, 2.3, 1.1, 2.8]  # overlapping (< 2) and free (> 2)


@pytest.fixture(scope="module")
def setup():
    rest, faces = two_spheres(3.0)
    partition = np.repeat([0, 1], len(rest) // 2)
    clean = ExactLabeler(faces, rest, partition=partition)
    faulty = FaultLabeler(faces, rest, partition=partition)
    rng = np.random.default_rng(0)
    batch = np.stack([two_spheres(o)[0] for o in OFFSETS])
    batch = batch + 1e-3 * rng.standard_normal(batch.shape)
    return clean, faulty, batch


def local_cluster(n_workers: int) -> distributed.LocalCluster:
    """Worker processes x 1 thread on loopback, no dashboard (the scheduler's health/metrics HTTP server on any
    free port rather than 8787)."""
    return distributed.LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                    dashboard_address=None,
                                    scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})


@pytest.fixture(scope="module")
def cluster():
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        cluster = local_cluster(2)
    yield cluster
    cluster.close()


def reference(clean: ExactLabeler, batch: np.ndarray) -> Labels:
    return Labels.stack([clean.label(v) for v in batch], clean.n_parts)


def assert_rows_equal(got: Labels, want: Labels, rows=slice(None)) -> None:
    for name in Labels._fields:
        g, w = getattr(got, name), getattr(want, name)
        assert g.dtype == w.dtype and g.shape == w.shape, name
        np.testing.assert_array_equal(g[rows], w[rows], err_msg=f"field {name}")


def test_labels_equal_in_process_in_input_order(setup, cluster):
    clean, _, batch = setup
    ref = reference(clean, batch)
    with LabelPool(clean, executor="dask", scheduler=cluster.scheduler_address, chunk_size=3) as pool:
        assert_rows_equal(pool.label(batch), ref)
        order = np.random.default_rng(1).permutation(len(batch))
        assert_rows_equal(pool.label(batch[order]), reference(clean, batch[order]))
        assert pool.label(batch[:0]).pd.shape == (0,)
        limit = 0.1 * float(-ref.pd.min())  # labels for training: clearances capped, the rest equal
        capped = Labels.stack([limit_clearance(clean.label(v), limit) for v in batch], clean.n_parts)
        assert not np.array_equal(capped.pd_sub, ref.pd_sub)
        assert_rows_equal(pool.label(batch, clearance_limit=limit), capped)
        assert "executor='dask'" in repr(pool)
        # at most 2 chunks per cluster thread are in flight
        submitted, submit, peak = [], pool._dask.submit, [0]

        def counting_submit(chunk, *limit):
            fut, tid = submit(chunk, *limit)
            submitted.append(fut)
            peak[0] = max(peak[0], sum(not f.done() for f in submitted))
            return fut, tid

        pool._dask.submit = counting_submit
        pool.chunk_size = 1
        many = np.concatenate([batch] * 3)
        assert_rows_equal(pool.label(many), reference(clean, many))
        assert len(submitted) == len(many) and 2 <= peak[0] <= 4, peak
    # a cluster given by address is left running, without the pool's labeler
    with distributed.Client(cluster, set_as_default=False) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        left = client.run(lambda: sorted(__import__("neuralcol.collision.pool_dask", fromlist=["_"])._LABELERS))
        assert all(v == [] for v in left.values()), left


def test_worker_killed_mid_batch_loses_no_label(setup, cluster, tmp_path):
    clean, faulty, batch = setup
    faulty = FaultLabeler(faulty.faces, faulty.rest, partition=faulty.partition)
    faulty.marker = str(tmp_path / "died")  # the first worker to label mesh 5 dies, dask runs the chunk again
    bad = batch.copy()
    bad[5] = mark(bad[5], EXIT_ONCE)
    with LabelPool(faulty, executor="dask", scheduler=cluster.scheduler_address, chunk_size=2) as pool:
        report = pool.label_report(bad)
    assert Path(faulty.marker).is_file(), "a worker died"
    assert report.ok.all() and not report.failures
    assert_rows_equal(report.labels, reference(clean, bad))


def test_mesh_that_kills_every_worker_is_reported(setup, cluster):
    clean, faulty, batch = setup
    bad = batch.copy()
    bad[4], bad[9] = mark(bad[4], EXIT), mark(bad[9], RAISE)
    with LabelPool(faulty, executor="dask", scheduler=cluster.scheduler_address, chunk_size=3) as pool:
        report = pool.label_report(bad)
        assert [f.index for f in report.failures] == [4, 9]
        assert report.failures[0].reason.startswith("worker died (dask KilledWorker"), report.failures
        assert report.failures[1].reason == "ValueError: degenerate mesh (injected fault)"
        assert np.flatnonzero(~report.ok).tolist() == [4, 9] and np.isnan(report.labels.pd[[4, 9]]).all()
        assert_rows_equal(report.labels, reference(clean, bad), report.ok)
        # the cluster replaced its dead workers: the pool labels the next batch
        assert_rows_equal(pool.label(batch), reference(clean, batch))


def test_hang_times_out_and_is_reported(setup, cluster):
    clean, faulty, batch = setup
    bad = batch[:6].copy()
    bad[1], bad[3] = mark(bad[1], HANG), mark(bad[3], NAN)
    with LabelPool(faulty, executor="dask", scheduler=cluster.scheduler_address, chunk_size=2, timeout=2) as pool:
        t0 = time.monotonic()
        report = pool.label_report(bad)
        seconds = time.monotonic() - t0
    assert [f.index for f in report.failures] == [1, 3]
    assert report.failures[0].reason == "timed out after 2 s"
    assert report.failures[1].reason.startswith("non-finite label")
    assert_rows_equal(report.labels, reference(clean, bad), report.ok)
    assert seconds < 60, "two timeouts plus two worker restarts"


def test_config_starts_and_closes_its_own_cluster(setup, capsys, monkeypatch):
    monkeypatch.setenv("NEURALCOL_PROGRESS", "bar")  # the tqdm bar, as on a terminal
    clean, _, batch = setup
    cfg = OmegaConf.load(ROOT / "conf" / "labeling" / "cpu.yaml").pool
    cfg.executor = "dask"  # scheduler null: a LocalCluster of `workers` processes
    with LabelPool(clean, **OmegaConf.to_container(cfg), desc="dask-labels") as pool:
        assert_rows_equal(pool.label(batch), reference(clean, batch))
        own = pool._dask.cluster
        assert own is not None and len(own.workers) == cfg.workers == 2
    assert pool._dask is None and own.status.name == "closed"
    err = capsys.readouterr().err  # the progress bar, as with the local pool
    assert "dask-labels" in err and f"{len(batch)}/{len(batch)}" in err


def test_lost_scheduler_raises(setup):
    clean, _, batch = setup
    cluster = local_cluster(1)
    pool = LabelPool(clean, executor="dask", scheduler=cluster.scheduler_address, chunk_size=1)
    closer = threading.Timer(0.5, cluster.close)
    try:
        pool.label(batch[:2])
        closer.start()
        with pytest.raises(RuntimeError, match="dask cluster at tcp://127.0.0.1:.* dropped a chunk"):
            pool.label(np.concatenate([batch] * 100))
    finally:
        pool.close()
        if closer.is_alive():  # the pool can raise while the timer's close is still running: two concurrent
            closer.join()      # closes of one LocalCluster fail inside distributed (UnboundLocalError, seen on CI)
        cluster.close()


def test_dask_config_is_valid():
    from hydra import compose, initialize_config_dir

    from neuralcol.pipeline.validate import config_problems

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=["labeling.pool.executor=dask",
                                                       "labeling.pool.scheduler=tcp://127.0.0.1:8786"])
    assert config_problems(cfg) == []


def test_bad_executor_settings(setup, monkeypatch):
    clean, _, _ = setup
    with pytest.raises(ValueError, match=r"executor='spark'; use 'local'.*'dask'"):
        LabelPool(clean, executor="spark")
    with pytest.raises(ValueError, match=r"scheduler='tcp://h:1' is only used with executor='dask'"):
        LabelPool(clean, scheduler="tcp://h:1")
    with pytest.raises(ValueError, match="scheduler=''"):
        LabelPool(clean, executor="dask", scheduler="")
    with pytest.raises(TypeError, match="Executor"):
        LabelPool(clean, executor=3)
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "distributed"
                        else find_spec(name, *a))
    with pytest.raises(ImportError, match=r'pip install "dask\[distributed\]"'):
        LabelPool(clean, executor="dask")
    LabelPool(clean, executor="local")  # the local pool does not need dask
