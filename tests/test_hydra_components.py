"""Hydra builds the pipeline's components from their `_target_`s: the composed configs instantiate to
the classes the stages use, and swapping a `_target_` on the command line swaps the component."""

from __future__ import annotations

import functools
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from neuralcol.active.acquisition import ProjectedAcquisition, UniformAcquisition
from neuralcol.active.rounds import RoundCallback
from neuralcol.lit.detector import detector_module
from neuralcol.nn.detector import CollisionDetector
from neuralcol.utils.config import as_dict

CONF = str(Path(__file__).resolve().parents[1] / "conf")


def _cfg(overrides=()):
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


@pytest.mark.parametrize("method, cls", [("supv", UniformAcquisition), ("supv_bd", UniformAcquisition),
                                         ("active", ProjectedAcquisition), ("active_paper", ProjectedAcquisition)])
def test_each_method_builds_its_acquisition(method, cls):
    made = instantiate(as_dict(_cfg([f"method={method}"]).method)["acquisition"])
    assert isinstance(made, functools.partial) and made.func is cls


def test_active_acquisition_takes_the_method_level_settings():
    acq = as_dict(_cfg(["method=active", "method.candidates=7", "method.start=dc"]).method)["acquisition"]
    assert (acq["candidates"], acq["start"], acq["project"]) == (7, "dc", False)
    assert acq["newton"]["max_iter"] == 50  # detector.newton, interpolated


def test_detector_components_build_and_swap():
    det = as_dict(_cfg(["detector.optimizer._target_=torch.optim.SGD"]).detector)
    net = CollisionDetector(2, 1, 8, 16)
    opt = detector_module(net, det, w_b=0.5, lr=0.01).configure_optimizers()
    assert isinstance(opt, torch.optim.SGD) and opt.param_groups[0]["lr"] == 0.01
    assert instantiate(det["rounds"]).func is RoundCallback
    trainer = instantiate(det["trainer"])(max_epochs=1, logger=False, enable_progress_bar=False)
    assert trainer.max_epochs == 1 and trainer.check_val_every_n_epoch == det["val_every"]
    default = as_dict(_cfg().detector)
    assert isinstance(detector_module(net, default, 0.5, 0.01).configure_optimizers(), torch.optim.Adam)


@pytest.mark.parametrize("backend, target", [("cpu", "neuralcol.collision.labeler.ExactLabeler"),
                                             ("gpu", "neuralcol.collision.warp_labeler.WarpLabeler"),
                                             ("fcl", "neuralcol.collision.fcl_labeler.FCLLabeler"),
                                             ("auto", "neuralcol.collision.backends.auto_labeler")])
def test_labeling_backends_are_config_files(backend, target):
    lab = _cfg([f"labeling={backend}"]).labeling
    assert lab.labeler._target_ == target and lab.backend == backend
    assert lab.labeler.boundary_eps == 1.0e-4  # the shared settings, written once in cpu.yaml
