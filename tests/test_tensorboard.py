"""TensorBoard as a researcher reads it: one run per stage, round examples with their verdict."""

from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from neuralcol.metrics.tensorboard import pick_examples

CONF = str(Path(__file__).resolve().parents[1] / "conf")


def test_pick_examples_alternates_colliding_and_free():
    assert pick_examples(np.array([0, 0, 1, 0, 1, 1], bool), 4).tolist() == [2, 0, 4, 1]
    assert pick_examples(np.array([1, 1, 1], bool), 2).tolist() == [0, 1]
    assert pick_examples(np.zeros(0, bool), 3).tolist() == []


def _tags(run: Path) -> dict:
    acc = EventAccumulator(str(run), size_guidance={"images": 0, "scalars": 0})
    acc.Reload()
    return acc.Tags(), acc


def test_one_tensorboard_run_per_stage(tmp_path):
    from experiments.run import run

    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        cfg = compose(config_name="config", overrides=[
            "dataset=proc_hand", "dataset.source.n_poses=24", f"paths.cache_dir={tmp_path}/cache", "autoencoder=tiny",
            "detector=tiny", "realistic=tiny", "speed_accuracy.enabled=false",
            "method=supv", "labeling.pool.workers=0", "labeling.pool.progress=false",
            "handler.n_inputs=4", "handler.verify_margins=[]", "n_example_meshes=0",
            "detector.tensorboard_examples=2"])
    metrics = run(cfg, tmp_path / "run")
    from neuralcol.pipeline import STAGES

    assert list(metrics["sittings"]["stage_seconds"]) == list(STAGES)  # every stage timed, in order, by its name
    tb = tmp_path / "run" / "tensorboard"
    assert sorted(p.name for p in tb.iterdir()) == ["autoencoder_level1", "autoencoder_level2", "data",
                                                     "detector_supv", "handling", "latent"]
    tags, _ = _tags(tb / "autoencoder_level1")
    assert any(t.startswith("train") for t in tags["scalars"]), tags["scalars"]
    tags, acc = _tags(tb / "detector_supv")
    sizes = [r["dataset_size"] for r in metrics["rounds"]]
    assert [e.step for e in acc.Scalars("test/accuracy")] == sizes  # x axis: |D_c|
    assert {"samples/0", "samples/1"} <= set(tags["images"])
    assert [e.step for e in acc.Images("samples/0")] == sizes  # one picture per round
    assert len(list((tmp_path / "run" / "round_examples").glob("*.png"))) == 2 * len(sizes)
    # the realistic set, at the final |D_c|, beside U(Z)
    assert {"realistic/accuracy", "realistic/round_trip_agreement"} <= set(tags["scalars"])
    assert [e.step for e in acc.Scalars("realistic/accuracy")] == sizes[-1:]
    tags, _ = _tags(tb / "handling")
    assert "handling/success_rate" in tags["scalars"]
    # the latent space beside its PCA references; 19 training meshes cannot span |Z_all| = 32, so the
    # references say why and log nothing (test_run.py checks them logged on SCAPE)
    tags, _ = _tags(tb / "latent")
    assert {"latent/val_error", "latent/uz_collision_share", "latent/round_trip_agreement"} <= set(tags["scalars"])
    refs = metrics["autoencoder"]["references"]
    assert all("spans at most 18" in r["reason"] for r in refs.values()), refs
    assert not any("_pca_" in t for t in tags["scalars"]), tags["scalars"]
