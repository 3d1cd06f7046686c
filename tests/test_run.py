"""Config smoke tests: every data set config composes; the main entry point runs and reports errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
CONF = str(ROOT / "conf")
DATASETS = sorted(p.stem for p in (ROOT / "conf" / "dataset").glob("*.yaml"))


def _compose(overrides):
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return compose(config_name="config", overrides=overrides, return_hydra_config=False)


@pytest.mark.parametrize("name", DATASETS)
def test_dataset_configs_compose(name):
    cfg = _compose([f"dataset={name}"])
    # variants of a data set (other sizes of the same meshes) keep its name, so they share its outputs and caches
    assert cfg.dataset.name == {"scape_k8l3": "scape"}.get(name, name)
    assert cfg.dataset.source._target_.startswith("neuralcol.data.datasets.")


def test_scape_k8l3_is_scape_with_the_sizes_of_before():
    new, old = _compose(["dataset=scape"]).dataset, _compose(["dataset=scape_k8l3"]).dataset
    assert (new.latent.n_components, new.latent.level2_dim) == (16, 0)
    assert (old.latent.n_components, old.latent.level2_dim) == (8, 3)
    assert (old.detector_net.state_dim, old.detector_net.hidden, old.cpu.n_init, old.cpu.n_aug) == (64, 128, 2000, 2000)
    assert old.source == new.source and old.cpu.test_size == new.cpu.test_size


@pytest.mark.parametrize("overrides, kind", [
    (["dataset=scape"], "pca"), (["experiment=cpu_scape"], "pca"), (["dataset=proc_cloth"], "pca"),
    (["experiment=cpu_proc_cloth"], "pca"), ([], "pca"), (["dataset=scape", "autoencoder=cpu"], "bilevel"),
    (["experiment=paper_scape"], "bilevel"), (["experiment=paper_proc_cloth"], "bilevel"),
    (["dataset=scape_k8l3"], "bilevel"), (["experiment=size_scape"], "bilevel"), (["dataset=anny_body"], "pca"),
    (["experiment=cpu_anny_body"], "pca"), (["experiment=paper_anny_body"], "bilevel"),
    (["dataset=anny_body", "autoencoder=cpu"], "bilevel")])
def test_latent_space_of_each_preset(overrides, kind):
    """SCAPE, proc_hand, proc_cloth and anny_body take a PCA latent space with a fitted box (rule v2,
    docs/studies/latent_space.md); the paper presets, the bilevel SCAPE layout and the size search keep the
    autoencoder; the command line wins."""
    cfg = _compose(overrides)
    assert cfg.autoencoder.kind == kind
    assert cfg.box_fit.enabled and list(cfg.box_fit.band) == [0.10, 0.55]
    assert not _compose([*overrides, "detector=tiny"]).box_fit.enabled


def test_scape_cpu_preset_labels_26000_samples_with_the_detector_over_code_and_mesh():
    # rule v3 (docs/studies/one_detector.md): the detector over code and mesh at 8 000 + 3 x 6 000 labels is past
    # the latent detector's 38 000 and fits the 30 minutes
    cfg = _compose(["experiment=cpu_scape"])
    cpu = cfg.dataset.cpu
    assert cpu.n_init + cpu.max_rounds * cpu.n_aug == 26000
    assert (cpu.n_init, cpu.n_aug, cpu.max_rounds, cpu.test_size) == (8000, 6000, 3, 20000)
    assert (cfg.detector.inputs, cfg.detector.operating_fnr, cfg.detector.operating_set) == ("code_and_mesh", 0.1,
                                                                                             "auto")
    tiny = _compose(["experiment=cpu_scape", "detector=tiny"]).detector  # tests: the paper's detector
    assert (tiny.inputs, tiny.operating_fnr) == ("latent", None)


def test_anny_body_picks_the_large_mesh_presets_and_the_command_line_still_wins():
    """A data set's defaults may pick the evaluation stages' presets (conf/config.yaml lists dataset after
    them); anny_body takes the *large_mesh ones and its own calibration size, other data sets keep the defaults."""
    body, scape = _compose(["dataset=anny_body"]), _compose(["dataset=scape"])
    body_train, scape_train = body.detector.geometry.train_set, scape.detector.geometry.train_set
    assert (body.realistic.n_acap_interp, body_train.n_acap_interp, body.speed_accuracy.n_exact,
            body.detector.cascade.calibration_size) == (1360, 340, 100, 500)
    assert (scape.realistic.n_acap_interp, scape_train.n_acap_interp, scape.speed_accuracy.n_exact,
            scape.detector.cascade.calibration_size) == (12000, 1500, 300, 2000)
    assert body.realistic.t_range == scape.realistic.t_range  # the rest of default.yaml is kept
    tiny = _compose(["dataset=anny_body", "realistic=tiny", "realistic.per_class=3"])
    assert (tiny.realistic.n_acap_interp, tiny.realistic.per_class) == (48, 3)
    assert _compose(["experiment=cpu_anny_body"]) == body


TRAIN_SET = ("seed", "n_acap_interp", "n_vertex_interp", "n_perturbed", "t_range", "perturb_scale", "clear_eps",
             "per_class")


@pytest.mark.parametrize("overrides, sizes", [
    ([], (1500, 600, 600, 600)), (["experiment=cpu_scape"], (1500, 600, 600, 600)),
    (["experiment=cpu_proc_cloth"], (1500, 600, 600, 600)), (["experiment=paper_scape"], (1500, 600, 600, 600)),
    (["experiment=cpu_anny_body"], (340, 130, 130, 150)), (["experiment=paper_anny_body"], (340, 130, 130, 150)),
    (["detector=tiny"], (48, 16, 16, 16)), (["dataset=anny_body", "detector=tiny"], (48, 16, 16, 16))])
def test_realistic_training_meshes_of_the_one_detector(overrides, sizes):
    """The realistic training meshes moved from mesh_detector.train_set to detector.geometry.train_set with
    the values of before (anny_body: large_mesh's sizes through dataset.cpu.geometry_train_set; detector=tiny: the
    old mesh_detector=tiny's), so their cache key (a hash of these values) is unchanged."""
    ts = OmegaConf.to_container(_compose(overrides).detector.geometry.train_set, resolve=True)
    assert sorted(ts) == sorted(TRAIN_SET)
    assert (ts["n_acap_interp"], ts["n_vertex_interp"], ts["n_perturbed"], ts["per_class"]) == sizes
    assert (ts["seed"], ts["t_range"], ts["perturb_scale"], ts["clear_eps"]) == (1, [-0.6, 1.6], 0.8, 0)
    assert all(type(ts[k]) is int for k in ("n_acap_interp", "n_vertex_interp", "n_perturbed", "per_class"))
    assert "mesh_detector" not in _compose(overrides)


def test_make_run_preset_labels_12000_samples():
    """`make run` sized to its 10-minute budget, 4 rounds of 2 000 after 4 000."""
    cpu = _compose([]).dataset.cpu
    assert (cpu.n_init, cpu.n_aug, cpu.max_rounds, cpu.n_init + cpu.max_rounds * cpu.n_aug) == (4000, 2000, 4, 12000)


def test_paper_scale_scape_presets_have_the_papers_sizes():
    """experiment=paper_scape is the paper's configuration (bilevel autoencoder, 3000 epochs a level, the
    latent-only detector at p > 0.5, Algorithm 1), experiment=paper_scape_neuralcol neuralcol's defaults, both at
    N_init 2e5, N_aug 5e4, 7 rounds (5.5e5 labels), 100 / 50 epochs, 1e4 handler inputs, a U(Z) test set of 1e5."""
    paper, ours = _compose(["experiment=paper_scape"]), _compose(["experiment=paper_scape_neuralcol"])
    for cfg in (paper, ours):
        d = cfg.detector
        assert (d.n_init, d.n_aug, d.max_rounds, d.n_init + d.max_rounds * d.n_aug) == (200000, 50000, 7, 550000)
        assert (d.epochs, d.finetune_epochs, d.test_size, cfg.handler.n_inputs) == (100, 50, 100000, 10000)
        assert cfg.max_minutes is None and d.targets.training_labels == "limited"
    assert (paper.autoencoder.kind, paper.autoencoder.level1.epochs, paper.autoencoder.level2.epochs) == (
        "bilevel", 3000, 3000)
    assert (paper.detector.inputs, paper.detector.operating_fnr, paper.method.name) == ("latent", None, "active_paper")
    assert (ours.autoencoder.kind, ours.detector.inputs, ours.detector.operating_fnr, ours.method.name) == (
        "pca", "code_and_mesh", 0.1, "active")
    assert _compose(["experiment=paper_scape", "method=supv", "detector.test_size=750000"]).detector.test_size == 750000


def test_paper_datasets_present():
    assert {"scape", "swing", "jump", "skirt", "hand", "proc_hand", "proc_cloth"} <= set(DATASETS)


def test_run_on_scape(tmp_path, scape_dir, capsys):
    from experiments.run import run

    cfg = _compose(["dataset=scape", f"paths.data_dir={scape_dir.parent}", f"paths.cache_dir={tmp_path}/cache",
                    "n_example_meshes=2", "autoencoder=tiny", "detector=tiny", "realistic=tiny", "speed_accuracy=tiny",
                    "labeling.pool.workers=0",
                    "labeling.pool.progress=false"])
    metrics = run(cfg, tmp_path / "run")
    saved = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert saved == json.loads(json.dumps(metrics))
    assert saved["dataset"]["n_meshes"] == 71 and saved["dataset"]["n_vertices"] == 2161
    assert saved["acap"]["worst_mesh_mean_rel_error"] <= 2e-3
    assert sorted(p.name for p in (tmp_path / "run" / "examples" / "input").iterdir()) == ["1.obj", "2.obj"]
    assert saved["dataset_labels"]["colliding"] == ["8", "71"]
    assert saved["latent"]["dim"] == 16  # SCAPE: 16 sub-domains, no level 2 (conf/dataset/scape.yaml)
    assert [r["dataset_size"] for r in saved["rounds"]] == [120, 180, 240]  # detector=tiny: N_init 120, N_aug 60
    assert saved["detector"]["method"] == "active" and saved["detector"]["test_set"]["n"] == 200
    assert (tmp_path / "run" / "detector.pt").is_file() and (tmp_path / "run" / "dc.h5").is_file()
    assert sum(saved["autoencoder"]["partition_sizes"]) == 2161
    # PCA at the same |Z_all| beside the autoencoder, the box probe, the round trips of both
    refs = saved["autoencoder"]["references"]
    assert set(refs) == {"vertex_pca", "acap_pca"}
    assert 0 < refs["vertex_pca"]["train_mean_vertex_error"] < refs["vertex_pca"]["val_mean_vertex_error"] < 0.05
    probe = saved["latent"]["box_probe"]
    assert probe["space"]["n"] == 32 and set(probe["references"]) == {"vertex_pca", "acap_pca"}  # detector=tiny
    assert 0 <= probe["space"]["collision_share"] <= 1
    assert set(saved["realistic"]["round_trip"]["references"]) == {"vertex_pca", "acap_pca"}
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(tmp_path / "run" / "tensorboard" / "latent")).Reload()
    assert {"latent/vertex_pca_val_error", "latent/acap_pca_box_collision_share",
            "latent/vertex_pca_round_trip_agreement"} <= set(acc.Tags()["scalars"])
    assert acc.Scalars("latent/vertex_pca_val_error")[0].value == pytest.approx(
        refs["vertex_pca"]["val_mean_vertex_error"], rel=1e-6)
    assert (tmp_path / "run" / "subdomains.png").stat().st_size > 10_000
    assert any((tmp_path / "run" / "tensorboard").iterdir()), "TensorBoard event files"
    h = saved["handling"]
    for key in ("success_rate", "resolved_rate", "mean_pd_reduction", "mean_embedding_diff", "seconds_per_mesh"):
        assert key in h and key in h["verified"]
    assert h["n"] > 0 and h["verified"]["resolved_rate"] >= h["resolved_rate"]
    assert (tmp_path / "run" / "handling" / "reduction_vs_difference.png").is_file()
    import numpy as np

    from neuralcol.metrics.detection import detection_metrics

    # the realistic set: every run evaluates on meshes nobody trained on, labeled exactly
    r = saved["realistic"]
    kinds = r["kinds"]  # realistic=tiny: the 14 held-out meshes, then at most 6 clear colliding and as many free
    assert kinds["heldout"] == 14 and sum(kinds.values()) == r["n"] <= 14 + 12
    assert r["n_labeled"] <= r["n"] and 0 <= r["round_trip"]["agreement"] <= 1
    with np.load(tmp_path / "run" / "realistic_predictions.npz") as f:
        clear, pd, logit, kind = f["clear"], f["pd"], f["logit"], f["kind"]
        assert clear.sum() == r["n_clear"] and clear[kind != 0].all()  # every selected candidate is clear
        assert (pd[kind != 0] > 0).sum() == (pd[kind != 0] < 0).sum()  # balanced
        if r["detection"]["n"]:
            assert detection_metrics(logit[clear] > 0, pd[clear] > 0)["accuracy"] == r["detection"]["accuracy"]
        if "handled" in f:
            assert (pd[f["handled"]] > 0).all() and len(f["handled"]) == r["handling"]["n"] <= 4
            by_kind = r["handling"]["verified_by_kind"]  # every handled input has one kind
            assert sum(k["n"] for k in by_kind.values()) == r["handling"]["n"]
            freed = int((np.nan_to_num(f["handled_pd_after"], nan=1.0) <= 0).sum())
            assert sum(k["freed"] for k in by_kind.values()) == freed
            renders = r["handling"]["renders"]  # one before/after picture per kind present
            assert set(renders) == {k for k, v in by_kind.items() if v["n"]}
            assert all((tmp_path / "run" / "realistic_renders" / name).is_file() for name in renders.values())
    # one detector: no separate mesh detector beside it, in the metrics or the run directory
    assert "mesh_detector" not in saved and "detection_mesh" not in r
    assert not (tmp_path / "run" / "mesh_detector.pt").exists()
    cached = list((tmp_path / "cache" / "collision").glob("*/realistic_[0-9a-f]*.npz"))
    assert len(cached) == 1, cached  # the evaluation set, cached beside the U(Z) test set
    with np.load(cached[0]) as c:
        assert len(c["pd"]) == r["n"]
    # the per-run data of the report's cost and failure charts

    with np.load(tmp_path / "run" / "test_predictions.npz") as f:
        assert f["prob"].shape == (200,) and f["pd_sub"].shape == (200, 16) and f["collides"].dtype == bool
        assert detection_metrics(f["logit"] > 0, f["collides"])["accuracy"] == saved["rounds"][-1]["accuracy"]
    assert 0 < saved["detector"]["inference_us"]["batch_4096"] < saved["detector"]["inference_us"]["batch_1"]
    with np.load(tmp_path / "run" / "handling" / "per_input.npz") as f:
        assert f["pd_before"].shape == (h["n"],) and f["pd_sub_before"].shape == (h["n"], 16)
        assert (f["pd_before"] > 0).all() and f["success"].mean() == h["success_rate"]
    # the users' command on the finished run: a mesh in, the resolved mesh out, exact PD printed
    (tmp_path / "run" / ".hydra").mkdir()
    OmegaConf.save(cfg, tmp_path / "run" / ".hydra" / "config.yaml")
    from experiments.handle import main as handle_main

    handle_main([str(tmp_path / "run"), str(tmp_path / "run" / "examples" / "input" / "1.obj"),
                 "--out", str(tmp_path / "handled")])
    out = capsys.readouterr().out
    assert "PD result" in out and out.strip().splitlines()[-1].startswith("1 ")
    assert (tmp_path / "handled" / "1_resolved.obj").is_file()
    again = run(OmegaConf.merge(cfg, {"realistic": {"enabled": False}, "handler": {"n_inputs": 0}}),
                tmp_path / "run2")
    assert again["autoencoder"]["from_cache"], "the second run reuses the trained autoencoder"


@pytest.mark.slow
def test_scape_autoencoder_cpu_preset(tmp_path, scape_dir):
    """Slow (~5 min): the CPU preset of the bilevel autoencoder (|Z_0| = 8, level-2 codes
    of 3: ``dataset=scape_k8l3``) reaches <= 1% mean vertex error on the training meshes. SCAPE's default
    (16 components, no level 2) trades training error (1.5 %) for held-out error (4.9 % against 7.8 %)
    and trains about 3x longer: docs/studies/autoencoder_cpu_preset.md."""
    from experiments.run import run

    cfg = _compose(["dataset=scape_k8l3", f"paths.data_dir={scape_dir.parent}", f"paths.cache_dir={tmp_path}/cache",
                    "detector=tiny", "realistic=tiny", "autoencoder.progress_bar=false"])
    m = run(cfg, tmp_path / "run")
    assert m["autoencoder"]["train_mean_vertex_error"] <= 0.01
    assert all(p == 1 for p in m["autoencoder"]["pieces"])


def test_missing_dataset_is_one_line_error(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.run", "dataset=swing", f"paths.data_dir={tmp_path}",
         f"paths.output_dir={tmp_path}/out"],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
        env={k: v for k, v in __import__("os").environ.items() if k not in ("HYDRA_FULL_ERROR", "NEURALCOL_DEBUG")},
    )
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "swing: data set not found" in lines[0], lines


def test_degenerate_box_stops_the_run_with_one_line(tmp_path, scape_dir):
    """A box whose probe is (nearly) one class ends the run before the test set, with one line naming the setting.
    No box is 60 % minority, so min_class_share 0.6 makes any box "degenerate"; the PCA space fits in milliseconds,
    so this also runs ``autoencoder=pca`` through the command line."""
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.run", "dataset=scape", "autoencoder=pca", "detector=tiny",
         "box_check.min_class_share=0.6", f"paths.data_dir={scape_dir.parent}", f"paths.cache_dir={tmp_path}/cache",
         f"hydra.run.dir={tmp_path}/run", "labeling.pool.workers=0", "labeling.pool.progress=false"],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
        env={k: v for k, v in __import__("os").environ.items() if k not in ("HYDRA_FULL_ERROR", "NEURALCOL_DEBUG")},
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: dataset=scape: "), lines
    assert "box_check.min_class_share=0.6" in lines[0] and "vertex_pca" in lines[0]
    assert not (tmp_path / "run" / "metrics.json").exists()


def test_tiny_multirun_then_report(tmp_path, scape_dir):
    """A real Hydra multirun (tiny preset, two methods x two seeds, two jobs at a time with the joblib launcher,
    handler evaluated every round), then the
    report: the Table 3 layout (Markdown + CSV) and all charts."""
    sweep = tmp_path / "sweep"
    env = {k: v for k, v in __import__("os").environ.items() if k not in ("HYDRA_FULL_ERROR",)}
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.run", "-m", "dataset=scape", "autoencoder=tiny", "detector=tiny",
         "realistic=tiny", "speed_accuracy=tiny",
         "method=supv_bd,active", "seed=0,1", "hydra/launcher=parallel", "handler.n_inputs=4",
         "handler.eval_every_round=true", "handler.verify_margins=[4.0]", "n_example_meshes=0",
         "labeling.pool.workers=0", "labeling.pool.progress=false", f"paths.data_dir={scape_dir.parent}",
         f"paths.cache_dir={tmp_path}/cache",
         f"hydra.sweep.dir={sweep}"],
        cwd=ROOT, capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = sorted(p.parent for p in sweep.rglob("metrics.json"))
    assert len(runs) == 4
    metrics = [json.loads((r / "metrics.json").read_text()) for r in runs]
    # the sweep shares one autoencoder and one test set: trained / labeled by the first job only
    assert sum(not m["autoencoder"]["from_cache"] for m in metrics) == 1
    assert len(list((tmp_path / "cache" / "collision").glob("*/test_s*.h5"))) == 1
    assert all(r.get("handling") for m in metrics for r in m["rounds"]), "handling after every round"
    (sweep / "model_size.json").write_text(json.dumps({"chosen": {"method": "active", "state_dim": 16, "hidden": 32}}))
    proc = subprocess.run([sys.executable, "-m", "experiments.report", str(sweep)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    text = (sweep / "report.md").read_text()
    assert "Table 3 layout" in text and "equivalent supv_bd size" in text and "detector parameters" in text
    # the "real meshes" block: every run of the sweep evaluated the realistic set
    assert "real meshes: accuracy, detector" in text and "real meshes: resolve, collision-free" in text
    rows = list(__import__("csv").DictReader(open(sweep / "table3.csv")))
    assert [r["method"] for r in rows] == ["supv_bd", "active"] and rows[0]["n_seeds"] == "2"
    for chart in ("accuracy.png", "fnr.png", "handling.png", "speed.png", "stability.png", "projection.png",
                  "pareto.png", "cost.png", "failures.png"):
        assert (sweep / chart).stat().st_size > 10_000, chart
    assert "where the acquired samples landed (mean over 2 active runs)" in text
    assert "left out" not in proc.stderr, "every run wrote the files of the cost and failure charts"
    # Pareto table: one configuration (the tiny sizes), both methods over two seeds, the chosen one marked
    pareto = [line for line in text.splitlines() if line.startswith("| K16 L0 16/32 |")]
    assert [line.split("|")[2:4] for line in pareto] == [[" supv_bd ", " 2 "], [" active ", " 2 "]]
    assert "**chosen**" in pareto[1] and "**chosen**" not in pareto[0]
    # failures: five PD bins per method; the bins add up to each method's final accuracy and handler success
    import numpy as np

    from neuralcol.metrics.breakdown import PD_BIN_NAMES

    fails = text.split("where each method fails")[1].split("recall by the deepest")[0]
    for method in ("supv_bd", "active"):
        assert [line.split("|")[2].strip() for line in fails.splitlines() if line.startswith(f"| {method} |")] == \
            list(PD_BIN_NAMES)
    report = json.loads((sweep / "report.json").read_text())
    for method in ("supv_bd", "active"):
        f = report["failures"][f"scape/{method}"]
        final = [m for m in metrics if m["detector"]["method"] == method]
        count, rate = np.array(f["accuracy"]["count"]), np.array(f["accuracy"]["mean"])
        assert count.sum() == 200 and len(f["recall"]["count"]) == 16  # SCAPE: 16 sub-domains
        np.testing.assert_allclose((np.nan_to_num(rate) * count).sum() / 200,
                                   np.mean([m["rounds"][-1]["accuracy"] for m in final]), atol=1e-9)
        count, rate = np.array(f["handler"]["count"]), np.array(f["handler"]["mean"])
        assert count.sum() == 4 and count[:2].sum() == 0, "handler inputs all self-penetrate"
        np.testing.assert_allclose((np.nan_to_num(rate) * count).sum() / 4,
                                   np.mean([m["handling"]["success_rate"] for m in final]), atol=1e-9)
