"""The operating threshold's one home (neuralcol.operating): where it is measured, how it is set, reported and
folded into a detector, and the configuration's rules."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuralcol import operating


def test_auto_prefers_the_realistic_calibration_set_then_dc_rows_then_codes():
    assert operating.choose_set("auto", True, True) == "realistic_calibration"
    assert operating.choose_set("auto", False, True) == "realistic"
    assert operating.choose_set("auto", False, False) == "calibration"
    assert operating.choose_set("both", True, True) == "both"
    with pytest.raises(ValueError, match="operating_set='nowhere'"):
        operating.choose_set("nowhere", True, True)


def test_a_run_draws_calibration_meshes_only_when_its_threshold_reads_them():
    assert operating.needs_calibration_meshes({"operating_fnr": 0.1, "operating_set": "auto"}, True)
    assert operating.needs_calibration_meshes({"operating_fnr": 0.1, "operating_set": "realistic_calibration"}, True)
    assert not operating.needs_calibration_meshes({"operating_fnr": 0.1, "operating_set": "auto"}, False)
    assert not operating.needs_calibration_meshes({"operating_fnr": None, "operating_set": "auto"}, True)
    assert not operating.needs_calibration_meshes({"operating_fnr": 0.1, "operating_set": "calibration"}, True)
    assert not operating.needs_calibration_meshes({"operating_fnr": 0.1}, True)


def test_threshold_for_one_set_is_fnr_threshold_and_several_the_mean_rule():
    rng = np.random.default_rng(0)
    a = (rng.normal(size=200), rng.random(200) < 0.5)
    b = (rng.normal(1.0, 1.0, size=50), rng.random(50) < 0.7)
    assert operating.threshold_for([a], 0.1) == operating.fnr_threshold(*a, 0.1)
    assert operating.threshold_for([a, b], 0.1) == operating.mean_fnr_threshold([a, b], 0.1)


def test_calibration_record_counts_the_misses_at_the_threshold():
    logit = np.array([-2.0, -1.0, 0.5, 1.0, 2.0, -3.0, 0.2])
    y = np.array([True, True, True, True, True, False, False])
    rec = operating.calibration_record([(logit, y)], 0.0)
    # at logit > 0: colliding -2, -1 missed (2 of 5); the free 0.2 is a false alarm (1 of 2)
    assert (rec["n"], rec["n_colliding"]) == (7, 5)
    assert rec["fnr"] == pytest.approx(0.4) and rec["fpr"] == pytest.approx(0.5)
    assert rec["accuracy"] == pytest.approx(4 / 7)
    lo, hi = rec["fnr_ci95"]
    assert lo < 0.4 < hi
    two = operating.calibration_record([(logit, y), (np.array([1.0, -1.0]), np.array([True, True]))], 0.0)
    assert two["fnr"] == pytest.approx((0.4 + 0.5) / 2) and "fnr_ci95" not in two


def test_score_reports_skill_against_the_majority_class():
    y = np.array([True] * 3 + [False] * 7)
    always_free = operating.score(np.full(10, -1.0), y, 0.0)
    assert always_free["accuracy"] == pytest.approx(0.7) and always_free["skill"] == pytest.approx(0.0)
    perfect = operating.score(np.where(y, 1.0, -1.0), y, 0.0)
    assert perfect["skill"] == pytest.approx(1.0) and perfect["fnr"] == 0.0


def test_config_problems_name_the_key_and_the_fix():
    def get(cfg):
        return lambda key: cfg.get(key)

    assert operating.config_problems(get({"detector.operating_fnr": 0.1, "detector.operating_set": "auto"})) == []
    bad = operating.config_problems(get({"detector.operating_fnr": 1.5, "detector.operating_set": "sideways"}))
    assert any(p.startswith("detector.operating_fnr=1.5") for p in bad)
    assert any(p.startswith("detector.operating_set='sideways'") for p in bad)
    need = operating.config_problems(get({"detector.operating_fnr": 0.1,
                                          "detector.operating_set": "realistic_calibration",
                                          "realistic.enabled": False}))
    assert len(need) == 1 and "realistic.enabled=true" in need[0]
    rows = operating.config_problems(get({"detector.operating_fnr": 0.1, "detector.operating_set": "both",
                                          "detector.inputs": "latent"}))
    assert len(rows) == 1 and "code_and_mesh" in rows[0]
    # the paper's decision (no operating FNR) asks nothing of the set
    assert operating.config_problems(get({"detector.operating_fnr": None,
                                          "detector.operating_set": "realistic_calibration"})) == []


def test_folding_a_threshold_into_a_saved_detector_equals_folding_it_in_memory(tmp_path):
    from neuralcol.nn.detector import CollisionDetector, load_detector, save_detector

    torch.manual_seed(0)
    net = CollisionDetector(4, 2, state_dim=8, hidden=8)
    path = tmp_path / "detector.pt"
    save_detector(path, net, {"net": {"state_dim": 8, "hidden": 8}}, {"name": "supv"}, 1.0)
    z = torch.rand(16, net.latent_dim) * 2 - 1
    with torch.no_grad():
        before = net(z).logit
    operating.fold_into_file(path, 0.7)
    saved, _ = load_detector(path)
    operating.fold_into(net, 0.7)
    with torch.no_grad():
        assert torch.allclose(saved(z).logit, before - 0.7, atol=1e-6)
        assert torch.equal(net(z).logit, saved(z).logit)
