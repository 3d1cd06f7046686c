"""Thin LightningModule training the mesh-reading detector on precomputed contact features (BCE)."""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F

from neuralcol.lit.base import SplitStepModule
from neuralcol.nn.mesh_detector import MeshDetector


class MeshDetectorLitModule(SplitStepModule):
    """Trains :class:`MeshDetector` on batches ``(features (B, 3 P), collides (B,))``.

    Args:
        net: the detector. optimizer: partial of a torch optimizer taking the parameters
            (``mesh_detector.train.optimizer``).
        pos_weight: weight of the colliding rows in the cross-entropy (None: 1).
    """

    def __init__(self, net: MeshDetector, optimizer: Callable, pos_weight: float | None = None):
        super().__init__()
        self.save_hyperparameters(ignore=["net", "optimizer"])
        self.net = net
        self.optimizer = optimizer
        self.pos_weight = None if pos_weight is None else float(pos_weight)

    def step(self, batch, split: str) -> torch.Tensor:
        feats, y = batch
        logit = self.net.logit_from_features(feats)
        pw = None if self.pos_weight is None else torch.as_tensor(self.pos_weight, device=logit.device)
        loss = F.binary_cross_entropy_with_logits(logit, y.float(), pos_weight=pw)
        acc = ((logit > 0) == y.bool()).float().mean()
        self.log(f"{split}/mesh_loss", loss, prog_bar=False, on_epoch=True, on_step=False)
        self.log(f"{split}/mesh_accuracy", acc, prog_bar=False, on_epoch=True, on_step=False)
        return loss

    def configure_optimizers(self):
        return self.optimizer(self.net.parameters())
