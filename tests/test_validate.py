"""Configuration errors are caught before any work, each naming the key, its value and the rule."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from neuralcol.errors import UserInputError
from neuralcol.pipeline.validate import config_problems, validate_run_config

ROOT = Path(__file__).resolve().parents[1]


def _compose(overrides):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


@pytest.mark.parametrize("preset", ["", "experiment=cpu_scape", "experiment=paper_scape",
                                    "experiment=paper_scape_neuralcol", "experiment=cpu_anny_body",
                                    "experiment=paper_anny_body", "detector=tiny",
                                    "method=supv", "method=supv_bd", "method.start=uncertain"])
def test_shipped_configs_are_valid(preset):
    assert config_problems(_compose([preset] if preset else [])) == []


@pytest.mark.parametrize("override, key", [
    ("method.name=foo", "method.name='foo': use one of supv, supv_bd, active"),
    ("detector.n_init=-5", "detector.n_init=-5: must be an integer >= 1"),
    ("detector.n_aug=1001", "detector.n_aug=1001: must be even"),
    ("labeling.labeler.boundary_eps=0", "labeling.labeler.boundary_eps=0: must be > 0"),
    ("detector.newton.eps_z=-1e-7", "detector.newton.eps_z=-1e-07: must be > 0"),
    ("handler.n_inputs=-1", "handler.n_inputs=-1: must be an integer >= 0"),
    ("handler.verify_margins=[2.0,1.0]", "handler.verify_margins=[2.0, 1.0]: must increase"),
    ("handler.alm.mu0=0", "handler.alm: handler settings"),
    ("handler.repair.delta=0", "handler.repair: handler.repair RepairSettings"),
    ("labeling.pool.timeout=0", "labeling.pool.timeout=0: must be > 0 seconds"),
    ("labeling.pool.max_restarts=-1", "labeling.pool.max_restarts=-1: must be an integer >= 0"),
    ("labeling.data_in_process=-5", "labeling.data_in_process=-5: must be an integer >= 0"),
    ("labeling.pool.executor=spark", "labeling.pool.executor='spark': use one of local (this machine's worker "
                                     "processes), dask"),
    ("labeling.pool.scheduler=tcp://h:8786", "labeling.pool.scheduler='tcp://h:8786': only used with "
                                             "labeling.pool.executor=dask"),
    ("detector.newton.coordinates=normalised", "detector.newton.coordinates='normalised': use one of box, raw"),
    ("detector.loss.boundary_reduction=sum", "detector.loss.boundary_reduction='sum': use one of boundary, batch"),
    ("autoencoder.box_from=val", "autoencoder.box_from='val': use one of train, all"),
    ("method.start=random", "method.start='random': use one of dc, uncertain"),
    ("method.candidates=0", "method.candidates=0: must be an integer >= 1"),
    ("detector.targets.pd_floor=0.5", "detector.targets.pd_floor=0.5: must be < 0"),
    ("autoencoder.level1.code_noise=-0.1", "autoencoder.level1.code_noise=-0.1: must be >= 0"),
    ("autoencoder.level2.interp_ratio=-1", "autoencoder.level2.interp_ratio=-1: must be >= 0"),
    ("autoencoder.interp_t=[1.0,0.0]", "autoencoder.interp_t"),
    ("detector.targets.training_labels=clipped", "detector.targets.training_labels='clipped': use limited or full"),
    ("detector.operating_set=codes", "detector.operating_set='codes': use auto, calibration, realistic, both or "
                                     "realistic_calibration"),
    ("detector.inputs=latent detector.operating_set=both", "detector.operating_set='both': needs detector.inputs"),
    ("detector.operating_set=realistic_calibration realistic.enabled=false",
     "detector.operating_set='realistic_calibration': needs realistic.enabled=true"),
    ("realistic.label_clearance=some", "realistic.label_clearance='some': use clear or full"),
])
def test_bad_settings_are_named(override, key):
    problems = config_problems(_compose(override.split()))
    assert any(p.startswith(key) for p in problems), problems
    with pytest.raises(UserInputError, match="bad configuration"):
        validate_run_config(_compose(override.split()))


def test_several_problems_reported_together():
    problems = config_problems(_compose(["detector.n_init=0", "detector.lr=-1"]))
    assert len(problems) == 2


def test_bad_config_is_one_line_before_any_work(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "experiments.run", "detector.n_aug=999",
                           f"paths.output_dir={tmp_path}/out", f"paths.cache_dir={tmp_path}/cache"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120,
                          env={k: v for k, v in __import__("os").environ.items()
                               if k not in ("HYDRA_FULL_ERROR", "NEURALCOL_DEBUG")})
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "detector.n_aug=999: must be even" in lines[0], lines
    assert not (tmp_path / "cache").exists(), "no work started"


def test_unknown_data_set_names_the_allowed_values(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "experiments.run", "dataset=scap",
                           f"paths.output_dir={tmp_path}/out", f"paths.cache_dir={tmp_path}/cache"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert "Could not find 'dataset/scap'" in proc.stderr and "Available options in 'dataset'" in proc.stderr
    assert "\tscape\n" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "cache").exists(), "no work started"


def test_missing_checkpoint_is_one_line(tmp_path, capsys, monkeypatch):
    from experiments.handle import main as handle_main

    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    monkeypatch.delenv("NEURALCOL_DEBUG", raising=False)
    (tmp_path / "run" / ".hydra").mkdir(parents=True)
    (tmp_path / "run" / ".hydra" / "config.yaml").write_text("seed: 0\n")
    (tmp_path / "run" / "metrics.json").write_text("{}")
    with pytest.raises(SystemExit) as exit_:
        handle_main([str(tmp_path / "run"), str(tmp_path / "in.obj")])
    assert exit_.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "detector.pt: missing" in lines[0] and "finished" in lines[0], lines
