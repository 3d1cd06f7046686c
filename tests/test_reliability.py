"""Crash safety and determinism of whole runs, with real processes killed by SIGKILL.

A run of the tiny preset on SCAPE is killed three times in a row at different points by fault injection
(``NEURALCOL_FAULT``, see ``neuralcol/utils/faults.py``): in the middle of writing D_c rows, in the middle of
labeling the next round's samples, and in the middle of fine-tuning. Each time the *same command* is run again;
it continues the unfinished run directory. The finished run must equal an uninterrupted run of the same
command: D_c row for row (every labeled sample exactly once, ids 0..N-1) and the same metrics per round.
The uninterrupted run is itself run twice: the same seed gives the same D_c and metrics (determinism).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
# metrics that measure time or what the shared cache already held, not results
VOLATILE_KEYS = {"decode_ms_per_mesh", "resumed", "from_cache", "inference_us"}


def _volatile(key: str) -> bool:
    return key in VOLATILE_KEYS or key.endswith(("seconds", "seconds_per_mesh", "labeled_now"))


def _run(args: list[str], out: Path, cache: Path, fault: str | None = None,
         stop_at: str | None = None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items()
           if k not in ("HYDRA_FULL_ERROR", "NEURALCOL_FAULT", "NEURALCOL_SITTING_STOP_AT")}
    if fault:
        env["NEURALCOL_FAULT"] = fault
    if stop_at:
        env["NEURALCOL_SITTING_STOP_AT"] = stop_at
    cmd = [sys.executable, "-m", "experiments.run", "dataset=scape", "autoencoder=tiny", "detector=tiny",
           # the realistic set is not compared here (test_run, test_api cover it)
           "realistic.enabled=false", "speed_accuracy.enabled=false",
           "method=active", "handler.n_inputs=4", "handler.verify_margins=[]", "n_example_meshes=0",
           "labeling.pool.workers=0", "labeling.pool.chunk_size=8", "labeling.pool.progress=false",
           f"paths.data_dir={args[0]}", f"paths.cache_dir={cache}", f"paths.output_dir={out}", *args[1:]]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900, env=env)


def _run_dirs(out: Path) -> list[Path]:
    return sorted(p for p in (out / "runs" / "scape" / "active_s0").iterdir() if (p / ".hydra").is_dir())


def _dc(run_dir: Path) -> dict:
    import h5py

    with h5py.File(run_dir / "dc.h5", "r") as h5:
        n = int(h5.attrs["committed"])
        return {k: h5[k][:n] for k in h5.keys()}


def _strip(obj):
    if isinstance(obj, dict):
        return {k: _strip(v) for k, v in obj.items() if not _volatile(k)}
    if isinstance(obj, list):
        return [_strip(v) for v in obj]
    return obj


def _result(run_dir: Path) -> tuple[dict, dict]:
    m = json.loads((run_dir / "metrics.json").read_text())
    return _dc(run_dir), _strip({k: m[k] for k in ("rounds", "detector", "handling", "latent")})


@pytest.fixture(scope="module")
def reference(tmp_path_factory, scape_dir):
    """Two uninterrupted runs of the same command (the shared cache: autoencoder, test set, uniform pool)."""
    base = tmp_path_factory.mktemp("reliability")
    cache = base / "cache"
    results = []
    for name in ("ref_a", "ref_b"):
        proc = _run([str(scape_dir.parent)], base / name, cache)
        assert proc.returncode == 0, proc.stderr[-3000:]
        (run_dir,) = _run_dirs(base / name)
        results.append(_result(run_dir))
    return base, cache, results


def test_same_seed_gives_the_same_dc_and_metrics(reference):
    _, _, ((dc_a, m_a), (dc_b, m_b)) = reference
    assert dc_a.keys() == dc_b.keys()
    for k in dc_a:
        np.testing.assert_array_equal(dc_a[k], dc_b[k], err_msg=k)
    assert m_a == m_b


def test_killed_three_times_then_resumed_equals_the_uninterrupted_run(reference, scape_dir):
    base, cache, ((dc_ref, m_ref), _) = reference
    out, data = base / "killed", [str(scape_dir.parent)]
    n_init, n_aug = 120, 60  # detector=tiny

    # 1. SIGKILL while the second acquisition's rows are written to D_c (on disk, not committed)
    proc = _run(data, out, cache, fault="store_append:3")
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    (run_dir,) = _run_dirs(out)
    assert not (run_dir / "metrics.json").exists()
    assert len(_dc(run_dir)["id"]) == n_init + n_aug, "the half-written rows are not committed"

    # 2. the same command again: resumes, and is killed while labeling the second acquisition's samples
    #    (the data set's 71 meshes are labeled first: 9 chunks of 8)
    proc = _run(data, out, cache, fault="label_chunk:11")
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    assert "resuming the interrupted run in" in proc.stdout
    rounds = json.loads((run_dir / "detector_rounds.json").read_text())["rounds"]
    assert [r["round"] for r in rounds] == [0, 1], "died after round 1, while acquiring round 2's samples"

    # 3. again: resumes from round 1's checkpoint saved before its acquisition (round 1 is not trained again),
    #    finishes the acquisition, is killed in round 2's second epoch (had it retrained round 1 first, it would
    #    be killed there, before the acquisition's rows)
    proc = _run(data, out, cache, fault="train_epoch:2")
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    assert len(_dc(run_dir)["id"]) == n_init + 2 * n_aug

    # 4. again, no fault: finishes in the same directory
    proc = _run(data, out, cache)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert f"resuming the interrupted run in {run_dir}" in proc.stdout
    assert (run_dir / "metrics.json").is_file()
    dc, metrics = _result(run_dir)
    np.testing.assert_array_equal(dc["id"], np.arange(n_init + 2 * n_aug))  # every sample exactly once
    np.testing.assert_array_equal(np.bincount(dc["round"]), [n_init, n_aug, n_aug])
    for k in dc_ref:
        np.testing.assert_array_equal(dc[k], dc_ref[k], err_msg=k)
    assert metrics == m_ref
    # the directories Hydra made for the re-runs only point at the resumed one
    others = [d for d in _run_dirs(out) if d != run_dir]
    assert len(others) == 3 and all((d / "resumed_in.txt").read_text().strip() == str(run_dir) for d in others)


def test_a_finished_run_is_not_resumed_and_resume_false_starts_afresh(reference, scape_dir):
    from neuralcol.utils.resume import find_interrupted_run

    base, _, _ = reference
    (done,) = _run_dirs(base / "ref_a")
    fresh = done.parent / "9999-new"
    (fresh / ".hydra").mkdir(parents=True)
    (fresh / ".hydra" / "overrides.yaml").write_text((done / ".hydra" / "overrides.yaml").read_text())
    assert find_interrupted_run(fresh) is None, "a finished run (metrics.json) is never resumed"
    (done / "metrics.json").rename(done / "metrics.json.bak")
    try:
        assert find_interrupted_run(fresh) == done.resolve()
        (fresh / ".hydra" / "overrides.yaml").write_text("- seed=1\n")
        assert find_interrupted_run(fresh) is None, "other overrides: another experiment"
    finally:
        (done / "metrics.json.bak").rename(done / "metrics.json")


def test_a_sitting_stops_at_a_round_and_the_same_command_finishes_the_run(reference, scape_dir):
    """max_minutes: a sitting stops at a safe point with exit code 75, saying where, and the same command
    goes on from there; the finished run equals the uninterrupted one, and sittings.json holds both sittings."""
    base, cache, ((dc_ref, m_ref), _) = reference
    out, data = base / "sittings", [str(scape_dir.parent), "max_minutes=600"]
    # 1. stops once round 0 is trained, before its acquisition; 2. goes on with that acquisition (no training
    # first), stops at the end of round 0; 3. finishes
    proc = _run(data, out, cache, stop_at="before its acquisition")
    assert proc.returncode == 75, proc.stderr[-3000:]
    assert "[sitting] stopped at round 0's training, before its acquisition (|D_c| = 120)" in proc.stdout
    (run_dir,) = _run_dirs(out)
    proc = _run(data, out, cache, stop_at="the end of round 0")
    assert proc.returncode == 75, proc.stderr[-3000:]
    assert "[sitting] stopped at the end of round 0 (|D_c| = 180)" in proc.stdout
    assert not (run_dir / "metrics.json").exists()
    first = json.loads((run_dir / "sittings.json").read_text())["sittings"]
    assert len(first) == 2 and first[1]["stopped_at"].startswith("the end of round 0")
    assert "detector" in first[0]["stages"] and not first[1]["finished"]
    proc = _run(data, out, cache)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert f"resuming the interrupted run in {run_dir}" in proc.stdout
    dc, metrics = _result(run_dir)
    for k in dc_ref:
        np.testing.assert_array_equal(dc[k], dc_ref[k], err_msg=k)
    assert metrics == m_ref
    sittings = json.loads((run_dir / "metrics.json").read_text())["sittings"]
    assert sittings["n"] == 3 and sittings["stage_seconds"]["detector"] > 0
    assert json.loads((run_dir / "sittings.json").read_text())["sittings"][2]["finished"]


def test_a_round_stopped_inside_goes_on_from_its_epoch(reference, scape_dir):
    """detector.checkpoint_minutes: inside a round the training state is saved at epochs' ends (here
    every epoch), with the round's best validation epoch so far. A sitting stopped there, or a run killed after
    such a save, goes on from the next epoch instead of training the round again, and ends equal to the
    uninterrupted run (same D_c, same metrics: the same epochs selected)."""
    from neuralcol.utils.safe_files import read_torch_file

    base, cache, ((dc_ref, m_ref), _) = reference
    out = base / "inside"
    data = [str(scape_dir.parent), "max_minutes=600", "detector.checkpoint_minutes=0"]
    # tiny: 4 epochs a round; round 0 is epochs 0-3, round 1 epochs 4-7, round 2 epochs 8-11
    proc = _run(data, out, cache, stop_at="round 1's epoch 2/4")
    assert proc.returncode == 75, proc.stderr[-3000:]
    assert "[sitting] stopped at round 1's epoch 2/4 (|D_c| = 180)" in proc.stdout
    (run_dir,) = _run_dirs(out)
    ckpt = run_dir / "checkpoints" / "detector.ckpt"
    state = read_torch_file(ckpt)
    assert state["epoch"] == 5
    (rounds_state,) = [v for k, v in state["callbacks"].items() if "RoundCallback" in k]
    assert rounds_state["round"] == 1 and rounds_state["best"]["epoch"] in (4, 5)

    # again, killed when its 4th epoch starts: epochs 6-7 end round 1, 8 is round 2's first, 9 its second. Had it
    # trained round 1 again from its start (epochs 4-7), it would die inside round 1, before recording it
    proc = _run(data, out, cache, fault="train_epoch:4")
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    rounds = json.loads((run_dir / "detector_rounds.json").read_text())["rounds"]
    assert [r["round"] for r in rounds] == [0, 1]
    assert read_torch_file(ckpt)["epoch"] == 8

    proc = _run(data, out, cache)
    assert proc.returncode == 0, proc.stderr[-3000:]
    dc, metrics = _result(run_dir)
    for k in dc_ref:
        np.testing.assert_array_equal(dc[k], dc_ref[k], err_msg=k)
    assert metrics == m_ref
    rounds = json.loads((run_dir / "metrics.json").read_text())["rounds"]
    assert all(0 < r["train_seconds"] < 900 for r in rounds), [r["train_seconds"] for r in rounds]
