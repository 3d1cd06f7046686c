"""The detector's training loop (D_c growth, three methods, resume) on an analytic oracle: a ball in Z.

The oracle stands in for "decode + exact labeler": a code collides iff it lies inside a ball, PD is the signed
distance to the sphere (positive inside) and PD_i splits it over the sub-domain blocks with max_i PD_i = PD.
Everything else (stores, acquisition, Newton projection, Lightning rounds, checkpoints) is the real code.
"""

from __future__ import annotations

import json
import time
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from neuralcol.active.stopping import accuracy_elbow, should_stop
from neuralcol.collision.labeler import split_subsets
from neuralcol.metrics.detection import detection_metrics
from neuralcol.nn.detector import load_detector
from neuralcol.samples.oracle import OracleLabels
from neuralcol.samples.store import CollisionStore
from neuralcol.samples.uniform import BLOCK, labeled_uniform_rows, uniform_codes
from neuralcol.stages.detector import train_detector

K, L2 = 4, 1  # sub-domains, level-2 size: D = 8
D = K * (1 + L2)
RADIUS = 1.44  # ~30 % of the box [-1, 1]^8 lies inside


class FakeSpace:
    dim, n_parts = D, K
    box_lo = -torch.ones(D)
    box_hi = torch.ones(D)


class BallOracle:
    """Exact labels of the ball {|z| < RADIUS}."""

    def __init__(self, eps=0.02):
        self.space = FakeSpace()
        self.pool = SimpleNamespace(labeler=SimpleNamespace(eps=eps, cap=0.5, tau=0.0, n_parts=K))
        self.calls = 0
        self.labeled = 0

    def __call__(self, z, desc=None):
        t0 = time.perf_counter()
        z = torch.as_tensor(z, dtype=torch.float32).numpy()
        pd = RADIUS - np.linalg.norm(z.astype(np.float64), axis=1)
        parts = np.concatenate([z[:, :K, None], z[:, K:].reshape(-1, K, L2)], -1)
        b = (parts.astype(np.float64) ** 2).sum(-1)  # (B, K) block contributions
        pd_sub = pd[:, None] - (b.max(1, keepdims=True) - b) / (2 * RADIUS)
        self.calls += 1
        self.labeled += len(z)
        return OracleLabels(z, pd, pd_sub, pd > 0, split_subsets(pd, self.pool.labeler.eps),
                            time.perf_counter() - t0)


def _det_cfg(**over):
    cfg = {"net": {"_target_": "neuralcol.nn.detector.detector_for_space", "_partial_": True, "state_dim": 16,
                   "hidden": 32, "normalize_inputs": True},
           "loss": {"w_pd": 5.0, "w_pdsum": 0.2, "w_r": 2.0, "w_ce": 2.0, "margin": 0.01, "temperature": 0.1},
           "targets": {"pd_clip": 3.0}, "n_init": 200, "n_aug": 100, "max_rounds": 2,
           "stop": {"kneedle": False, "min_points": 5, "sensitivity": 1.0}, "test_size": 500, "test_seed": 99,
           "epochs": 40, "lr": 1e-2, "batch_size": 64, "finetune_epochs": 10, "finetune_lr": 3e-3,
           "finetune_batch_size": 64, "newton": {"eps_z": 1e-7, "max_iter": 30, "damping": 1e-6, "max_step": 0.25},
           "val_every": 1, "select_best_val": True, "accelerator": "cpu", "progress_bar": False}
    cfg.update(over)
    # the components conf/detector/cpu.yaml builds with Hydra, with this dict's settings
    cfg.update({"optimizer": {"_target_": "torch.optim.Adam", "_partial_": True},
                "rounds": {"_target_": "neuralcol.active.rounds.RoundCallback", "_partial_": True,
                           "n_aug": cfg["n_aug"], "max_rounds": cfg["max_rounds"],
                           "stop_at_elbow": cfg["stop"]["kneedle"],
                           "elbow_min_points": cfg["stop"]["min_points"],
                           "elbow_sensitivity": cfg["stop"]["sensitivity"],
                           "select_best_val": cfg["select_best_val"]},
                "trainer": {"_target_": "lightning.Trainer", "_partial_": True, "accelerator": cfg["accelerator"],
                            "devices": 1, "check_val_every_n_epoch": cfg["val_every"],
                            "enable_progress_bar": cfg["progress_bar"], "reload_dataloaders_every_n_epochs": 1,
                            "enable_checkpointing": False, "num_sanity_val_steps": 0, "enable_model_summary": False,
                            "log_every_n_steps": 1}})
    return cfg


def _method(name, det):
    scratch = {"epochs": det["epochs"], "lr": det["lr"], "batch_size": det["batch_size"]}
    tune = {"epochs": det["finetune_epochs"], "lr": det["finetune_lr"], "batch_size": det["finetune_batch_size"]}
    uniform = {"_target_": "neuralcol.active.acquisition.UniformAcquisition", "_partial_": True}
    projected = {"_target_": "neuralcol.active.acquisition.ProjectedAcquisition", "_partial_": True,
                 "projected_fraction": 0.5, "newton": det["newton"]}
    return {"supv": {"name": "supv", "acquisition": uniform, "use_boundary_set": False, "w_b": 0.0,
                     "projected_fraction": 0.0, "bootstrap": {**scratch, "reinit": False},
                     "update": {**scratch, "reinit": True}},
            "supv_bd": {"name": "supv_bd", "acquisition": uniform, "use_boundary_set": True, "w_b": 0.5,
                        "projected_fraction": 0.0, "bootstrap": {**scratch, "reinit": False},
                        "update": {**scratch, "reinit": True}},
            "active": {"name": "active", "acquisition": projected, "use_boundary_set": True, "w_b": 0.5,
                       "projected_fraction": 0.5, "bootstrap": {**scratch, "reinit": False},
                       "update": {**tune, "reinit": False}}}[name]


def _train(tmp_path, method, run="run", oracle=None, **over):
    oracle = oracle or BallOracle()
    det = _det_cfg(**over)
    return train_detector(oracle.space, oracle, det, _method(method, det), "ball", seed=0,
                          cache_dir=tmp_path / "cache", run_dir=tmp_path / run), oracle


# ----------------------------------------------------------------------------- pure pieces
def test_detection_metrics_by_hand():
    pred = np.array([1, 1, 0, 0, 1, 0, 0, 0], bool)
    true = np.array([1, 0, 1, 0, 1, 0, 0, 1], bool)  # TP 2, FP 1, FN 2, TN 3
    m = detection_metrics(pred, true)
    assert m["accuracy"] == pytest.approx(5 / 8)
    assert m["fnr"] == pytest.approx(2 / 4) and m["fpr"] == pytest.approx(1 / 4)
    assert m["balanced_accuracy"] == pytest.approx(1 - (0.5 + 0.25) / 2)
    assert m["base_rate"] == pytest.approx(0.5) and m["majority_accuracy"] == pytest.approx(0.5)
    with pytest.raises(ValueError):
        detection_metrics(pred[:3], true)


def test_kneedle_finds_the_kink_of_a_saturating_curve():
    sizes = np.arange(1, 9) * 1000
    acc = np.minimum(0.80 + 0.05 * np.arange(8), 0.90)  # rises until 3000, flat after
    assert accuracy_elbow(sizes, acc) == 3000
    assert should_stop(sizes[:4], acc[:4], min_points=5) == (False, None)  # too few points yet
    stop, knee = should_stop(sizes, acc, min_points=5)
    assert stop and knee == 3000
    assert not should_stop(sizes, 0.8 + 0.01 * np.arange(8), min_points=5)[0]  # a straight line has no elbow


def test_uniform_rows_are_a_function_of_seed_and_index():
    space = FakeSpace()
    whole = uniform_codes(space, 7, 0, 2 * BLOCK + 10)
    pieces = torch.cat([uniform_codes(space, 7, 0, 5), uniform_codes(space, 7, 5, BLOCK + 3),
                        uniform_codes(space, 7, BLOCK + 3, 2 * BLOCK + 10)])
    assert torch.equal(whole, pieces)
    assert not torch.equal(whole, uniform_codes(space, 8, 0, 2 * BLOCK + 10))
    assert (whole >= -1).all() and (whole <= 1).all()


def test_labeled_uniform_store_extends_and_refuses_another_seed(tmp_path):
    oracle = BallOracle()
    rows, _, labeled = labeled_uniform_rows(tmp_path / "u.h5", oracle, 300, seed=3)
    assert len(rows.z) == 300 and labeled == 300
    more, _, labeled = labeled_uniform_rows(tmp_path / "u.h5", oracle, 500, seed=3)
    assert labeled == 200 and np.array_equal(more.z[:300], rows.z)
    again, _, labeled = labeled_uniform_rows(tmp_path / "u.h5", oracle, 400, seed=3)
    assert labeled == 0 and np.array_equal(again.z, more.z[:400])
    with pytest.raises(Exception, match="seed 3"):
        labeled_uniform_rows(tmp_path / "u.h5", oracle, 10, seed=4)


# ----------------------------------------------------------------------------- the rounds
def test_active_grows_dc_by_exactly_the_labeled_samples(tmp_path):
    out, oracle = _train(tmp_path, "active")
    rounds = out.rounds
    assert [r["round"] for r in rounds] == [0, 1, 2]
    assert [r["dataset_size"] for r in rounds] == [200, 300, 400]
    with CollisionStore(tmp_path / "run" / "dc.h5", D, K) as store:
        rows = store.read()
    assert np.bincount(rows.round).tolist() == [200, 100, 100]
    # bootstrap is uniform; each round adds n_aug/2 projected + n_aug/2 uniform samples
    for r, (n_uniform, n_projected) in enumerate([(200, 0), (50, 50), (50, 50)]):
        origin = rows.origin[rows.round == r]
        assert ((origin == 0).sum(), (origin == 1).sum()) == (n_uniform, n_projected)
    # the uniform rows are the seed's pool, in order: bootstrap 0..199, then 200..249, 250..299
    with CollisionStore(next((tmp_path / "cache").rglob("uniform_s0.h5")), D, K) as pool:
        pz = pool.read().z
    uni = rows.z[rows.origin == 0]
    assert np.array_equal(uni, pz[:300])
    info = rounds[0]["next_round_acquisition"]
    assert info["n_projected"] == 50 and info["newton_converged_fraction"] > 0.9
    assert abs(info["projected_prob_mean"] - 0.5) < 0.02, "projected samples sit on the 0.5 level set"
    for key in ("dataset_size", "accuracy", "fnr", "fpr", "balanced_accuracy", "base_rate", "label_seconds",
                "train_seconds"):
        assert all(key in r for r in rounds)
    assert out.summary["stopped_by"] == "max_rounds"
    saved = json.loads((tmp_path / "run" / "detector_rounds.json").read_text())
    assert saved["finished"] and saved["rounds"] == json.loads(json.dumps(rounds))
    net, meta = load_detector(tmp_path / "run" / "detector.pt")
    assert meta["method"] == "active" and net.latent_dim == D
    # the final detector on the test set, next to the test rows' exact labels (the report's failure breakdown)
    with np.load(tmp_path / "run" / "test_predictions.npz") as f:
        pred = dict(f)
    assert sorted(pred) == ["collides", "logit", "pd", "pd_sub", "prob"]
    assert pred["prob"].dtype == np.float32 and pred["pd_sub"].shape == (500, K) and pred["collides"].dtype == bool
    np.testing.assert_array_equal(pred["collides"], pred["pd"] > 0)
    assert detection_metrics(pred["logit"] > 0, pred["collides"])["accuracy"] == rounds[-1]["accuracy"]
    np.testing.assert_allclose(pred["prob"], 1 / (1 + np.exp(-pred["logit"].astype(np.float64))), atol=1e-6)
    timing = out.summary["inference_us"]
    assert timing["batch_1"] > 0 and timing["batch_4096"] > 0 and timing["batch_4096"] < timing["batch_1"]
    assert saved["summary"]["inference_us"] == timing


def test_projected_samples_are_closer_to_the_true_boundary_than_uniform_ones(tmp_path):
    out, _ = _train(tmp_path, "active", max_rounds=1, epochs=60)
    with CollisionStore(tmp_path / "run" / "dc.h5", D, K) as store:
        rows = store.read()
    dist = np.abs(RADIUS - np.linalg.norm(rows.z.astype(np.float64), axis=1))
    proj, uni = dist[rows.origin == 1], dist[rows.origin == 0]
    assert np.median(proj) < 0.5 * np.median(uni)


def test_baselines_train_on_the_same_uniform_samples_at_equal_sizes(tmp_path):
    oracle = BallOracle()
    supv, _ = _train(tmp_path, "supv", run="supv", oracle=oracle)
    labeled_after_supv = oracle.labeled
    bd, _ = _train(tmp_path, "supv_bd", run="bd", oracle=oracle)
    assert oracle.labeled == labeled_after_supv, "supv_bd reuses the pool and the test set"
    assert [r["dataset_size"] for r in supv.rounds] == [r["dataset_size"] for r in bd.rounds] == [200, 300, 400]
    with CollisionStore(tmp_path / "supv" / "dc.h5", D, K) as a, CollisionStore(tmp_path / "bd" / "dc.h5", D, K) as b:
        ra, rb = a.read(), b.read()
    assert np.array_equal(ra.z, rb.z) and (ra.origin == 0).all()
    # a supervised detector on this easy problem is far better than the majority class
    last = bd.rounds[-1]
    assert last["accuracy"] > last["majority_accuracy"] + 0.1


def test_interrupted_run_resumes_after_the_last_finished_round(tmp_path, monkeypatch):
    from neuralcol.active import acquisition

    full, _ = _train(tmp_path, "active", run="full")
    calls = {"n": 0}
    real = acquisition.ProjectedAcquisition.__call__

    def dies_in_round_2(self, round_, net, store, n):
        calls["n"] += 1
        if round_ == 2:
            # rows appended after the last checkpoint must be dropped on resume
            store.append(np.zeros((7, D)), np.zeros(7), np.zeros((7, K)), np.zeros(7), np.ones(7), 2, 0)
            raise RuntimeError("simulated crash")
        return real(self, round_, net, store, n)

    monkeypatch.setattr(acquisition.ProjectedAcquisition, "__call__", dies_in_round_2)
    with pytest.raises(RuntimeError, match="simulated crash"):
        _train(tmp_path, "active", run="cut")
    partial = json.loads((tmp_path / "cut" / "detector_rounds.json").read_text())
    assert not partial["finished"] and [r["round"] for r in partial["rounds"]] == [0, 1]
    monkeypatch.setattr(acquisition.ProjectedAcquisition, "__call__", real)
    resumed, _ = _train(tmp_path, "active", run="cut")
    assert resumed.summary["resumed"] is True
    assert [r["dataset_size"] for r in resumed.rounds] == [200, 300, 400]
    keys = ("round", "dataset_size", "accuracy", "fnr", "fpr")
    assert [[r[k] for k in keys] for r in resumed.rounds[:2]] == [[r[k] for k in keys] for r in partial["rounds"]]
    # training is deterministic, so the resumed run ends where the uninterrupted one did
    assert [r["accuracy"] for r in resumed.rounds] == [r["accuracy"] for r in full.rounds]
    with CollisionStore(tmp_path / "cut" / "dc.h5", D, K) as store:
        rows = store.read()
    assert np.bincount(rows.round).tolist() == [200, 100, 100]
    # the resumed D_c holds the same rows as the uninterrupted run's
    with CollisionStore(tmp_path / "full" / "dc.h5", D, K) as store:
        np.testing.assert_array_equal(store.read().z[:300], rows.z[:300])
    # a finished run is not retrained
    again, _ = _train(tmp_path, "active", run="cut")
    assert again.summary["resumed"] == "already finished" and again.rounds == json.loads(
        json.dumps(resumed.rounds))
    # the finished detector comes from detector.pt then; within a run it is the trained net itself, the same detector
    z = torch.rand(16, D, generator=torch.Generator().manual_seed(0)) * 2 - 1
    with torch.no_grad():
        torch.testing.assert_close(again.net(z).logit, resumed.net(z).logit, rtol=0, atol=0)
