"""The model-size search: the choice rule on hand-made records, and a tiny search end to end with its preset."""

import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from neuralcol.errors import UserInputError
from neuralcol.stages.model_size import (
    choose_detector,
    choose_from_records,
    choose_latent,
    error_envelope,
    knee_latent,
    validate_model_size,
)

CONF = str(Path(__file__).resolve().parents[1] / "conf")


def test_choose_latent_smallest_within_relative_tolerance():
    recs = [{"n_components": 16, "level2_dim": 3, "val_error": 0.010},   # best, dim 64
            {"n_components": 8, "level2_dim": 3, "val_error": 0.0109},   # dim 32, within 10 %
            {"n_components": 8, "level2_dim": 1, "val_error": 0.0115},   # dim 16, 15 % worse: out
            {"n_components": 4, "level2_dim": 6, "val_error": 0.0105}]   # dim 28, within: the smallest eligible
    assert choose_latent(recs, 0.1)["n_components"] == 4
    assert choose_latent(recs, 0.0)["n_components"] == 16      # no tolerance: the best
    assert choose_latent(recs, 0.2)["level2_dim"] == 1         # 8 x (1 + 1) = 16 entries now eligible
    with pytest.raises(ValueError, match="held-out"):
        choose_latent([{"n_components": 2, "level2_dim": 0, "val_error": None}], 0.1)


def _lat(k, l2, err):
    return {"n_components": k, "level2_dim": l2, "val_error": err}


def test_error_envelope_is_the_best_error_with_at_most_d_entries():
    recs = [_lat(2, 0, 0.030), _lat(4, 0, 0.020), _lat(2, 1, 0.025),   # dim 4: 0.020 (K4 L0), not 0.025
            _lat(4, 1, 0.022),                                          # dim 8, worse than dim 4: envelope keeps 0.020
            _lat(8, 1, 0.010)]                                          # dim 16
    env = error_envelope(recs)
    assert [(d, e) for d, e, _ in env] == [(2, 0.030), (4, 0.020), (8, 0.020), (16, 0.010)]
    assert env[2][2]["n_components"] == 4 and env[2][2]["level2_dim"] == 0   # the smaller candidate reaching it


def test_knee_rule_picks_where_doubling_the_latent_space_stops_paying():
    # error halves with each doubling up to 8 entries, then barely moves: the knee is at 8 entries
    recs = [_lat(2, 0, 0.040), _lat(4, 0, 0.020), _lat(8, 0, 0.010), _lat(8, 1, 0.0095), _lat(8, 3, 0.0090),
            _lat(8, 7, 0.0086)]
    assert knee_latent(recs)["n_components"] == 8 and knee_latent(recs)["level2_dim"] == 0
    assert choose_latent(recs, 0.1, "knee")["level2_dim"] == 0
    assert choose_latent(recs, 0.1, "tolerance")["level2_dim"] == 3   # 0.0090 <= 1.1 x 0.0086; 0.0095 is not
    # a straight line in log2(d) has no knee: the tolerance rule decides
    line = [_lat(2, 0, 0.04), _lat(4, 0, 0.03), _lat(8, 0, 0.02), _lat(16, 0, 0.01)]
    assert knee_latent(line) is None
    assert choose_latent(line, 0.1, "knee") == choose_latent(line, 0.1, "tolerance")
    assert knee_latent(recs[:2]) is None   # two sizes: no curve
    with pytest.raises(ValueError, match="rule"):
        choose_latent(recs, 0.1, "smallest")


def test_choose_detector_fewest_parameters_within_absolute_tolerance():
    recs = [{"n_parameters": 800, "accuracy": 0.850}, {"n_parameters": 3000, "accuracy": 0.861},
            {"n_parameters": 12000, "accuracy": 0.864}, {"n_parameters": 48000, "accuracy": 0.858}]
    assert choose_detector(recs, 0.005)["n_parameters"] == 3000   # 0.861 >= 0.864 - 0.005; 800 is 1.4 points off
    assert choose_detector(recs, 0.0)["n_parameters"] == 12000
    assert choose_detector(recs, 0.02)["n_parameters"] == 800


def test_choose_from_records_compares_detectors_at_the_chosen_latent_only():
    def rec(run, k, l2, err, params, acc):
        return {"run": run, "n_components": k, "level2_dim": l2, "latent_dim": k * (1 + l2), "val_error": err,
                "n_parameters": params, "accuracy": acc, "detector_width": params / 1000}
    recs = [rec("a", 8, 3, 0.010, 1000, 0.80), rec("b", 8, 3, 0.010, 4000, 0.81),
            rec("c", 4, 3, 0.0105, 1000, 0.86), rec("d", 4, 3, 0.0105, 4000, 0.862),
            rec("e", 2, 0, 0.05, 500, 0.90)]   # most accurate, but its autoencoder is 5x worse: never chosen
    doc = choose_from_records(recs, 0.1, 0.005)
    assert doc["chosen"] == {"n_components": 4, "level2_dim": 3, "detector_width": 1.0}
    assert doc["chosen_run"] == "c" and doc["best_run"] == "d"   # best: at the chosen latent space


def _cfg(tmp_path, *extra):
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return compose(config_name="config", overrides=[
            "dataset=proc_hand", "dataset.source.n_poses=24", f"paths.cache_dir={tmp_path}/cache",
            "autoencoder=tiny", "detector=tiny",
            "realistic=tiny", "speed_accuracy=tiny", "labeling.pool.workers=0",
            "labeling.pool.progress=false",
            "handler.n_inputs=4", "handler.verify_margins=[]", "n_example_meshes=0", *extra])


def test_validate_model_size(tmp_path):
    validate_model_size(_cfg(tmp_path))  # fixed: nothing to check
    for bad, match in (("model_size.width=[]", "model_size.width"), ("model_size.level2_dim=[-1]", "level2_dim"),
                       ("model_size.accuracy_tol=-1", "accuracy_tol"), ("model_size.latent_rule=best", "latent_rule")):
        with pytest.raises(UserInputError, match=match):
            validate_model_size(_cfg(tmp_path, "model_size=auto", bad))


def test_a_run_refuses_model_size_auto_and_names_the_search_command(tmp_path):
    """The search is a command of its own: a run with model_size=auto stops before any work, saying which command
    searches the sizes (with the run's overrides)."""
    from experiments.run import refuse_size_search
    from neuralcol.pipeline.validate import validate_run_config

    cfg = _cfg(tmp_path, "model_size=auto")
    with pytest.raises(UserInputError, match=r"python -m experiments\.model_size search dataset=scape"):
        refuse_size_search(cfg, ["dataset=scape", "model_size=auto"])
    with pytest.raises(UserInputError, match=r"model_size=auto: .*python -m experiments\.model_size search"):
        validate_run_config(cfg)  # (the pipeline's own check, for runs started from Python)


def test_a_preset_is_refused_for_another_data_set(tmp_path):
    from omegaconf import open_dict

    from neuralcol.pipeline.validate import validate_run_config

    cfg = _cfg(tmp_path)
    with open_dict(cfg):
        cfg.model_size.dataset = "scape"  # what a preset of the size search for SCAPE holds
    with pytest.raises(UserInputError, match="searched for dataset=scape, not dataset=proc_hand"):
        validate_run_config(cfg)


def test_auto_search_end_to_end(tmp_path, capsys):
    """The search (python -m experiments.model_size search) on proc_hand at test size, then a run with the preset it
    writes: the same search and the same choice as model_size=auto made inside a run."""
    from experiments.model_size import main as model_size_main
    from experiments.model_size import search, write_preset
    from experiments.run import run

    sizes = ["model_size.n_components=[2,4]", "model_size.level2_dim=[0,1]", "model_size.width=[0.5,1.0]",
             "model_size.budget=80", "model_size.recon_tol=0.5", "detector.max_rounds=0", "realistic.enabled=false"]
    cfg = _cfg(tmp_path, "model_size=auto", *sizes)
    evidence = tmp_path / "search"
    doc = search(cfg, evidence, run)
    assert json.loads((evidence / "model_size.json").read_text()) == json.loads(json.dumps(doc))
    assert len(doc["latent"]) == 4 and len(doc["detector"]) == 2 and doc["budget"] == 80
    c = doc["chosen"]
    assert c["n_components"] in (2, 4) and c["level2_dim"] in (0, 1) and c["detector_width"] in (0.5, 1.0)
    # the rule, checked on the recorded evidence by an independent computation
    best_err = min(r["val_error"] for r in doc["latent"])
    eligible = [r for r in doc["latent"] if r["val_error"] <= 1.5 * best_err]
    assert c["n_components"] * (1 + c["level2_dim"]) == min(r["n_components"] * (1 + r["level2_dim"])
                                                            for r in eligible)
    best_acc = max(r["accuracy"] for r in doc["detector"])
    chosen = next(r for r in doc["detector"] if r["detector_width"] == c["detector_width"])
    assert chosen["accuracy"] >= best_acc - 0.005
    assert json.dumps(search(cfg, evidence, run)) == json.dumps(doc)  # a finished search is read back (NaN: NaN)
    # each width's sub-run is a run directory of its own: the Python API opens it with its sizes
    from neuralcol import load_run

    sub = load_run(evidence / "width_0.5")
    assert sub.cfg.detector.net.width == 0.5 and sub.cfg.detector.max_rounds == 0
    assert sub.detect(sub.space.sample(3)).prob.shape == (3,)
    sub.close()
    # the preset: a model_size option of its own (here on Hydra's search path); the run takes the chosen sizes
    preset = write_preset(tmp_path / "conf" / "model_size" / "searched.yaml", doc, "proc_hand",
                          evidence / "model_size.json")
    assert preset.read_text().startswith("# @package _global_\n")
    run_cfg = _cfg(tmp_path, "model_size=searched", f"hydra.searchpath=[file://{tmp_path / 'conf'}]", *sizes[-2:])
    assert run_cfg.dataset.latent.n_components == c["n_components"] and run_cfg.model_size.mode == "fixed"
    metrics = run(run_cfg, tmp_path / "run")
    assert metrics["model_size"]["chosen"] == c
    assert {k: metrics["model_size"][k] for k in ("chosen_accuracy", "best_accuracy", "budget", "default", "rule")} \
        == {k: doc[k] for k in ("chosen_accuracy", "best_accuracy", "budget", "default", "rule")}
    assert metrics["latent"]["n_parts"] == c["n_components"]
    assert metrics["latent"]["dim"] == c["n_components"] * (1 + c["level2_dim"])
    assert metrics["detector"]["net"]["width"] == c["detector_width"]
    # the sub-runs are a sweep directory: the CLI applies the same rule to them
    capsys.readouterr()
    model_size_main([str(evidence), "--recon-tol", "0.5"])
    assert "chosen:" in capsys.readouterr().out
    again = json.loads((evidence / "model_size.json").read_text())
    assert again["chosen"]["detector_width"] == c["detector_width"]
    # ... and the report draws them with the choice marked on the Pareto chart
    from experiments.report import main as report_main

    report_main([str(evidence), "--out", str(tmp_path / "report")])
    assert (tmp_path / "report" / "pareto.png").is_file()
    starred = [ln for ln in (tmp_path / "report" / "report.md").read_text().splitlines() if "**chosen**" in ln]
    assert len(starred) == 1 and f"K{c['n_components']} L{c['level2_dim']}" in starred[0]
