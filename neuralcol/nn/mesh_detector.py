"""A collision detector that reads the mesh (issue 27): contact-pair features -> MLP -> collision logit.

The paper's detector sees only the latent code, so on a user's mesh it judges the autoencoder's round trip,
not the mesh. :class:`MeshDetector` judges any mesh of the topology from :class:`ContactFeatures`
(distances and signed normal offsets of vertex pairs that come close in the data). Codes are judged through
the meshes they decode to (``neuralcol.handler.resolve.resolve_meshes`` differentiates it through the decoder).

Symbols: B batch, V vertices, D latent size, P contact pairs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from neuralcol.geometry.contact_pairs import ContactFeatures
from neuralcol.utils.files import atomic_path
from neuralcol.utils.safe_files import plain_values, read_torch_file


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


def decoded_batches(space, z: np.ndarray, batch: int = 256):
    """Yield the decoded meshes of ``z`` (N, D), ``batch`` at a time, as float32 CPU tensors."""
    zt = torch.as_tensor(np.asarray(z, np.float32))
    with torch.no_grad():
        for c in zt.split(batch):
            yield space.decode(c.to(space.box_lo.device)).cpu().float()


def mesh_features(features: ContactFeatures, meshes, batch: int = 256) -> np.ndarray:
    """(N, 3 P) float32 features of meshes given as an (N, V, 3) array or an iterable of (b, V, 3) batches."""
    if isinstance(meshes, np.ndarray) or torch.is_tensor(meshes):
        meshes = torch.as_tensor(np.asarray(meshes), dtype=torch.float32).split(batch)
    out = []
    with torch.no_grad():
        for m in meshes:
            out.append(features(torch.as_tensor(m, dtype=torch.float32)).numpy())
    return np.concatenate(out) if out else np.zeros((0, features.n_features), np.float32)


def code_logits(net: MeshDetector, space, z: np.ndarray, batch: int = 256) -> np.ndarray:
    """(N,) logits of the mesh detector on the meshes that codes decode to."""
    feats = mesh_features(net.features, decoded_batches(space, z, batch))
    return mesh_logits_from_features(net, feats)


def mesh_logits_from_features(net: MeshDetector, feats: np.ndarray, batch: int = 4096) -> np.ndarray:
    was = net.training
    net.eval()
    with torch.no_grad():
        x = torch.as_tensor(feats, dtype=torch.float32)
        out = [net.logit_from_features(c) for c in x.split(batch)]
    net.train(was)
    return torch.cat(out).double().numpy() if out else np.zeros(0)


def mesh_logits(net: MeshDetector, vertices: np.ndarray, batch: int = 256) -> np.ndarray:
    """(N,) logits of the mesh detector on meshes (N, V, 3)."""
    return mesh_logits_from_features(net, mesh_features(net.features, vertices, batch))


def save_mesh_detector(path: Path, net: MeshDetector) -> None:
    f = net.features
    blob = plain_values({"pairs": f.pairs.cpu(), "faces": f.faces.cpu(), "radius": f.radius, "clip": f.clip,
                         "hidden": net.hidden, "state": {k: v.cpu() for k, v in net.mlp.state_dict().items()}},
                        Path(path).name)
    with atomic_path(path) as tmp:
        torch.save(blob, tmp)


def load_mesh_detector(path: str | Path) -> MeshDetector:
    """The mesh detector saved by :func:`train_mesh_detector`, read without unpickling code
    (:func:`~neuralcol.utils.safe_files.read_torch_file`; a refused file raises ``UnsafeFileError`` naming it)."""
    blob = read_torch_file(path, "cpu", fix="re-create it with this version of neuralcol (run the run's command "
                                            "again in a new directory)")
    # the saved faces are already the ones around the pair vertices; ContactFeatures keeps them all
    feats = ContactFeatures(blob["pairs"].numpy(), blob["faces"].numpy(), float(blob["radius"]), float(blob["clip"]))
    net = MeshDetector(feats, hidden=int(blob["hidden"]))
    net.mlp.load_state_dict(blob["state"])
    return net.eval()
