"""The data sets a user points at a folder of their own meshes (`dataset=meshes|hand|skirt|swing|jump
dataset.source.path=...`) compose to the adopted latent space, PCA of the vertices with the fitted box, exactly as
scape, proc_hand, proc_cloth and anny_body do; an explicit `autoencoder=cpu|paper` and the paper-scale presets keep
the bilevel autoencoder; `dataset=meshes` without a path stops with one line. Config composition only."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf

from neuralcol.errors import DatasetNotFoundError
from neuralcol.utils.cli import find_user_error, report_user_errors

CONF = str(Path(__file__).resolve().parents[1] / "conf")
USER_DATASETS = ("meshes", "hand", "skirt", "swing", "jump")
CPU_PRESETS = ("hand", "skirt", "swing", "jump")  # conf/experiment/cpu_<name>.yaml (none for meshes)


def _cfg(overrides=()):
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def _latent_settings(cfg) -> dict:
    """What chooses the latent space: the autoencoder group (kind, basis, box rule) and the box fit, unresolved."""
    return {"autoencoder": OmegaConf.to_container(cfg.autoencoder), "box_fit": OmegaConf.to_container(cfg.box_fit)}


@pytest.mark.parametrize("overrides", [[f"dataset={name}"] for name in USER_DATASETS]
                         + [[f"experiment=cpu_{name}"] for name in CPU_PRESETS])
def test_user_datasets_take_the_pca_space_with_the_fitted_box(overrides):
    cfg = _cfg(overrides)
    assert (cfg.autoencoder.kind, cfg.autoencoder.basis) == ("pca", "vertex")
    assert cfg.box_fit.enabled and list(cfg.box_fit.band) == [0.10, 0.55]
    assert _latent_settings(cfg) == _latent_settings(_cfg(["dataset=scape"]))  # exactly SCAPE's
    assert not _cfg([*overrides, "detector=tiny"]).box_fit.enabled  # the tests' tiny runs sample the paper's box


@pytest.mark.parametrize("name", USER_DATASETS)
@pytest.mark.parametrize("autoencoder, epochs", [("cpu", "${dataset.cpu.ae_epochs}"), ("paper", 3000)])
def test_an_explicit_autoencoder_keeps_the_bilevel_one(name, autoencoder, epochs):
    ae = _cfg([f"dataset={name}", f"autoencoder={autoencoder}"]).autoencoder
    assert ae.kind == "bilevel" and "basis" not in ae
    assert OmegaConf.to_container(ae)["level1"]["epochs"] == epochs


@pytest.mark.parametrize("name", CPU_PRESETS)
def test_paper_presets_keep_the_papers_autoencoder(name):
    assert _cfg([f"experiment=cpu_{name}", "autoencoder=cpu"]).autoencoder.kind == "bilevel"
    ae = _cfg([f"experiment=paper_{name}"]).autoencoder
    assert (ae.kind, ae.level1.epochs, ae.level2.epochs) == ("bilevel", 3000, 3000)


def test_meshes_has_no_paper_specific_setting():
    ds = _cfg(["dataset=meshes", "dataset.source.path=/my/meshes"]).dataset
    assert ds.name == "meshes" and ds.source.path == "/my/meshes"
    assert ds.source._target_ == "neuralcol.data.datasets.load_mesh_dataset" and ds.source.expected_vertices is None
    cpu = ds.cpu
    assert (cpu.n_init, cpu.n_aug, cpu.max_rounds, cpu.test_size, cpu.handler_inputs, cpu.ae_epochs) == (
        2000, 2000, 3, 4000, 300, 500)


def test_meshes_without_a_path_stops_with_one_line(tmp_path, monkeypatch, capsys):
    for var in ("HYDRA_FULL_ERROR", "NEURALCOL_DEBUG"):  # (they ask for the traceback)
        monkeypatch.delenv(var, raising=False)
    cfg = _cfg(["dataset=meshes", f"paths.data_dir={tmp_path}"])
    with pytest.raises(Exception) as raised:  # (hydra wraps the loader's error)
        instantiate(cfg.dataset.source)
    assert isinstance(find_user_error(raised.value), DatasetNotFoundError)
    with pytest.raises(SystemExit) as exit_:
        report_user_errors(lambda: instantiate(cfg.dataset.source))()  # as experiments.run reports it
    assert exit_.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {tmp_path / 'meshes'}: data set not found"), lines
    assert "dataset.source.path=DIR" in lines[0]  # the fix a user of dataset=meshes needs
