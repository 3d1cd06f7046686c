"""A collision detector that reads the mesh (issue 27): contact-pair features -> MLP -> collision logit.

The paper's detector sees only the latent code, so on a user's mesh it judges the autoencoder's round trip,
not the mesh. :class:`MeshDetector` judges any mesh of the topology from :class:`ContactFeatures`
(distances and signed normal offsets of vertex pairs that come close in the data). Codes are judged through
the meshes they decode to (``neuralcol.stages.handling.resolve_meshes`` differentiates it through the decoder).

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
