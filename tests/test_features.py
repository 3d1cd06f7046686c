"""Data set features: normaliser round trip and state, feature cache."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuralcol.data.datasets import MeshDataset
from neuralcol.data.features import dataset_features
from neuralcol.nn.normalizer import FeatureNormalizer


def test_normalizer_round_trip_and_range():
    rng = np.random.default_rng(0)
    feats = torch.from_numpy(rng.normal(size=(20, 30, 9)) * rng.uniform(0.01, 3, size=(1, 30, 9)))
    feats[:, 5, 2] = 0.7  # constant entry: its range is floored, no division by zero
    norm = FeatureNormalizer(bound=0.9, min_range_ratio=0.05).fit(feats)
    z = norm.normalize(feats)
    assert torch.isfinite(z).all()
    assert z.abs().max() <= 0.9 + 1e-12
    assert torch.allclose(z[:, 5, 2], torch.zeros(20, dtype=torch.float64))
    torch.testing.assert_close(norm.denormalize(z), feats)
    restored = FeatureNormalizer().load_state_dict(norm.state_dict())
    torch.testing.assert_close(restored.normalize(feats), z)
    with pytest.raises(RuntimeError, match="not fitted"):
        FeatureNormalizer().normalize(feats)


def test_dataset_features_cache(tmp_path, scape):
    small = scape.subset(slice(0, 4))
    ds = MeshDataset(small.vertices, small.faces, small.names)
    a = dataset_features(ds, reference_index=0, cache_dir=tmp_path, fit_index=[0, 1, 2])
    files = list(tmp_path.glob("acap_*.npz"))
    assert len(files) == 1
    b = dataset_features(ds, reference_index=0, cache_dir=tmp_path, fit_index=[0, 1, 2])
    torch.testing.assert_close(a.features, b.features, rtol=0, atol=0)
    torch.testing.assert_close(a.features, a.acap.encode(ds.vertices))
    # the normaliser was fitted on meshes 0..2 only
    z = a.normalizer.normalize(a.features[:3])
    assert z.abs().max() <= 0.95 + 1e-9
    c = dataset_features(ds, reference_index=1, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("acap_*.npz"))) == 2
    assert not torch.allclose(c.features, a.features)
    with pytest.raises(ValueError, match="reference_index=9"):
        dataset_features(ds, reference_index=9)
