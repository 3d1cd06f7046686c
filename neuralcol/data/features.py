"""ACAP features of a whole data set, their normalisation for the autoencoder, and their cache."""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from neuralcol.data.datasets import MeshDataset
from neuralcol.geometry.acap import ACAP, FEATURE_DIM
from neuralcol.nn.normalizer import FeatureNormalizer
from neuralcol.utils.files import atomic_path
from neuralcol.utils.hashing import settings_key


class DatasetFeatures(NamedTuple):
    """ACAP features of a data set.

    Attributes:
        acap: the ACAP transform (rest mesh = the reference mesh of the data set).
        features: (N, V, 9) float raw features.
        normalizer: FeatureNormalizer fitted on ``features[fit_index]``.
        reference_index: index of the rest mesh in the data set.
        from_cache: the features were read from the cache instead of computed.
    """

    acap: ACAP
    features: torch.Tensor
    normalizer: FeatureNormalizer
    reference_index: int
    from_cache: bool


def dataset_features(
    dataset: MeshDataset,
    reference_index: int = 0,
    acap_kwargs: dict | None = None,
    normalizer_kwargs: dict | None = None,
    fit_index=None,
    cache_dir: str | os.PathLike | None = None,
) -> DatasetFeatures:
    """ACAP-encode every mesh of a data set and fit the feature normaliser; cached on disk.

    Args:
        dataset: the meshes.
        reference_index: mesh used as the ACAP rest mesh.
        acap_kwargs: keyword arguments of :class:`ACAP`.
        normalizer_kwargs: keyword arguments of :class:`FeatureNormalizer`.
        fit_index: meshes the normaliser is fitted on (e.g. the training split); default all.
        cache_dir: folder for the ``.npz`` cache keyed by the vertices and settings; None disables it.

    Returns:
        DatasetFeatures.
    """
    n = len(dataset)
    if not 0 <= reference_index < n:
        raise ValueError(f"reference_index={reference_index}: the data set has {n} meshes (0..{n - 1})")
    acap_kwargs = dict(acap_kwargs or {})
    normalizer_kwargs = dict(normalizer_kwargs or {})
    verts = dataset.vertices.detach().cpu().to(torch.float64)
    acap = ACAP(verts[reference_index], dataset.faces, **acap_kwargs)
    idx = np.arange(n)[fit_index] if fit_index is not None else np.arange(n)
    cache = None
    if cache_dir is not None:
        key = settings_key([reference_index, acap_kwargs], 16,
                           data=[verts.numpy().tobytes(), dataset.faces.cpu().numpy().tobytes()])
        cache = Path(cache_dir).expanduser() / f"acap_{key}.npz"
    feats = None
    from_cache = False
    if cache is not None and cache.is_file():
        try:
            with np.load(cache) as z:
                feats = torch.from_numpy(z["features"])
            from_cache = feats.shape == (n, dataset.n_vertices, FEATURE_DIM)
            feats = feats if from_cache else None
        except (OSError, ValueError, KeyError):
            feats = None
    if feats is None:
        feats = acap.encode(verts)
        if cache is not None:
            cache.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(cache) as tmp:
                np.savez(tmp, features=feats.numpy())
    feats = feats.to(dataset.vertices.dtype)
    normalizer = FeatureNormalizer(**normalizer_kwargs).fit(feats[torch.as_tensor(idx)])
    return DatasetFeatures(acap, feats, normalizer, reference_index, from_cache)
