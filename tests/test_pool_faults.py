"""LabelPool under worker faults: a mesh that raises, kills its worker or hangs is reported by index, the others
keep the labels of a fault-free run, and the pool stays usable; the oracle and the uniform pool drop and count
the failed samples (never written to D_c).

The faults are injected by tests/fault_labelers.py (an ExactLabeler subclass keyed on a sentinel vertex).
Worker-process tests spawn real workers (a few seconds each on a busy machine); the whole file takes ~1 min.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import torch
from fault_labelers import EXIT, FLAKY, HANG, NAN, RAISE, SLOW, FaultLabeler, mark, two_spheres

from neuralcol.active.acquisition import AcquiredRows, UniformAcquisition, concat_acquired
from neuralcol.collision import pool_common
from neuralcol.collision.labeler import ExactLabeler, Labels
from neuralcol.collision.pool import LabelingError, LabelPool
from neuralcol.samples.oracle import LatentOracle
from neuralcol.samples.store import CollisionStore, StoreCorruptedError
from neuralcol.samples.uniform import labeled_uniform_rows, uniform_codes, uniform_rows

OFFSETS = [1.5, 2.6, 1.9, 3.0, 1.2, 2.05, 1.99, 4.0]  # overlapping (< 2) and free (> 2)


@pytest.fixture(scope="module")
def setup():
    rest, faces = two_spheres(3.0)
    partition = np.repeat([0, 1], len(rest) // 2)
    clean = ExactLabeler(faces, rest, partition=partition)
    faulty = FaultLabeler(faces, rest, partition=partition)
    batch = np.stack([two_spheres(o)[0] for o in OFFSETS])
    return clean, faulty, batch


def reference(clean: ExactLabeler, batch: np.ndarray) -> Labels:
    return Labels.stack([clean.label(v) for v in batch], clean.n_parts)


def assert_rows_equal(got: Labels, want: Labels, rows) -> None:
    for name in Labels._fields:
        g, w = getattr(got, name), getattr(want, name)
        assert g.dtype == w.dtype, name
        np.testing.assert_array_equal(g[rows], w[rows], err_msg=f"field {name}")


def assert_failed_rows(report, bad: list[int]) -> None:
    assert [f.index for f in report.failures] == bad
    assert np.flatnonzero(~report.ok).tolist() == bad
    assert np.isnan(report.labels.pd[bad]).all() and np.isnan(report.labels.pd_sub[bad]).all()
    assert (report.labels.n_pairs[bad] == -1).all() and not report.labels.collides[bad].any()


@pytest.mark.parametrize("workers", [0, 2])
def test_raise_on_one_mesh_is_reported_others_identical(setup, workers, caplog):
    clean, faulty, batch = setup
    bad = batch.copy()
    bad[2], bad[5] = mark(bad[2], RAISE), mark(bad[5], NAN)
    ref = reference(clean, bad)
    with LabelPool(faulty, workers=workers, chunk_size=3, desc="test batch") as pool:
        with caplog.at_level(logging.WARNING, logger="neuralcol.collision.pool"):
            report = pool.label_report(bad)
        assert_failed_rows(report, [2, 5])
        assert report.failures[0].reason == "ValueError: degenerate mesh (injected fault)"
        assert report.failures[1].reason.startswith("non-finite label")
        assert_rows_equal(report.labels, ref, report.ok)
        # one warning line for the batch, naming the indices and reasons
        (line,) = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert line.startswith("test batch: 2 of 8 meshes could not be labelled: [2] ValueError") and "[5]" in line
        # label() (the default, raising mode) names the failed meshes
        with pytest.raises(LabelingError, match=r"\[2\] ValueError: degenerate.*\[5\] non-finite") as err:
            pool.label(bad)
        assert err.value.report.ok.tolist() == report.ok.tolist()
        # the pool is still usable
        assert_rows_equal(pool.label(batch), reference(clean, batch), slice(None))


def test_transient_failure_is_retried(setup):
    clean, faulty, batch = setup
    bad = batch.copy()
    bad[4] = mark(bad[4], FLAKY)
    report = LabelPool(faulty, chunk_size=3).label_report(bad)
    assert report.ok.all() and not report.failures
    assert_rows_equal(report.labels, reference(clean, bad), slice(None))


def test_user_executor_catches_exceptions(setup):
    clean, faulty, batch = setup
    bad = batch.copy()
    bad[7] = mark(bad[7], RAISE)
    with ThreadPoolExecutor(max_workers=2) as ex:
        report = LabelPool(faulty, executor=ex, chunk_size=3).label_report(bad)
    assert_failed_rows(report, [7])
    assert_rows_equal(report.labels, reference(clean, bad), report.ok)


def test_worker_death_is_isolated_and_reported(setup):
    clean, faulty, batch = setup
    bad = batch.copy()
    bad[4] = mark(bad[4], EXIT)
    with LabelPool(faulty, workers=2, chunk_size=3) as pool:
        report = pool.label_report(bad)
        assert_failed_rows(report, [4])
        assert report.failures[0].reason == "worker died (exit code 3)"
        assert_rows_equal(report.labels, reference(clean, bad), report.ok)
        # the pool restarted its workers and labels the next batch
        assert_rows_equal(pool.label(batch[::-1]), reference(clean, batch[::-1]), slice(None))


def test_restart_limit_reports_the_rest(setup):
    clean, faulty, batch = setup
    bad = batch.copy()
    bad[0] = mark(bad[0], EXIT)
    with LabelPool(faulty, workers=2, chunk_size=4, max_restarts=0) as pool:
        report = pool.label_report(bad)
    assert 0 in [f.index for f in report.failures]
    assert all("max_restarts=0" in f.reason for f in report.failures)
    assert_rows_equal(report.labels, reference(clean, bad), report.ok)


def test_hang_times_out_and_is_reported(setup):
    clean, faulty, batch = setup
    bad = batch.copy()
    bad[1] = mark(bad[1], HANG)
    with LabelPool(faulty, workers=2, chunk_size=2, timeout=3) as pool:
        t0 = time.monotonic()
        report = pool.label_report(bad)
        seconds = time.monotonic() - t0
    assert_failed_rows(report, [1])
    assert report.failures[0].reason == "timed out after 3 s"
    assert_rows_equal(report.labels, reference(clean, bad), report.ok)
    assert seconds < 60, "two timeouts plus two restarts"


def test_a_stopped_process_is_not_a_hung_chunk(setup, caplog):
    """``kill -STOP`` of the labeling process and its workers for longer than the timeout (Ctrl-Z, a paused
    queue), during a slow chunk: when they go on, the chunk is not taken for hung (a paper-scale run
    lost 20 minutes to that: the pause counted as the chunk's running time). The timeout leaves the slow chunk's
    1.5 s of CPU time room on a loaded machine (a quarter of a core); the pause outlasts it."""
    clean, faulty, batch = setup
    slow = batch.copy()
    slow[1] = mark(slow[1], SLOW)
    with LabelPool(faulty, workers=2, chunk_size=4, timeout=6) as pool:
        pool.label(batch[:2])  # the workers are up
        pids = " ".join(str(p) for p in [os.getpid(), *(c.pid for c in multiprocessing.active_children())])
        stopper = subprocess.Popen(["sh", "-c", f"sleep 0.5; kill -STOP {pids}; sleep 8; kill -CONT {pids}"])
        try:
            with caplog.at_level(logging.INFO, logger="neuralcol.collision.pool"):
                t0 = time.monotonic()
                report = pool.label_report(slow)
                seconds = time.monotonic() - t0
        finally:
            stopper.wait()
    assert seconds > 8, "the stopper did not stop this process"
    assert not report.failures and "timed out" not in caplog.text
    assert_rows_equal(report.labels, reference(clean, slow), report.ok)


def test_run_clock_leaves_out_stopped_time(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(pool_common.time, "monotonic", lambda: now[0])
    clock = pool_common.RunClock(max_gap=2.0)
    readings = []
    for t in (100.5, 101.9, 103.8, 113.8, 114.3):  # gaps 0.5, 1.4, 1.9 (running), 10 (stopped), 0.5
        now[0] = t
        readings.append(clock())
    assert readings == pytest.approx([100.5, 101.9, 103.8, 103.8 + pool_common.POLL_S, 104.3 + pool_common.POLL_S])


def test_non_finite_meshes(setup):
    clean, faulty, batch = setup
    bad = batch.copy()
    bad[3, 5, 1] = np.nan
    bad[6, 0, 0] = np.inf
    pool = LabelPool(clean, chunk_size=3)
    report = pool.label_report(bad)
    assert_failed_rows(report, [3, 6])
    assert {f.reason for f in report.failures} == {"non-finite vertices"}
    keep = [0, 1, 2, 4, 5, 7]
    want = reference(clean, bad[keep])
    for name in Labels._fields:
        np.testing.assert_array_equal(getattr(report.labels, name)[keep], getattr(want, name))
    with pytest.raises(ValueError, match=r"meshes \[3, 6\]"):  # label() refuses the batch up front, as before
        pool.label(bad)


def test_bad_fault_arguments(setup):
    clean, _, _ = setup
    with ThreadPoolExecutor(1) as ex:
        for kwargs, match in [({"timeout": 0}, "timeout"), ({"timeout": "1"}, "timeout"),
                              ({"max_restarts": -1}, "max_restarts"),
                              ({"timeout": 5, "executor": ex}, "user executor")]:
            with pytest.raises(ValueError, match=match):
                LabelPool(clean, **kwargs)


# ----------------------------------------------------------------------------- the oracle and D_c
class SphereSpace:
    """A stand-in latent space: code (offset, m) decodes to two spheres ``offset`` apart; m > 2.7 marks the
    mesh so the FaultLabeler raises, 2.4 < m <= 2.7 gives NaN vertices."""

    dim, n_parts = 2, 2
    box_lo = torch.tensor([1.0, 0.0], dtype=torch.float64)
    box_hi = torch.tensor([3.0, 3.0], dtype=torch.float64)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        from fault_labelers import SphereDecoder

        return torch.as_tensor(SphereDecoder()(z.numpy()))


def test_oracle_reports_and_drops_failures(setup):
    clean, faulty, _ = setup
    space = SphereSpace()
    oracle = LatentOracle(space, LabelPool(faulty, chunk_size=2))
    z = torch.tensor([[1.5, 0.0], [2.6, 2.9], [3.0, 2.5], [1.2, 1.0], [2.5, 0.5]])
    lab = oracle(z)
    assert lab.n_failed == 2 and lab.ok.tolist() == [True, False, False, True, True]
    assert [i for i, _ in lab.failures] == [1, 2]
    assert "ValueError" in lab.failures[0][1] and lab.failures[1][1] == "non-finite vertices"
    assert lab.subset[1] == lab.subset[2] == -1 and np.isnan(lab.pd[[1, 2]]).all()
    kept = lab.without_failures()
    assert len(kept.z) == 3 and kept.n_failed == 2 and np.isfinite(kept.pd).all()
    np.testing.assert_array_equal(kept.z, z.numpy()[[0, 3, 4]])
    want = [clean.label(v).pd for v in oracle.decode(z[[0, 3, 4]])]
    np.testing.assert_array_equal(kept.pd, want)


def test_uniform_rows_replace_failed_codes(setup, tmp_path):
    _, faulty, _ = setup
    space = SphereSpace()
    oracle = LatentOracle(space, LabelPool(faulty, chunk_size=8))
    path = tmp_path / "u.h5"
    rows, _, labeled, failed = uniform_rows(path, oracle, 30, seed=1)
    assert len(rows.z) == labeled == 30 and failed > 0
    codes = uniform_codes(space, 1, 0, 30 + failed).numpy()
    good = codes[:, 1] <= 2.4
    assert good.sum() == 30 and good[-1], "the failed codes were replaced by the next ones"
    np.testing.assert_array_equal(rows.z, codes[good])
    assert np.isfinite(rows.pd).all() and np.isfinite(rows.pd_sub).all() and (rows.subset >= 0).all()
    with CollisionStore(path, space.dim, space.n_parts) as store:
        assert int(store.attrs["n_codes"]) == 30 + failed and int(store.attrs["n_label_failures"]) == failed
    # growing the store continues the same sequence
    more, _, labeled = labeled_uniform_rows(path, oracle, 40, seed=1)
    assert labeled == 10 and np.array_equal(more.z[:30], rows.z)
    codes = uniform_codes(space, 1, 0, 80).numpy()
    np.testing.assert_array_equal(more.z, codes[codes[:, 1] <= 2.4][:40])
    # the uniform acquisition counts the failures of the rows it had to label
    take = UniformAcquisition(path, oracle, seed=1)
    take.cursor = 40
    got = take.take_uniform(5)
    assert len(got.z) == 5 and got.info["n_label_failures"] == got.info["n_uniform_label_failures"] >= 0
    assert np.isfinite(got.pd).all()


def test_concat_sums_label_failures():
    def part(n_failed):
        return AcquiredRows(*(np.zeros(0) for _ in range(6)), 0.0, 0.0, {"n_label_failures": n_failed})

    assert concat_acquired([part(2), part(3)]).info["n_label_failures"] == 5


def test_training_oracle_gives_the_full_labels_clipped_targets_and_its_own_pool(setup, tmp_path):
    """LatentOracle.for_training(pd_floor): clearances capped at the floor's depth; the detector's targets, verdicts
    and subsets equal the full oracle's bit for bit; a cached uniform pool holds one kind of labels only."""
    from neuralcol.samples.datamodule import detector_targets
    from neuralcol.samples.store import CollisionRows

    clean, _, _ = setup
    space = SphereSpace()
    full = LatentOracle(space, LabelPool(clean, chunk_size=3))
    limited = full.for_training(-0.25)
    assert full.for_training(None) is full and limited.pool is full.pool
    assert limited.clearance_limit == pytest.approx(0.25 * clean.cap) and limited.clearance_limit > 0.25 * clean.cap
    z = torch.tensor([[1.5, 0.0], [2.6, 0.1], [2.02, 0.2], [1.99, 1.0], [2.3, 0.5], [2.9, 1.5]])
    a, b = full(z), limited(z)
    assert (b.pd_sub < a.pd_sub).sum() == 0 and (b.pd_sub > a.pd_sub).any(), "some clearance was capped"
    np.testing.assert_array_equal(a.collides, b.collides)
    np.testing.assert_array_equal(a.subset, b.subset)

    def rows(lab):
        n = len(lab.z)
        return CollisionRows(lab.z, lab.pd, lab.pd_sub, lab.collides, lab.subset, np.zeros(n, np.int16),
                             np.zeros(n, np.int8), np.arange(n))

    for x, y in zip(detector_targets(rows(a), clean.cap, 0.25, pd_floor=-0.25),
                    detector_targets(rows(b), clean.cap, 0.25, pd_floor=-0.25)):
        assert torch.equal(x, y)
    uniform_rows(tmp_path / "u.h5", full, 4, seed=1)
    with pytest.raises(StoreCorruptedError, match="clearance limit"):
        uniform_rows(tmp_path / "u.h5", limited, 8, seed=1)
    uniform_rows(tmp_path / "v.h5", limited, 4, seed=1)
    assert uniform_rows(tmp_path / "v.h5", limited, 6, seed=1).labeled == 2


@pytest.mark.parametrize("workers", [0, 2])
def test_codes_decoded_where_they_are_labeled_get_the_labels_of_their_meshes(setup, workers):
    """label_codes_report(codes, decoder): the decoder runs in the workers (pickled once; a new decoder reaches the
    running workers, and its labels are its own); the labels equal label_report on the decoded meshes, non-finite
    meshes and raising ones are reported; close() removes the pool's scratch folder."""
    from fault_labelers import SphereDecoder

    _, faulty, _ = setup
    codes = np.array([[1.5, 0.0], [2.6, 2.5], [3.0, 0.1], [1.2, 2.9], [2.5, 0.5], [1.9, 1.0], [2.2, 0.2]], np.float32)
    dec = SphereDecoder()
    with LabelPool(faulty, workers=workers, chunk_size=3) as pool:
        want = pool.label_report(dec(codes), clearance_limit=0.05)
        got = pool.label_codes_report(codes, dec, clearance_limit=0.05)
        assert [f.index for f in got.failures] == [1, 3]
        assert got.failures[0].reason == "non-finite vertices" and "ValueError" in got.failures[1].reason
        np.testing.assert_array_equal(got.ok, want.ok)
        for name in Labels._fields:
            np.testing.assert_array_equal(getattr(got.labels, name), getattr(want.labels, name), err_msg=name)
        if workers:
            pids = set(pool._pids)
            pool.label_codes_report(codes[:2], dec)
            assert pool._pids == pids, "the same decoder keeps the workers"
            again = pool.label_codes_report(codes, SphereDecoder(), clearance_limit=0.05)
            np.testing.assert_array_equal(again.labels.pd, got.labels.pd)
            shifted = SphereDecoder(shift=1.0)  # the spheres 1 apart further: fewer collide
            moved = pool.label_codes_report(codes, shifted, clearance_limit=0.05)
            assert pool._pids == pids, "a new decoder keeps the workers"
            ref = pool.label_report(shifted(codes), clearance_limit=0.05)
            assert (moved.labels.collides != got.labels.collides).any(), "the second decoder labels other meshes"
            for name in Labels._fields:
                np.testing.assert_array_equal(getattr(moved.labels, name), getattr(ref.labels, name), err_msg=name)
            back = pool.label_codes_report(codes, dec, clearance_limit=0.05)  # and back to the first
            np.testing.assert_array_equal(back.labels.pd, got.labels.pd)
            scratch = pool._scratch.name
            decoders = [f for f in os.listdir(scratch) if f.endswith(".decoder.pkl")]
            assert len(decoders) == 1, "one decoder file at a time"
            assert os.stat(scratch).st_mode & 0o777 == 0o700, "the pickles are this user's alone"
    if workers:
        assert not os.path.exists(scratch), "close() removes the scratch folder"
