"""Same command, same numbers: a run's models and metrics do not depend on the machine's core count.

Each run is a subprocess of ``python -m experiments.run`` with its own empty cache, started with
``OMP_NUM_THREADS=1`` or ``=2`` (what a user's shell on another machine amounts to). proc_hand's autoencoder is
trained for 40 epochs per level: enough for thread-dependent float reductions to show (the tiny presets' few
epochs are not). 50 poses (40 training meshes: one batch, so as many steps as with 100) keep it short. The
control run unpins the threads (``threads=null``) and must differ, so the test can fail (its latent space moves by
about 3 after 40 epochs); it stops after the autoencoder.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.compare_runs import compare_arrays, compare_metrics
from neuralcol.nn.latent_space import LatentSpace
from neuralcol.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]
OVERRIDES = ["dataset=proc_hand", "dataset.source.n_poses=50", "autoencoder=tiny", "autoencoder.level1.epochs=40",
             "autoencoder.level2.epochs=40", "detector=tiny", "method=supv", "realistic=tiny",
             "speed_accuracy.enabled=false", "handler.n_inputs=4", "n_example_meshes=0",
             "labeling.pool.workers=0", "labeling.pool.progress=false"]

# the stages after the autoencoder, switched off (the control run needs only its latent space)
AE_ONLY = ["detector.max_rounds=0", "detector.cascade.enabled=false", "box_check.enabled=false",
           "realistic.enabled=false", "handler.n_inputs=0"]


def _run(tmp: Path, name: str, omp: int, *extra: str) -> tuple[RunDir, Path]:
    env = {**os.environ, "OMP_NUM_THREADS": str(omp), "PYTHONUNBUFFERED": "1"}
    for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env.pop(var, None)
    cache = tmp / f"cache_{name}"
    cmd = [sys.executable, "-m", "experiments.run", *OVERRIDES, *extra, f"paths.cache_dir={cache}",
           f"hydra.run.dir={tmp / name}"]
    out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    return RunDir(tmp / name), cache


def _latent_state(cache: Path) -> dict:
    (path,) = cache.glob("autoencoders/*/latent_space.pt")
    return LatentSpace.load(path).state_dict()


def _weight_diff(a: dict, b: dict) -> float:
    assert a.keys() == b.keys()
    return max(float((a[k].double() - b[k].double()).abs().max()) if a[k].numel() else 0.0 for k in a)


def test_same_numbers_on_one_and_two_threads(tmp_path):
    one, cache_one = _run(tmp_path, "one", 1)
    two, cache_two = _run(tmp_path, "two", 2)
    assert _weight_diff(_latent_state(cache_one), _latent_state(cache_two)) == 0.0
    res = compare_metrics(json.loads(one.metrics.read_text()), json.loads(two.metrics.read_text()))
    assert not res["diffs"] and not res["only_a"] and not res["only_b"], res
    assert res["same"] > 50
    assert compare_arrays(one, two) == []  # predictions and detector weights, bit for bit
    # the control: the machine's default threads (what the code did before it pinned them) changes the latent space.
    # Only its latent space is compared, and the autoencoder is trained before (and independently of) every later
    # stage (its cache key: data set, autoencoder settings, seed, threads), so the control skips those stages
    free, cache_free = _run(tmp_path, "free", 2, "threads=null", *AE_ONLY)
    assert _weight_diff(_latent_state(cache_one), _latent_state(cache_free)) > 1e-6


@pytest.mark.parametrize("bad", ["0", "-2", "two", "1.5", "true"])
def test_bad_thread_count_is_named(bad):
    from hydra import compose, initialize_config_dir

    from neuralcol.pipeline.validate import config_problems

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"threads={bad}"])
    assert [p for p in config_problems(cfg) if p.startswith("threads=")], config_problems(cfg)


@pytest.mark.parametrize("good", ["1", "4", "null"])
def test_thread_counts_accepted(good):
    from hydra import compose, initialize_config_dir

    from neuralcol.pipeline.validate import config_problems

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"threads={good}"])
    assert not [p for p in config_problems(cfg) if p.startswith("threads=")]


def test_pinned_block_restores_threads():
    import torch

    from neuralcol.utils.threads import threads_pinned

    before = torch.get_num_threads()
    with threads_pinned(3):
        assert torch.get_num_threads() == 3 and os.environ["OMP_NUM_THREADS"] == "3"
    assert torch.get_num_threads() == before
    with pytest.raises(ValueError, match="threads"):
        with threads_pinned(0):
            pass
