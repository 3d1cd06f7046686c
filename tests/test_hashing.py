"""Cache keys stay byte for byte what they were: every cache site computes its key through
``neuralcol.utils.hashing``, and each known key below was computed with the code before that helper existed (the
hand-written ``hashlib.sha1(json.dumps(...)).hexdigest()[:N]`` at each site). A changed key would silently invalidate
every user's cache (data sets, ACAP features, autoencoders, labeled samples, realistic sets, box fits)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

from neuralcol.utils.hashing import content_key, settings_key

REALISTIC_CFG = {"seed": 3, "n_acap_interp": 10, "n_vertex_interp": 4, "n_perturbed": 2, "t_range": [-0.6, 1.6],
                 "perturb_scale": 0.8, "clear_eps": 10, "per_class": None, "label_clearance": "clear"}


def test_settings_key_is_the_sha1_of_sorted_json():
    box_fit = {"band": [0.1, 0.55], "shrink": [0.9, 0.8, 0.7, 0.6, 0.5], "grow": [1.25, 1.5, 2.0], "n_probe": 256,
               "seed": 7}
    assert settings_key(box_fit, 12) == "1fe98c156e73"  # RunContext.fit_box's box_fit_<tag>.json
    assert settings_key(dict(reversed(box_fit.items())), 12) == "1fe98c156e73"  # the order of entries is not read
    assert settings_key(box_fit) == settings_key(box_fit, 40)[:16]
    assert content_key([b"ab", b"c"]) == content_key([b"abc"])


def test_samples_cache_dir_keys(tmp_path):
    from neuralcol.samples.cache import samples_cache_dir

    lab = SimpleNamespace(eps=0.004, cap=0.05, tau=0.5, n_parts=8, label_version=3)
    assert samples_cache_dir(tmp_path / "a", "0123456789abcdef-box0.8", lab).name == "231dbbb0ec5ad415"
    fcl = SimpleNamespace(eps=0.004, cap=0.05, tau=0.5, n_parts=8, label_kind="fcl")
    assert samples_cache_dir(tmp_path / "b", "0123456789abcdef", fcl).name == "cb1eebd507d71c7e"


def test_autoencoder_and_dataset_and_feature_keys(tmp_path):
    from neuralcol.data.datasets import load_procedural_dataset
    from neuralcol.data.features import dataset_features
    from neuralcol.stages.autoencoder import autoencoder_cache_key

    ds = SimpleNamespace(vertices=torch.arange(24, dtype=torch.float64).reshape(2, 4, 3) / 7,
                         faces=torch.tensor([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]))
    key = autoencoder_cache_key(ds, 0, {"w": 1.0}, {"kind": "pca", "epochs": 3, "lr": Path("x")},
                                {"n_components": 4, "level2_dim": 0}, 2)
    assert key == "e55f625156e43ef2"
    load_procedural_dataset("proc_hand", 3, 5, cache_dir=tmp_path / "ds", geometry={})
    assert [p.name for p in (tmp_path / "ds").iterdir()] == ["proc_hand_n3_s5_ddc6a4e8aa.npz"]
    dataset_features(load_procedural_dataset("proc_hand", 2, 0), 0, {}, {}, cache_dir=tmp_path / "feat")
    assert [p.name for p in (tmp_path / "feat").iterdir()] == ["acap_e4d708bf8c678dd2.npz"]


def test_realistic_set_and_full_label_files(tmp_path):
    """The realistic sets are read from the file of their key (nothing is built or labeled: no pool is given)."""
    from neuralcol.samples.realistic import full_labels, realistic_set

    meshes = {"vertices": np.zeros((1, 3, 3)), "kind": np.zeros(1, np.int8), "source": np.zeros((1, 3), np.int64),
              "t": np.zeros(1), "pd": np.ones(1)}
    for tag, kw, name in (("realistic", {}, "realistic_b25a2fceaa68fc15.npz"),
                          ("realistic_calibration", {"clearance_limit": 0.04},
                           "realistic_calibration_f286d2c25b416359.npz"),
                          ("realistic_train", {"sources": [0, 2, 5]}, "realistic_train_023333c610c0c639.npz")):
        folder = tmp_path / tag
        folder.mkdir()
        np.savez(folder / name, **meshes)
        _, pd, cached = realistic_set(None, None, None, [1, 4], None, REALISTIC_CFG, folder, 0.004, tag=tag, **kw)
        assert cached and pd.tolist() == [1.0]
    v = np.linspace(0, 1, 2 * 5 * 3).reshape(2, 5, 3)
    np.savez(tmp_path / "realistic_train_full_0a7959f05edc7c63.npz", ok=np.ones(2, bool), pd=np.ones(2),
             pd_sub=np.ones((2, 1)))
    ok, _, _ = full_labels(None, v, tmp_path)
    assert ok.tolist() == [True, True]
