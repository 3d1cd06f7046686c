"""The detector over code and mesh through the whole pipeline (``detector.inputs=code_and_mesh``): its
pairs chosen on the bootstrap and the realistic training meshes, D_c storing every row's features, the realistic
meshes among the rows, a run interrupted mid-rounds resuming with the same pairs, and ``load_run`` judging a mesh
by its own geometry."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]


def _cfg(scape_dir, tmp_path):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=[
            "dataset=scape", "autoencoder=pca", f"paths.data_dir={scape_dir.parent}",
            f"paths.cache_dir={tmp_path}/cache", "n_example_meshes=0", "detector=tiny", "realistic=tiny",
            "speed_accuracy.enabled=false", "detector.cascade.enabled=false",
            "handler.n_inputs=4", "realistic.handler_inputs=0", "detector.inputs=code_and_mesh",
            "detector.operating_fnr=0.1",
            "labeling.pool.workers=0", "labeling.pool.progress=false"])


def test_code_and_mesh_run_stores_features_resumes_and_judges_meshes(tmp_path, scape_dir, monkeypatch):
    from experiments.run import run
    from neuralcol import load_run
    from neuralcol.active import acquisition
    from neuralcol.nn.detector import load_detector
    from neuralcol.samples.store import CollisionStore, Origin

    cfg = _cfg(scape_dir, tmp_path)
    real = acquisition.ProjectedAcquisition.__call__

    def dies_in_round_2(self, round_, net, store, n):
        if round_ == 2:
            raise RuntimeError("simulated crash")
        return real(self, round_, net, store, n)

    monkeypatch.setattr(acquisition.ProjectedAcquisition, "__call__", dies_in_round_2)
    run_dir = tmp_path / "run"
    with pytest.raises(RuntimeError, match="simulated crash"):
        run(cfg, run_dir)
    pairs = np.load(run_dir / "geometry.npz")["pairs"]
    monkeypatch.setattr(acquisition.ProjectedAcquisition, "__call__", real)
    metrics = run(cfg, run_dir)  # resumes after round 1 with the saved pairs
    d = metrics["detector"]
    assert d["resumed"] is True and d["inputs"] == "code_and_mesh" and d["n_pairs"] == len(pairs) > 0
    np.testing.assert_array_equal(np.load(run_dir / "geometry.npz")["pairs"], pairs)
    assert "mesh_detector" not in metrics, "one detector: the separate mesh detector is gone"
    assert not (run_dir / "mesh_detector.pt").exists()
    n_real = d["n_realistic_rows"]
    assert n_real > 0
    assert [r["dataset_size"] for r in metrics["rounds"]] == [120 + n_real, 180 + n_real, 240 + n_real]
    with CollisionStore(run_dir / "dc.h5", 16, 16, n_pairs=None) as store:
        rows = store.read()
    assert rows.geometry.shape == (len(rows.z), len(pairs), 3)
    real_rows = rows.origin == Origin.REALISTIC
    assert real_rows.sum() == n_real and (rows.round[real_rows] == 0).all()
    net, _ = load_detector(run_dir / "detector.pt")
    assert net.geometry is not None and net.geometry.n_pairs == len(pairs)
    r = metrics["realistic"]
    assert r["detection"]["n"] > 0 and "detection_decoded" in r
    # the public API: a mesh is judged by its own geometry, a code by its decoded one
    (run_dir / ".hydra").mkdir(exist_ok=True)
    OmegaConf.save(cfg, run_dir / ".hydra" / "config.yaml")  # (what Hydra writes for a command-line run)
    with load_run(run_dir) as trained:
        v = trained.decode(trained.space.box_lo[None].clone() * 0.5)
        on_mesh = trained.detect(v.double())
        on_code = trained.detect(trained.encode(v.double()))
        with torch.no_grad():
            want = net(trained.encode(v.double()), net.geometry_of_meshes(v.float())).logit
        torch.testing.assert_close(on_mesh.logit, want, rtol=1e-4, atol=1e-4)
        assert on_code.logit.shape == (1,)
    # the operating point: the threshold with FNR <= 0.1 on the calibration set, folded into the output bias
    op = d["operating_point"]
    assert op["operating_fnr"] == 0.1 and op["calibration"]["fnr"] <= 0.1
    last = metrics["rounds"][-1]
    assert last["threshold"] == op["threshold"] and set(last["at_logit_0"]) >= {"accuracy", "fnr"}
    with np.load(run_dir / "test_predictions.npz") as f:
        assert last["fnr"] == pytest.approx(float(np.mean(f["logit"][f["collides"]] <= 0)))
    saved = json.loads((run_dir / "metrics.json").read_text())
    assert saved["detector"]["inputs"] == "code_and_mesh"


def test_a_run_with_contact_summaries_reads_them_on_codes_and_meshes(tmp_path, scape_dir):
    """detector.geometry.summaries=true through the pipeline: two summary rows per sub-domain after the chosen
    pairs, stored with D_c, saved with the run's geometry and the detector, read on a user's mesh by load_run."""
    from experiments.run import run
    from neuralcol import load_run
    from neuralcol.nn.detector import load_detector

    cfg = _cfg(scape_dir, tmp_path)
    cfg.detector.geometry.summaries = True
    cfg.detector.max_rounds = 1
    cfg.realistic.enabled = False  # (the threshold on D_c's realistic rows instead: a shorter run)
    cfg.detector.operating_set = "realistic"
    cfg.handler.n_inputs = 0
    run_dir = tmp_path / "run"
    metrics = run(cfg, run_dir)
    with np.load(run_dir / "geometry.npz") as f:
        n_chosen, flagged = len(f["pairs"]), bool(f["summaries"])
    k = 16  # SCAPE's sub-domains
    assert flagged and metrics["detector"]["n_pairs"] == n_chosen + 2 * k
    net, meta = load_detector(run_dir / "detector.pt")
    assert net.geometry.summary is not None and meta["geometry"]["summaries"]["min_hops"] == 2
    (run_dir / ".hydra").mkdir(exist_ok=True)
    OmegaConf.save(cfg, run_dir / ".hydra" / "config.yaml")
    with load_run(run_dir) as trained:
        v = trained.decode(trained.space.box_lo[None].clone() * 0.5).double()
        with torch.no_grad():
            want = net(trained.encode(v), net.geometry_of_meshes(v.float())).logit
        torch.testing.assert_close(trained.detect(v).logit, want, rtol=1e-4, atol=1e-4)
