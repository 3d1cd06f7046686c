"""The diagnosis kit: projection quality, latent-space diagnostics, learning curves, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from test_active import BallOracle, D, K, _det_cfg, _train

from neuralcol.active.rounds import Schedule
from neuralcol.diagnose.curve import learning_curve, needed_size, take_rows
from neuralcol.diagnose.latent import decoder_report, label_roughness, plausibility_report, reconstruction_report
from neuralcol.metrics.projection import boundary_shares, projection_quality
from neuralcol.nn.detector import CollisionDetector
from neuralcol.samples.datamodule import detector_targets
from neuralcol.samples.store import CollisionRows

ROOT = Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------- projection quality
def test_projection_quality_by_hand():
    lo, hi = np.array([-100.0, -100.0, -10.0, -10.0]), np.array([100.0, 100.0, 10.0, 10.0])
    z0 = np.array([[0.0, 0.0, 0.0, 0.0], [50.0, 0.0, 5.0, 0.0]])
    z = np.array([[10.0, 0.0, 10.0, 0.0], [50.0, -20.0, 5.0, -10.0]])  # (0,2) and (1,3) on a face
    pd = np.array([0.5, -3.0])
    q = projection_quality(z0, z, pd, np.array([2.0, -0.5]), 1.0, lo, hi, n_level1=2)
    assert q["n"] == 2 and q["within_eps"] == 0.5 and q["within_2eps"] == 0.5 and q["colliding"] == 0.5
    assert q["start"] == {"within_eps": 0.5, "within_2eps": 1.0, "colliding": 0.5}
    assert q["on_face_level1"] == 0.0 and q["on_face_level2"] == 0.5
    # moved in half-range units: level 1: (0.1 + 0 + 0 + 0.2) / 4, level 2: (1 + 0 + 0 + 1) / 4
    assert q["moved_level1"] == pytest.approx(0.075) and q["moved_level2"] == pytest.approx(0.5)
    assert q["moved_ratio"] == pytest.approx(0.15)
    assert np.isnan(boundary_shares(np.zeros(0), 1.0)["within_eps"])
    # labels for training, clearances capped at 1.5: |PD| <= 2 is not known for a free sample, |PD| <= 1 is
    capped = boundary_shares(np.array([0.5, -1.5, -0.2]), 1.0, clearance_limit=1.5)
    assert capped["within_eps"] == pytest.approx(2 / 3) and np.isnan(capped["within_2eps"])
    with pytest.raises(ValueError):
        boundary_shares(pd, 0.0)


def test_active_rounds_record_projection_quality(tmp_path):
    """Every acquiring round of `active` records where its projected samples landed (metrics.json -> projection)."""
    out, _ = _train(tmp_path, "active", max_rounds=1)
    q = out.rounds[0]["projection"]
    assert q["n"] == 50 and 0 <= q["within_2eps"] <= 1 and "start" in q
    # the ball's projections land far closer to |z| = RADIUS than the D_c rows they started from
    assert q["within_2eps"] > q["start"]["within_2eps"]
    assert q["moved_level1"] > 0 and q["moved_level2"] > 0
    assert "projection" not in out.rounds[-1], "the last round projects nothing"


# ----------------------------------------------------------------------------- targets and schedules
def test_pd_targets_are_clipped_to_the_band():
    rows = CollisionRows(np.zeros((4, 2), np.float32), np.array([-0.02, -0.001, 0.001, 0.05]),
                         np.array([[-0.02], [-0.001], [0.001], [0.05]]), np.array([0, 0, 1, 1]),
                         np.array([1, 1, 2, 0]), np.zeros(4), np.zeros(4), np.arange(4))
    _, pd, pd_sub, _ = detector_targets(rows, 0.01, 0.25, pd_floor=-0.25)
    torch.testing.assert_close(pd, torch.tensor([-0.25, -0.1, 0.1, 0.25]))
    torch.testing.assert_close(pd_sub[:, 0], pd)
    _, wide, _, _ = detector_targets(rows, 0.01, 3.0)  # the old targets: clipped above at 3 only
    torch.testing.assert_close(wide, torch.tensor([-2.0, -0.1, 0.1, 3.0]))
    with pytest.raises(ValueError, match="pd_floor"):
        detector_targets(rows, 0.01, 0.25, pd_floor=0.1)


def test_schedule_step_floor():
    paper = Schedule(epochs=50, lr=1e-4, batch_size=1024)
    assert paper.epochs_for(3000) == 50, "min_steps = 0: epochs only, as in the paper"
    floor = Schedule(epochs=50, lr=1e-4, batch_size=1024, min_steps=2000)
    assert floor.epochs_for(3000) == 667  # 3 batches per epoch
    assert floor.epochs_for(400_000) == 50  # 391 batches: 50 epochs already exceed 2000 steps
    with pytest.raises(ValueError):
        Schedule(epochs=1, lr=1e-3, batch_size=8, min_steps=-1)


def test_rounds_run_the_step_floor(tmp_path):
    """A fine-tuning round with min_steps runs enough epochs to make that many optimizer steps."""
    from test_active import _det_cfg, _method

    from neuralcol.stages.detector import train_detector

    oracle = BallOracle()
    det = _det_cfg(max_rounds=1)
    method = _method("active", det)
    method["update"] = {**method["update"], "min_steps": 100}
    out = train_detector(oracle.space, oracle, det, method, "ball", seed=0, cache_dir=tmp_path / "cache",
                         run_dir=tmp_path / "run")
    # round 1: 300 rows, 240 training rows, batch 64 -> 4 batches per epoch -> 25 epochs (> finetune_epochs 10)
    assert [r["epochs"] for r in out.rounds] == [40, 25]


# ----------------------------------------------------------------------------- latent diagnostics
def test_label_roughness_of_a_half_space_matches_its_closed_form():
    """label = [x_0 > 0] on the box [-1, 1]^4: a shift of +-s flips it iff x_0 lies within s of 0 on the side the
    shift leaves, so the flip rate is s / 2."""
    gen = torch.Generator().manual_seed(0)
    z = torch.rand(40_000, 4, generator=gen) * 2 - 1
    out = label_roughness(lambda c: (c[:, 0] > 0).numpy(), z, -torch.ones(4), torch.ones(4), [0.02, 0.1, 0.4])
    np.testing.assert_allclose(out["flip_rate"], [0.01, 0.05, 0.2], rtol=0, atol=0.006)
    assert out["base_rate"] == pytest.approx(0.5, abs=0.01) and out["n"] == 40_000


def test_latent_reports_on_a_trained_space(tube_space, tube_dataset):
    space, report, *_ = tube_space
    rec = reconstruction_report(space, tube_dataset.vertices, report["train_index"])
    assert rec["train_mean"] == pytest.approx(report["train_mean_vertex_error"], rel=1e-4)
    assert rec["heldout_mean"] == pytest.approx(report["val_mean_vertex_error"], rel=1e-4)
    assert sum(rec["train"]) == len(report["train_index"])
    z = space.sample(16, torch.Generator().manual_seed(0))
    dec = decoder_report(space, z, n_points=41)
    assert 0 <= dec["saturation"] <= 1 and dec["even_share"] == pytest.approx(2 / 40)
    assert all(dec["even_share"] - 1e-9 <= s <= 1 for s in dec["busiest_share"])
    pl = plausibility_report(space, space.encode(tube_dataset.vertices), tube_dataset.vertices,
                             tube_dataset.faces.numpy())
    assert pl["edge_within"] > 0.9, "the data set's own codes decode within its edge-stretch range"


# ----------------------------------------------------------------------------- learning curves
def _ball_rows(n, seed):
    oracle = BallOracle()
    z = torch.rand(n, D, generator=torch.Generator().manual_seed(seed)) * 2 - 1
    lab = oracle(z)
    return CollisionRows(lab.z, lab.pd, lab.pd_sub, lab.collides, lab.subset, np.zeros(n), np.zeros(n),
                         np.arange(n))


# the ball's detector config and builder, shared by the learning-curve tests
BALL_DET = {"net": {"state_dim": 16, "hidden": 32}, "targets": {"pd_clip": 0.25, "pd_floor": -0.25},
            "loss": {"w_pd": 5.0, "w_pdsum": 0.2, "w_r": 2.0, "w_ce": 2.0, "margin": 0.01, "temperature": 0.1},
            "epochs": 30, "lr": 1e-2, "batch_size": 64}
# the training components (optimizer, round callback, Trainer) as conf/detector builds them
BALL_DET.update({k: v for k, v in _det_cfg().items() if k in ("optimizer", "rounds", "trainer")})


def _build_ball_detector(net: dict) -> CollisionDetector:
    return CollisionDetector(K, 1, int(net["state_dim"]), int(net["hidden"]), -torch.ones(D), torch.ones(D))


def test_learning_curve_on_the_ball():
    rows, test = _ball_rows(400, 0), _ball_rows(1000, 1)
    recs = learning_curve(rows, test, [100, 400], [{"name": "det"}, {"name": "wide", "width_factor": 2}],
                          _build_ball_detector, 0.5, BALL_DET, [0], -np.ones(D), np.ones(D), log=lambda *_: None)
    assert [(r["size"], r["model"]) for r in recs] == [(100, "hgb"), (100, "knn"), (100, "det"), (100, "wide"),
                                                       (400, "hgb"), (400, "knn"), (400, "det"), (400, "wide")]
    wide = [r for r in recs if r["model"] == "wide"][0]
    narrow = [r for r in recs if r["model"] == "det"][0]
    assert wide["n_parameters"] > 2 * narrow["n_parameters"]
    final = [r for r in recs if r["size"] == 400 and r["model"] == "det"][0]
    assert final["test"]["accuracy"] > final["test"]["majority_accuracy"] + 0.1, "the ball is learnable"
    assert 0 <= final["epoch"] < 30 and 0.5 < final["train_accuracy"] <= 1
    assert len(take_rows(rows, 7).z) == 7


def test_needed_size_extrapolates_a_log_linear_curve():
    sizes = [1000, 2000, 4000, 8000]
    acc = [0.70 + 0.02 * i for i in range(4)]  # +2 points per doubling
    assert needed_size(sizes, acc, 0.80) == pytest.approx(1000 * 2 ** 5)
    assert needed_size(sizes, acc, 0.72) == 2000, "a measured size that reaches the target"
    assert np.isnan(needed_size(sizes[:2], acc[:2], 0.80)), "two points are no trend"
    assert needed_size(sizes, [0.7, 0.7, 0.69, 0.7], 0.8) == float("inf")
    assert needed_size(sizes, acc, 0.99) == float("inf"), "beyond 1000x the largest size"


# ----------------------------------------------------------------------------- the command
def test_diagnose_command_on_scape(tmp_path, scape_dir, capsys):
    """experiments.diagnose with tiny sizes: all three parts, JSON and charts, copies to diagnose.out."""
    from hydra import compose, initialize_config_dir

    from experiments.diagnose import run

    fake = tmp_path / "fake_run"
    fake.mkdir()
    q = {"n": 10, "within_eps": 0.3, "within_2eps": 0.6, "colliding": 0.5, "on_face_level1": 0.0,
         "on_face_level2": 0.1, "moved_level1": 0.2, "moved_level2": 0.3, "moved_ratio": 0.67,
         "start": {"within_eps": 0.1, "within_2eps": 0.2, "colliding": 0.5}}
    (fake / "metrics.json").write_text(json.dumps({"rounds": [{"round": 0, "dataset_size": 120, "projection": q},
                                                              {"round": 1, "dataset_size": 180}]}))
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose("diagnose", overrides=[
            "dataset=scape", f"paths.data_dir={scape_dir.parent}", f"paths.cache_dir={tmp_path}/cache",
            "autoencoder=tiny", "detector=tiny", "labeling.pool.workers=0", "labeling.pool.progress=false",
            "diagnose.parts=[latent,curve,projection]", "diagnose.curve.sizes=[60,90,120]",
            "diagnose.latent.n_samples=20", "diagnose.latent.roughness_samples=10",
            "diagnose.curve.variants=[{name: detector}]", f"diagnose.runs=[{fake}]",
            f"diagnose.out={tmp_path}/docs"])
    res = run(cfg, tmp_path)
    assert set(res) >= {"latent", "curve", "projection"}
    assert len(res["latent"]["reconstruction"]["errors"]) == 71
    assert {r["model"] for r in res["curve"]["records"]} == {"hgb", "knn", "detector"}
    assert res["projection"][str(fake)][0]["within_2eps"] == 0.6
    for name in ("diagnosis.json", "latent.png", "curve.png", "projection.png"):
        assert (tmp_path / "docs" / name).stat().st_size > 1000, name
    assert "rows needed for accuracy" in capsys.readouterr().out


def test_diagnose_refuses_a_run_without_projections(tmp_path):
    from hydra import compose, initialize_config_dir

    from experiments.diagnose import run
    from neuralcol.errors import UserInputError

    (tmp_path / "metrics.json").write_text(json.dumps({"rounds": [{"round": 0, "dataset_size": 10}]}))
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose("diagnose", overrides=["diagnose.parts=[projection]", f"diagnose.runs=[{tmp_path}]"])
    with pytest.raises(UserInputError, match="no projected samples"):
        run(cfg, tmp_path)
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose("diagnose", overrides=["diagnose.parts=[nothing]"])
    with pytest.raises(UserInputError, match="diagnose.parts"):
        run(cfg, tmp_path)


def test_uncertain_start_selects_the_codes_nearest_the_level_set(tmp_path):
    """start="uncertain", project=False: the projected half are the candidates with the smallest |logit| of
    `candidates` x as many fresh U(Z) codes, labeled where they were drawn; with project=True they then land
    on the level set. The candidates are a function of (seed, round)."""
    from types import SimpleNamespace

    from neuralcol.active.acquisition import ProjectedAcquisition
    from neuralcol.samples.store import CollisionStore

    class BallLogit(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.scale = torch.nn.Parameter(torch.ones(()))

        def forward(self, z):
            return SimpleNamespace(logit=self.scale * (1.2 - z.norm(dim=-1)))

    def acquire(name, project, round_=1):
        acq = ProjectedAcquisition(tmp_path / f"{name}.h5", BallOracle(), seed=0, box_lo=-torch.ones(D),
                                   box_hi=torch.ones(D), projected_fraction=0.5,
                                   newton={"eps_z": 1e-9, "max_iter": 30}, start="uncertain", candidates=20,
                                   project=project)
        return acq(round_, BallLogit(), store, 100)

    store = CollisionStore(tmp_path / "dc.h5", D, K)
    drawn, projected = acquire("a", False), acquire("b", True)
    for new in (drawn, projected):
        assert (new.origin == 1).sum() == 50 and new.info["projection"]["n"] == 50
        assert "uniform" in new.info["projection"]
    dist = (torch.as_tensor(drawn.z[drawn.origin == 1]).double().norm(dim=-1) - 1.2).abs()
    assert dist.max() < 0.1, "the 50 most uncertain of 1000 candidates lie near |z| = 1.2"
    dist = (torch.as_tensor(projected.z[projected.origin == 1]).double().norm(dim=-1) - 1.2).abs()
    assert dist.max() < 1e-5, "projected onto the level set"
    np.testing.assert_array_equal(acquire("c", False).z[:50], drawn.z[:50])
    assert not np.array_equal(acquire("d", False, round_=2).z[:50], drawn.z[:50])
    store.close()


def test_ablation_bench_configs_compose():
    """Every variant of `python -m research.diagnosis_ablations` composes against conf/ (keys exist, no `+` needed)."""
    from research.diagnosis_ablations import LATENT_VARIANTS, study_config

    for name, overrides in LATENT_VARIANTS.items():
        cfg = study_config("proc_hand", list(overrides))
        assert "diagnose" in cfg and cfg.autoencoder.level1.activation in ("tanh", "linear"), name
    assert study_config("proc_hand", ["autoencoder.level1.code_noise=0.3"]).autoencoder.level1.code_noise == 0.3


def _write_curve(folder: Path, records: list[dict]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "diagnosis.json").write_text(json.dumps({"curve": {"records": records}}))


def test_compare_curves_pairs_variants_by_size_and_seed(tmp_path, capsys):
    from experiments.compare_curves import main

    def rec(model, size, seed, acc, fnr):
        return {"model": model, "size": size, "seed": seed, "epochs_run": 100, "test": {"accuracy": acc, "fnr": fnr}}

    _write_curve(tmp_path / "a", [rec("constant", 4000, 0, 0.80, 0.40), rec("constant", 4000, 1, 0.82, 0.30),
                                  rec("constant", 8000, 0, 0.85, 0.20), rec("other", 4000, 0, 0.0, 1.0)])
    _write_curve(tmp_path / "b", [rec("long", 4000, 0, 0.81, 0.35), rec("long", 4000, 1, 0.84, 0.30)])
    out = tmp_path / "cmp.json"
    assert main([f"{tmp_path / 'a'}:constant", f"{tmp_path / 'b'}:long", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert [(p["size"], p["seed"]) for p in res["pairs"]] == [(4000, 0), (4000, 1)]  # 8000 has no partner
    assert res["mean_d_accuracy"] == pytest.approx(0.015) and res["mean_d_fnr"] == pytest.approx(-0.025)
    assert "+1.50 points" in capsys.readouterr().out
    # a misspelt variant names the file and the variants it has
    with pytest.raises(SystemExit) as exc:
        main([f"{tmp_path / 'a'}:constnt", f"{tmp_path / 'b'}:long"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "no variant 'constnt'" in err and "'constant'" in err and "diagnosis.json" in err
