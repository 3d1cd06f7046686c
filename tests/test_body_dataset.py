"""The anny body data set: anny's main shell posed in action sequences, deterministic, cached, valid."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from neuralcol.errors import UserInputError

anny = pytest.importorskip("anny")  # the `body` extra (make install installs it)

from neuralcol.data.procedural.body import ACTIONS, action_angles, make_anny_body  # noqa: E402


@pytest.fixture(scope="module")
def stride_and_crouch():
    """20 poses: a walking stride (sequence 0) and a crouch and jump (sequence 1)."""
    return make_anny_body(20, seed=0)


def test_main_shell_topology_and_determinism(stride_and_crouch):
    verts, faces = stride_and_crouch
    assert verts.shape == (20, 13348, 3) and faces.shape == (26692, 3) and verts.dtype == np.float64
    assert faces.min() == 0 and faces.max() == 13347 and np.isfinite(verts).all()
    again, faces_again = make_anny_body(20, seed=0)
    np.testing.assert_array_equal(again, verts)
    np.testing.assert_array_equal(faces_again, faces)
    other, _ = make_anny_body(20, seed=1)
    assert np.abs(other - verts).max() > 1e-3  # another seed: other amplitudes


def test_rest_frame_is_free_and_the_crouch_touches(stride_and_crouch):
    """Pose 0 (the stride's first frame: the rest pose with the little toes turned out) is collision-free, which
    anny's own rest pose is not (each little toe cuts toe 4); the deep crouch brings thighs and calves together."""
    from neuralcol.collision.labeler import ExactLabeler

    verts, faces = stride_and_crouch
    lab = ExactLabeler(faces, verts[0])
    assert not lab.label(verts[0]).collides
    untouched, _ = make_anny_body(1, seed=0, toe_out_deg=0.0)
    assert lab.label(untouched[0]).n_pairs > 0
    assert lab.label(verts[13]).collides  # sequence 1, frame 3: deep in the crouch


def test_loader_caches_and_validates(tmp_path):
    from neuralcol.data.datasets import load_procedural_dataset

    ds = load_procedural_dataset("anny_body", n_poses=4, seed=0, cache_dir=tmp_path)
    assert ds.vertices.shape == (4, 13348, 3) and ds.faces.shape == (26692, 3)
    assert len(list(tmp_path.glob("anny_body_n4_s0_*.npz"))) == 1
    again = load_procedural_dataset("anny_body", n_poses=4, seed=0, cache_dir=tmp_path)
    np.testing.assert_array_equal(again.vertices.numpy(), ds.vertices.numpy())


def test_every_action_moves_the_body():
    t = np.linspace(0, 1, 5)
    for action in ACTIONS:
        angles = action_angles(action, t, np.ones(4), 1)
        assert angles and max(np.abs(a).max() for a in angles.values()) >= 20, action
    with pytest.raises(ValueError, match="action 'fly'"):
        action_angles("fly", t, np.ones(4), 1)


def test_bad_settings_and_missing_anny_are_one_clear_line(monkeypatch):
    with pytest.raises(UserInputError, match=r"unknown setting\(s\) \['wings'\]"):
        make_anny_body(2, wings=2)
    from neuralcol.data.procedural import body

    monkeypatch.setitem(sys.modules, "anny", None)  # `import anny` now raises ImportError
    with pytest.raises(UserInputError, match="pip install anny"):
        body._anny()


def test_pipeline_end_to_end_on_a_body_subset(tmp_path):
    """The whole run at body size (13 348 vertices, 26 692 triangles) on 20 poses with the tiny presets and fewer
    samples: every stage (data labels, autoencoder, D_c, detector, handler, cascade, realistic set, speed chart) meets
    the large mesh once in ``make test``."""
    from hydra import compose, initialize_config_dir

    from experiments.run import run

    conf = Path(__file__).resolve().parents[1] / "conf"
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        cfg = compose("config", overrides=[
            "dataset=anny_body", "dataset.source.n_poses=20", f"paths.cache_dir={tmp_path}/cache",
            "n_example_meshes=1", "autoencoder=tiny", "detector=tiny", "detector.n_init=24", "detector.n_aug=12",
            "detector.max_rounds=1", "detector.test_size=32", "detector.cascade.calibration_size=32",
            "realistic=tiny", "realistic.n_acap_interp=6", "realistic.n_vertex_interp=3", "realistic.n_perturbed=3",
            "realistic.handler_inputs=2",
            "speed_accuracy=tiny", "speed_accuracy.n_exact=4", "speed_accuracy.n_meshlab=4", "speed_accuracy.n_fcl=2",
            "handler.n_inputs=2", "handler.verify_margins=[4.0]", "labeling.pool.workers=0",
            "labeling.pool.progress=false"])
    m = run(cfg, tmp_path / "run")
    assert (m["dataset"]["n_meshes"], m["dataset"]["n_vertices"], m["dataset"]["n_faces"]) == (20, 13348, 26692)
    assert m["autoencoder"]["latent_dim"] == 16 and m["latent"]["dim"] == 16  # no level 2 (conf/dataset/anny_body)
    assert [r["dataset_size"] for r in m["rounds"]] == [24, 36]
    assert m["detector"]["test_set"]["n"] == 32 and 0 <= m["rounds"][-1]["accuracy"] <= 1
    assert m["realistic"]["n"] > 0 and "mesh_detector" not in m  # (no separate mesh detector)
    assert (tmp_path / "run" / "metrics.json").is_file() and (tmp_path / "run" / "speed_accuracy.png").is_file()
