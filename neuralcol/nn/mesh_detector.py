"""A collision detector that reads the mesh (issue 27): contact-pair features -> MLP -> collision logit.

The paper's detector sees only the latent code, so on a user's mesh it judges the autoencoder's round trip,
not the mesh. :class:`MeshDetector` judges any mesh of the topology from :class:`ContactFeatures`
(distances and signed normal offsets of vertex pairs that come close in the data). :class:`DecodedMeshDetector`
composes it with the latent space's decoder, so codes can be judged (and differentiated) through the mesh
they decode to.

Symbols: B batch, V vertices, D latent size, P contact pairs.
"""

from __future__ import annotations

import torch
from torch import nn

from neuralcol.geometry.contact_pairs import ContactFeatures


class MeshDetector(nn.Module):
    """(B, V, 3) meshes -> (B,) collision logits.

    Args:
        features: the contact-pair features.
        hidden: width of the two hidden layers.
    """

    def __init__(self, features: ContactFeatures, hidden: int = 256):
        super().__init__()
        self.features = features
        n = features.n_features
        self.mlp = nn.Sequential(nn.Linear(n, hidden), nn.SiLU(), nn.Linear(hidden, hidden), nn.SiLU(),
                                 nn.Linear(hidden, 1))
        self.hidden = int(hidden)

    def logit_from_features(self, feats: torch.Tensor) -> torch.Tensor:
        """(B, 3 P) features -> (B,) logits."""
        return self.mlp(feats)[:, 0]

    def forward(self, vertices: torch.Tensor) -> torch.Tensor:
        """(B, V, 3) or (V, 3) meshes -> (B,) logits (> 0: collides)."""
        return self.logit_from_features(self.features(vertices.to(self.mlp[0].weight.dtype)))


class DecodedMeshDetector(nn.Module):
    """Codes judged through their decoded meshes: ``logit(Z) = MeshDetector(D(Z))`` (differentiable).

    ``forward`` returns an object with ``.logit`` like :class:`~neuralcol.nn.detector.CollisionDetector`, so
    the handler can use it as its constraint.
    """

    def __init__(self, space, detector: MeshDetector):
        super().__init__()
        self.space, self.detector = space, detector

    def forward(self, z: torch.Tensor):
        from types import SimpleNamespace

        logit = self.detector(self.space.decode(z.to(self.space.box_lo.dtype)).to(z.dtype))
        return SimpleNamespace(logit=logit, prob=torch.sigmoid(logit))
