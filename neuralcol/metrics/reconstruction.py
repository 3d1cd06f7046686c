"""Vertex-space reconstruction errors (pure functions)."""

from __future__ import annotations

from typing import NamedTuple

import torch


class ReconstructionError(NamedTuple):
    """Per-mesh vertex errors relative to the bounding-box diagonal of the target mesh.

    Attributes:
        mean: (B,) mean over vertices of |pred - target| / diag.
        max: (B,) max over vertices of the same.
    """

    mean: torch.Tensor
    max: torch.Tensor


def relative_vertex_error(pred: torch.Tensor, target: torch.Tensor, remove_translation: bool = True
                          ) -> ReconstructionError:
    """Vertex error of ``pred`` against ``target`` in units of the target's bounding-box diagonal.

    Args:
        pred: (B, V, 3) float.
        target: (B, V, 3) float.
        remove_translation: align centroids first (ACAP and the autoencoder do not encode translation).

    Returns:
        ReconstructionError with (B,) mean and max errors.
    """
    if pred.shape != target.shape:
        raise ValueError(f"pred {tuple(pred.shape)} and target {tuple(target.shape)} differ in shape")
    if remove_translation:
        pred = pred - pred.mean(-2, keepdim=True)
        target = target - target.mean(-2, keepdim=True)
    diag = (target.amax(-2) - target.amin(-2)).norm(dim=-1)  # (B,)
    err = (pred - target).norm(dim=-1) / diag[..., None]  # (B, V)
    return ReconstructionError(err.mean(-1), err.amax(-1))
