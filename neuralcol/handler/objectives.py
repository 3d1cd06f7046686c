"""Objectives E of the collision handler (paper sec. 3.3). Each is called as ``E(z, idx)``: the codes z
(len(idx), D) of the problems ``idx`` (indices into the batch of B problems) -> (len(idx),) values."""

from __future__ import annotations

import torch

from neuralcol.nn.latent_space import LatentSpace


class LatentObjective:
    """``E(Z) = |Z - Z_user|^2 / 2`` (stay close to the user's code). z_user: (B, D)."""

    def __init__(self, z_user: torch.Tensor):
        self.z_user = z_user.detach()

    def __call__(self, z: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        return 0.5 * ((z - self.z_user[idx].to(z)) ** 2).sum(-1)


class CartesianObjective:
    """``E(Z) = |ACAP^-1(D(Z))[S] - V_user[S]|^2 / 2`` over a vertex subset S (all vertices by default): reach
    target positions in space, e.g. place a hand. v_user: (B, V, 3) or (V, 3) for every problem."""

    def __init__(self, space: LatentSpace, v_user: torch.Tensor, vertices: torch.Tensor | None = None):
        v = torch.as_tensor(v_user)
        self.v_user = (v[None] if v.ndim == 2 else v).detach()
        if self.v_user.shape[1:] != (space.acap.n_vertices, 3):
            raise ValueError(f"v_user has shape {tuple(v.shape)}, expected (B, {space.acap.n_vertices}, 3)")
        self.space = space
        self.vertices = None if vertices is None else torch.as_tensor(vertices, dtype=torch.long)

    def __call__(self, z: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        verts = self.space.decode(z)  # (b, V, 3)
        target = self.v_user[idx if len(self.v_user) > 1 else torch.zeros_like(idx)].to(verts)
        diff = verts - target
        if self.vertices is not None:
            diff = diff[:, self.vertices]
        return 0.5 * (diff ** 2).sum((-1, -2))
