"""Bilevel mesh autoencoder (paper sec. 3.1) as plain torch modules.

Symbols: B batch, V vertices, K = |Z_0| level-1 components (= sub-domains), d level-2 latent size per
component, F = 9 ACAP feature channels. Features are the *normalised* ACAP features (see
:class:`neuralcol.nn.normalizer.FeatureNormalizer`).

Level 1 (Yang et al. 2020, attention-based deformation components): a linear encoder maps the features to
``Z_0 (B, K)``; the decoder adds K deformation components, each a small MLP of one latent scalar,
``g_k(z_k) (B, V, F)``, masked per vertex by an attention ``A (K, V)`` (softmax over k, so every vertex
distributes one unit of attention over the components). A sparsity prior (low per-vertex entropy of A) and
a smoothness prior (attention varies little across mesh edges) make each component drive one localised
region; ``argmax_k A[:, v]`` is vertex v's sub-domain.

Level 2: one small autoencoder per component, on the level-1 residual restricted to its sub-domain,
latent ``Z_k (B, d)``; its decoder writes only into its sub-domain. ``D(Z_all) = D_0(Z_0) + sum_k D_k(Z_k)``.
"""

from __future__ import annotations

import warnings

import torch
from torch import nn

FEATURE_CHANNELS = 9


class Level1Autoencoder(nn.Module):
    """Level-1 autoencoder with attention-masked deformation components.

    Args:
        n_vertices: V.
        n_components: K = |Z_0|.
        hidden: hidden width of each component MLP (1 -> hidden -> V*F).
        attention_init: (K, V) initial attention logits (e.g. from a spatial clustering), or None for zeros.
        activation: ``"tanh"`` (component = ``W_out tanh(z w + b)``) or ``"linear"`` (``W_out (z w + b)``, a
            linear deformation component: decoded features change at the same rate over the whole code range).
    """

    ACTIVATIONS = ("tanh", "linear")

    def __init__(self, n_vertices: int, n_components: int, hidden: int = 4,
                 attention_init: torch.Tensor | None = None, activation: str = "tanh"):
        super().__init__()
        if activation not in self.ACTIVATIONS:
            raise ValueError(f"activation={activation!r}; use one of {self.ACTIVATIONS}")
        self.activation = activation
        self.n_vertices = n_vertices
        self.n_components = n_components
        width = n_vertices * FEATURE_CHANNELS
        self.encoder = nn.Linear(width, n_components)
        self.comp_in_w = nn.Parameter(torch.randn(n_components, hidden) * 0.5)
        self.comp_in_b = nn.Parameter(torch.zeros(n_components, hidden))
        self.comp_out = nn.Parameter(torch.randn(n_components, hidden, width) * (0.1 / hidden))
        self.bias = nn.Parameter(torch.zeros(n_vertices, FEATURE_CHANNELS))
        logits = torch.zeros(n_components, n_vertices) if attention_init is None else attention_init.clone()
        if logits.shape != (n_components, n_vertices):
            raise ValueError(f"attention_init has shape {tuple(logits.shape)}, expected ({n_components}, {n_vertices})")
        self.attention_logits = nn.Parameter(logits.float())

    def attention(self) -> torch.Tensor:
        """(K, V) attention, softmax over components."""
        return torch.softmax(self.attention_logits, dim=0)

    def encode(self, features: torch.Tensor) -> torch.Tensor:
        """(B, V, F) normalised features -> Z_0 (B, K)."""
        return self.encoder(features.flatten(1))

    def components(self, z0: torch.Tensor) -> torch.Tensor:
        """Unmasked component outputs g_k(z_k): (B, K) -> (B, K, V, F)."""
        h = z0[..., None] * self.comp_in_w + self.comp_in_b  # (B, K, H)
        if self.activation == "tanh":
            h = torch.tanh(h)
        out = torch.einsum("bkh,khw->bkw", h, self.comp_out)  # (B, K, V*F)
        return out.view(z0.shape[0], self.n_components, self.n_vertices, FEATURE_CHANNELS)

    def decode(self, z0: torch.Tensor) -> torch.Tensor:
        """Z_0 (B, K) -> normalised features (B, V, F)."""
        att = self.attention()  # (K, V)
        return self.bias + (att[None, :, :, None] * self.components(z0)).sum(1)

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        z0 = self.encode(features)
        return z0, self.decode(z0)


class Level2Autoencoders(nn.Module):
    """K small autoencoders, one per sub-domain, on the level-1 residual of that sub-domain.

    Args:
        partition: (V,) long sub-domain of each vertex, values in [0, K).
        n_components: K.
        latent_dim: d, latent size per sub-domain.
        hidden: hidden width of each decoder (d -> hidden -> V_k*F).
    """

    def __init__(self, partition: torch.Tensor, n_components: int, latent_dim: int = 2, hidden: int = 16):
        super().__init__()
        partition = torch.as_tensor(partition, dtype=torch.long)
        self.n_components = n_components
        self.latent_dim = latent_dim
        self.n_vertices = int(partition.numel())
        self.register_buffer("partition", partition.clone())
        self.encoders = nn.ModuleList()
        self.decoders = nn.ModuleList()
        for k in range(n_components):
            idx = torch.nonzero(partition == k).flatten()
            self.register_buffer(f"index_{k}", idx)
            width = max(1, int(idx.numel())) * FEATURE_CHANNELS
            with warnings.catch_warnings():  # latent_dim 0 (no level-2 code): torch warns on empty weights
                warnings.filterwarnings("ignore", message="Initializing zero-element tensors")
                self.encoders.append(nn.Linear(width, latent_dim))
                dec = nn.Sequential(nn.Linear(latent_dim, hidden), nn.Tanh(), nn.Linear(hidden, width))
            nn.init.zeros_(dec[-1].weight)
            nn.init.zeros_(dec[-1].bias)
            self.decoders.append(dec)

    def index(self, k: int) -> torch.Tensor:
        return getattr(self, f"index_{k}")

    def encode(self, residual: torch.Tensor) -> torch.Tensor:
        """(B, V, F) residual -> (B, K*d) level-2 codes [Z_1, ..., Z_K]."""
        codes = []
        for k, enc in enumerate(self.encoders):
            idx = self.index(k)
            part = residual[:, idx].flatten(1) if idx.numel() else residual.new_zeros(residual.shape[0], 9)
            codes.append(enc(part))
        return torch.cat(codes, dim=1)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """(B, K*d) -> (B, V, F) residual, each sub-domain written by its own decoder."""
        out = z.new_zeros(z.shape[0], self.n_vertices, FEATURE_CHANNELS)
        for k, dec in enumerate(self.decoders):
            idx = self.index(k)
            if idx.numel() == 0:
                continue
            zk = z[:, k * self.latent_dim:(k + 1) * self.latent_dim]
            out = out.index_add(1, idx, dec(zk).view(z.shape[0], idx.numel(), FEATURE_CHANNELS))
        return out


class BilevelAutoencoder(nn.Module):
    """Level 1 + level 2: ``Z_all = [Z_0, Z_1, ..., Z_K]``, ``D(Z_all) = D_0(Z_0) + sum_k D_k(Z_k)``.

    Args:
        level1: trained (or training) level-1 autoencoder.
        level2: level-2 autoencoders built on level-1's sub-domains (None before stage 2).
    """

    def __init__(self, level1: Level1Autoencoder, level2: Level2Autoencoders | None = None):
        super().__init__()
        self.level1 = level1
        self.level2 = level2

    @property
    def latent_dim(self) -> int:
        extra = 0 if self.level2 is None else self.level2.n_components * self.level2.latent_dim
        return self.level1.n_components + extra

    def encode(self, features: torch.Tensor) -> torch.Tensor:
        """(B, V, F) normalised features -> Z_all (B, D)."""
        z0 = self.level1.encode(features)
        if self.level2 is None:
            return z0
        residual = features - self.level1.decode(z0)
        return torch.cat([z0, self.level2.encode(residual)], dim=1)

    def decode(self, z_all: torch.Tensor) -> torch.Tensor:
        """Z_all (B, D) -> normalised features (B, V, F), differentiable."""
        k = self.level1.n_components
        out = self.level1.decode(z_all[:, :k])
        if self.level2 is not None:
            out = out + self.level2.decode(z_all[:, k:])
        return out
