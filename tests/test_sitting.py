"""The time budget of a sitting (``max_minutes``): where it stops, what it keeps."""

from __future__ import annotations

import numpy as np
import pytest

from neuralcol.utils import sitting


@pytest.fixture(autouse=True)
def _no_budget_after():
    yield
    sitting.stop()


def test_no_budget_never_stops_and_a_spent_one_stops_outside_held_work(monkeypatch):
    sitting.start(None)
    sitting.check("anywhere")
    sitting.start(0)  # <= 0: no budget either
    sitting.check("anywhere")
    sitting.start(1e-9)
    assert sitting.over()
    with sitting.held():
        sitting.check("inside an acquisition")  # held: no stop
    with pytest.raises(sitting.SittingOver, match=r"stopped at the end of round 3 after .* min \(max_minutes=1e-09\)"):
        sitting.check("the end of round 3")
    sitting.start(60)
    monkeypatch.setenv(sitting.STOP_AT_ENV, "round 3")
    sitting.check("the end of round 2")
    with pytest.raises(sitting.SittingOver, match="round 3"):
        sitting.check("the end of round 3")


def test_uniform_labeling_stops_after_a_committed_batch_and_goes_on(tmp_path, monkeypatch):
    """A stop between two committed batches of labels loses none: the next call labels only the rest."""
    from test_active import BallOracle

    import neuralcol.samples.uniform as uniform

    monkeypatch.setattr(uniform, "LABEL_CHUNK", 100)
    oracle = BallOracle()
    sitting.start(1e-9)  # spent: stops at the first safe point
    with pytest.raises(sitting.SittingOver, match=r"labeling u.h5 \(100 of 250 rows\)"):
        uniform.uniform_rows(tmp_path / "u.h5", oracle, 250, seed=3)
    sitting.stop()
    rows, _, labeled, _ = uniform.uniform_rows(tmp_path / "u.h5", oracle, 250, seed=3)
    assert labeled == 150 and len(rows.z) == 250
    whole, _, _, _ = uniform.uniform_rows(tmp_path / "w.h5", oracle, 250, seed=3)
    np.testing.assert_array_equal(rows.z, whole.z)
    np.testing.assert_array_equal(rows.pd, whole.pd)


def test_sitting_record_sums_the_stages_over_sittings(tmp_path):
    from neuralcol.utils.sitting_record import SittingRecord

    a = SittingRecord(tmp_path / "sittings.json")
    a.stage("data", 2.0)
    a.stage("detector", 30.0)
    a.close(stopped_at="the end of round 0")
    b = SittingRecord(tmp_path / "sittings.json")
    b.stage("data", 1.5)
    b.stage("detector", 20.0)
    b.close()
    s = b.summary()
    assert s["n"] == 2 and s["stage_seconds"] == {"data": 3.5, "detector": 50.0}
    assert b.records[0]["stopped_at"] == "the end of round 0" and b.records[1]["finished"]


def test_a_sitting_killed_mid_stage_keeps_that_stage_up_to_its_last_safe_point(tmp_path, monkeypatch):
    """A session's end kills a sitting from outside (no close); the stage it was in (the detector's
    rounds, for an hour) was missing from the wall time per stage. Each safe point (``sitting.check``) now writes the
    running stage's time so far (at most every 30 s), and the summary counts it."""
    from neuralcol.utils import sitting
    from neuralcol.utils import sitting_record as sr

    now = [1000.0]
    monkeypatch.setattr(sr.time, "monotonic", lambda: now[0])  # (time.monotonic itself, restored after the test)
    a = sr.SittingRecord(tmp_path / "sittings.json")
    sitting.on_check(a.progress)
    try:
        a.stage("data", 2.0)
        a.begin("detector")
        now[0] += 10.0
        sitting.check("a label batch")  # 10 s since the last write: not written yet
        now[0] += 50.0
        sitting.check("a label batch")  # 60 s: written
        now[0] += 20.0  # killed here: the last 20 s are lost, the first 60 kept
    finally:
        sitting.stop()
    b = sr.SittingRecord(tmp_path / "sittings.json")  # the next sitting reads what the killed one left
    assert b.records[0]["running"] == {"stage": "detector", "seconds": 60.0}
    b.begin("detector")
    b.stage("detector", 5.0)
    b.close()
    assert "running" not in b.records[1]
    assert b.summary()["stage_seconds"] == {"data": 2.0, "detector": 65.0}
