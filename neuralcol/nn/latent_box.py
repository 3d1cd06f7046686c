"""What every latent space shares: the box Z (``box_lo``, ``box_hi`` buffers), U(Z) and |Z_all|.

:class:`~neuralcol.nn.latent_space.LatentSpace` (the bilevel autoencoder's) and
:class:`~neuralcol.nn.pca_space.PCALatentSpace` (``autoencoder=pca``) derive from it.
"""

from __future__ import annotations

import copy

import numpy as np
import torch
from torch import nn

from neuralcol.geometry.acap import ACAP


class LatentBox(nn.Module):
    """Base of the latent spaces: subclasses register ``box_lo`` and ``box_hi`` (D,) float32 buffers."""

    box_lo: torch.Tensor
    box_hi: torch.Tensor

    def _register_mesh_and_box(self, rest_vertices, faces, acap_kwargs: dict, box_lo: torch.Tensor,
                               box_hi: torch.Tensor, partition, meta: dict | None) -> None:
        """What every latent space holds: the ACAP transform of its rest mesh, rest mesh (V, 3) and faces (F, 3),
        the box (D,) and the sub-domain of each vertex (V,), and its JSON-able facts."""
        self.acap_kwargs = dict(acap_kwargs)
        self.acap = ACAP(rest_vertices, faces, **self.acap_kwargs)
        self.register_buffer("rest_vertices", torch.as_tensor(np.asarray(rest_vertices), dtype=torch.float64))
        self.register_buffer("faces", torch.as_tensor(np.asarray(faces), dtype=torch.long))
        self.register_buffer("box_lo", box_lo.float().clone())
        self.register_buffer("box_hi", box_hi.float().clone())
        self.register_buffer("partition", torch.as_tensor(partition, dtype=torch.long).clone())
        self.meta = dict(meta or {})

    @property
    def dim(self) -> int:
        """D = |Z_all|."""
        return int(self.box_lo.numel())

    def sample(self, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """n codes from U(Z), (n, D) float32 on the box's device."""
        u = torch.rand(n, self.dim, generator=generator, device=self.box_lo.device)
        return self.box_lo + u * (self.box_hi - self.box_lo)

    def outside_box(self, z_all: torch.Tensor) -> torch.Tensor:
        """(B,) bool: the code lies outside the box Z in some entry. The detector trains on codes from Z (U(Z) and
        the projections into it); outside it extrapolates, which is where most codes of unseen meshes land
        (64 % of SCAPE's realistic meshes, 99 % of proc_hand's)."""
        lo, hi = self.box_lo.to(z_all), self.box_hi.to(z_all)
        return ((z_all < lo) | (z_all > hi)).any(-1)


def with_box(space, lo: torch.Tensor, hi: torch.Tensor):
    """A latent space like ``space`` with the box ``[lo, hi]`` ((D,) each, cast to the box's dtype and device); every
    other part (networks, ACAP transform, mesh, sub-domains) is shared, and ``space`` itself is unchanged. Works on
    any object with ``box_lo``/``box_hi`` attributes; a module gets its own buffer table, so the two boxes never
    alias."""
    other = copy.copy(space)
    if isinstance(space, nn.Module):
        other._buffers = dict(space._buffers)
    other.box_lo = torch.as_tensor(lo).to(space.box_lo).clone()
    other.box_hi = torch.as_tensor(hi).to(space.box_hi).clone()
    return other
