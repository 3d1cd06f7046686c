"""ACAP features of a whole data set, their normalisation for the autoencoder, and their cache."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from neuralcol.data.datasets import MeshDataset
from neuralcol.geometry.acap import ACAP, FEATURE_DIM
from neuralcol.utils.files import atomic_path


class FeatureNormalizer:
    """Per-entry affine map of ACAP features to ``[-bound, bound]`` (Gao et al.'s min-max scaling).

    Each of the V x 9 feature entries is scaled by its min and max over the fitted data set. A range below
    ``min_range_ratio`` x the median range of its channel is widened to that, so entries that barely vary
    (e.g. vertices that never deform) do not amplify noise.

    Args:
        bound: target half-width of the normalised range.
        min_range_ratio: floor of an entry's range, relative to its channel's median range.
    """

    def __init__(self, bound: float = 0.95, min_range_ratio: float = 0.05):
        if bound <= 0:
            raise ValueError(f"bound={bound}: must be > 0")
        self.bound = float(bound)
        self.min_range_ratio = float(min_range_ratio)
        self.center: torch.Tensor | None = None  # (V, 9)
        self.half_range: torch.Tensor | None = None  # (V, 9)

    def fit(self, features: torch.Tensor) -> FeatureNormalizer:
        """Fit to features (N, V, 9); returns self."""
        lo = features.amin(0)
        hi = features.amax(0)
        rng = hi - lo  # (V, 9)
        floor = self.min_range_ratio * rng.median(dim=0).values.clamp_min(1e-12)  # (9,)
        rng = torch.maximum(rng, floor.expand_as(rng))
        self.center = 0.5 * (hi + lo)
        self.half_range = 0.5 * rng
        return self

    def _check(self) -> None:
        if self.center is None or self.half_range is None:
            raise RuntimeError("FeatureNormalizer is not fitted; call fit() or load_state_dict() first")

    def normalize(self, features: torch.Tensor) -> torch.Tensor:
        """(..., V, 9) features -> normalised (..., V, 9)."""
        self._check()
        c = self.center.to(features)
        h = self.half_range.to(features)
        return (features - c) / h * self.bound

    def denormalize(self, normalized: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`normalize`, differentiable."""
        self._check()
        c = self.center.to(normalized)
        h = self.half_range.to(normalized)
        return normalized / self.bound * h + c

    def state_dict(self) -> dict:
        self._check()
        return {"bound": self.bound, "min_range_ratio": self.min_range_ratio,
                "center": self.center.clone(), "half_range": self.half_range.clone()}

    def load_state_dict(self, state: dict) -> FeatureNormalizer:
        self.bound = float(state["bound"])
        self.min_range_ratio = float(state["min_range_ratio"])
        self.center = torch.as_tensor(state["center"])
        self.half_range = torch.as_tensor(state["half_range"])
        return self


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
        h = hashlib.sha1()
        h.update(verts.numpy().tobytes())
        h.update(dataset.faces.cpu().numpy().tobytes())
        h.update(json.dumps([reference_index, acap_kwargs], sort_keys=True).encode())
        cache = Path(cache_dir).expanduser() / f"acap_{h.hexdigest()[:16]}.npz"
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
