"""Per-entry normalisation of ACAP features for the autoencoder; part of the latent space (saved with it)."""

from __future__ import annotations

import torch


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
