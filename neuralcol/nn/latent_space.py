"""A trained latent space: encoder, decoder to vertices, sub-domains, the sampling box Z and U(Z).

``LatentSpace.decode(Z_all (B, D)) -> vertices (B, V, 3)`` is batched, differentiable end to end (network,
feature de-normalisation, ACAP inverse) and keeps the device and dtype of its input.
"""

from __future__ import annotations

from pathlib import Path

import torch

from neuralcol.nn.autoencoder import BilevelAutoencoder, Level1Autoencoder, Level2Autoencoders
from neuralcol.nn.latent_box import LatentBox
from neuralcol.nn.normalizer import FeatureNormalizer
from neuralcol.nn.pca_space import PCALatentSpace
from neuralcol.utils.files import atomic_path
from neuralcol.utils.safe_files import plain_values, read_torch_file


class LatentSpace(LatentBox):
    """Trained bilevel autoencoder with everything needed to go from latent codes to meshes and back.

    Args:
        net: the trained bilevel autoencoder.
        normalizer: fitted feature normaliser.
        rest_vertices: (V, 3) ACAP rest mesh.
        faces: (F, 3) triangles.
        acap_kwargs: keyword arguments of :class:`ACAP`.
        box_lo, box_hi: (D,) the sampling box Z (paper sec. 4.1).
        partition: (V,) long sub-domain of each vertex (for PD_i).
        meta: JSON-able facts (config, errors, training time).
    """

    def __init__(self, net: BilevelAutoencoder, normalizer: FeatureNormalizer, rest_vertices, faces,
                 acap_kwargs: dict, box_lo: torch.Tensor, box_hi: torch.Tensor, partition: torch.Tensor,
                 meta: dict | None = None):
        super().__init__()
        self.net = net
        self._register_mesh_and_box(rest_vertices, faces, acap_kwargs, box_lo, box_hi, partition, meta)
        self.register_buffer("norm_center", normalizer.center.float().clone())
        self.register_buffer("norm_half_range", normalizer.half_range.float().clone())
        self.norm_bound = normalizer.bound

    # ------------------------------------------------------------------ facts
    @property
    def n_parts(self) -> int:
        """K = |Z_0| = number of sub-domains."""
        return self.net.level1.n_components

    def blocks(self) -> list[slice]:
        """Slices of Z_all: [Z_0, Z_1, ..., Z_K]."""
        k = self.n_parts
        out = [slice(0, k)]
        if self.net.level2 is not None:
            d = self.net.level2.latent_dim
            out += [slice(k + i * d, k + (i + 1) * d) for i in range(k)]
        return out

    # ------------------------------------------------------------------ maps
    def normalize(self, features: torch.Tensor) -> torch.Tensor:
        return (features - self.norm_center.to(features)) / self.norm_half_range.to(features) * self.norm_bound

    def denormalize(self, normalized: torch.Tensor) -> torch.Tensor:
        return normalized / self.norm_bound * self.norm_half_range.to(normalized) + self.norm_center.to(normalized)

    def encode(self, vertices: torch.Tensor) -> torch.Tensor:
        """Meshes (B, V, 3) -> Z_all (B, D)."""
        feats = self.acap.encode(vertices.detach().to(torch.float64)).to(self.box_lo.dtype)
        with torch.no_grad():
            return self.net.encode(self.normalize(feats.to(self.box_lo.device)))

    def decode_features(self, z_all: torch.Tensor) -> torch.Tensor:
        """Z_all (B, D) -> raw ACAP features (B, V, 9), differentiable."""
        return self.denormalize(self.net.decode(z_all))

    def decode(self, z_all: torch.Tensor) -> torch.Tensor:
        """Z_all (B, D) -> vertices (B, V, 3), differentiable, same dtype and device as ``z_all``."""
        if z_all.ndim != 2 or z_all.shape[1] != self.dim:
            raise ValueError(f"z_all has shape {tuple(z_all.shape)}, expected (B, {self.dim})")
        feats = self.decode_features(z_all.to(self.box_lo.dtype))
        return self.acap.decode(feats).to(z_all.dtype)

    def decode_vertices(self, z_all: torch.Tensor, idx) -> torch.Tensor:
        """Z_all (B, D) -> positions of the vertices ``idx`` only (B, K, 3): ``decode(z_all)[:, idx]`` to
        round-off, differentiable, one dense product on ``z_all``'s device instead of the sparse solve
        (:meth:`~neuralcol.geometry.acap.ACAP.decode_vertices`)."""
        if z_all.ndim != 2 or z_all.shape[1] != self.dim:
            raise ValueError(f"z_all has shape {tuple(z_all.shape)}, expected (B, {self.dim})")
        feats = self.decode_features(z_all.to(self.box_lo.dtype))
        return self.acap.decode_vertices(feats, idx).to(z_all.dtype)

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | Path) -> Path:
        """Save weights, normaliser, box, partition and the architecture to one file of tensors and plain values
        (it loads with ``weights_only=True``; :func:`~neuralcol.utils.safe_files.plain_values`)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        l1 = self.net.level1
        l2 = self.net.level2
        arch = {"n_vertices": l1.n_vertices, "n_components": l1.n_components, "hidden": l1.comp_in_w.shape[1],
                "activation": l1.activation,
                "level2": None if l2 is None else {"latent_dim": l2.latent_dim,
                                                    "hidden": l2.decoders[0][0].out_features}}
        facts = plain_values({"arch": arch, "acap_kwargs": self.acap_kwargs, "norm_bound": self.norm_bound,
                              "meta": self.meta}, path.name)
        blob = {**facts, "state": self.state_dict()}
        with atomic_path(path) as tmp:
            torch.save(blob, tmp)
        return path

    @classmethod
    def load(cls, path: str | Path, map_location="cpu") -> LatentSpace:
        """The latent space saved by :meth:`save`, read without unpickling code
        (:func:`~neuralcol.utils.safe_files.read_torch_file`).

        Raises:
            UnsafeFileError: the file holds pickled Python objects (not run) or is damaged; the message names it.
        """
        path = Path(path)
        blob = read_torch_file(path, map_location, fix=f"delete {path.parent} and run the command again "
                                                        "(the autoencoder is retrained into the cache)")
        if blob.get("kind") == "pca":  # autoencoder=pca
            return PCALatentSpace.from_blob(blob)
        arch, state = blob["arch"], blob["state"]
        l1 = Level1Autoencoder(arch["n_vertices"], arch["n_components"], arch["hidden"],
                               activation=arch.get("activation", "tanh"))
        l2 = None
        if arch["level2"] is not None:
            l2 = Level2Autoencoders(state["partition"], arch["n_components"], arch["level2"]["latent_dim"],
                                    arch["level2"]["hidden"])
        norm = FeatureNormalizer(bound=blob["norm_bound"])
        norm.center, norm.half_range = state["norm_center"], state["norm_half_range"]
        space = cls(BilevelAutoencoder(l1, l2), norm, state["rest_vertices"].numpy(), state["faces"].numpy(),
                    blob["acap_kwargs"], state["box_lo"], state["box_hi"], state["partition"], blob["meta"])
        space.load_state_dict(state)
        return space
