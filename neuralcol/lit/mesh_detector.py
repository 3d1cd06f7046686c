"""Thin LightningModule training the mesh-reading detector on precomputed contact features (BCE)."""

from __future__ import annotations

import lightning as L
import torch
import torch.nn.functional as F

from neuralcol.nn.mesh_detector import MeshDetector


class MeshDetectorLitModule(L.LightningModule):
    """Trains :class:`MeshDetector` on batches ``(features (B, 3 P), collides (B,))``.

    Args:
        net: the detector. lr: Adam learning rate. weight_decay: Adam weight decay.
        pos_weight: weight of the colliding rows in the cross-entropy (None: 1).
    """

    def __init__(self, net: MeshDetector, lr: float, weight_decay: float = 0.0, pos_weight: float | None = None):
        super().__init__()
        self.save_hyperparameters(ignore=["net"])
        self.net = net
        self.lr, self.weight_decay = float(lr), float(weight_decay)
        self.pos_weight = None if pos_weight is None else float(pos_weight)

    def _step(self, batch, split: str) -> torch.Tensor:
        feats, y = batch
        logit = self.net.logit_from_features(feats)
        pw = None if self.pos_weight is None else torch.as_tensor(self.pos_weight, device=logit.device)
        loss = F.binary_cross_entropy_with_logits(logit, y.float(), pos_weight=pw)
        acc = ((logit > 0) == y.bool()).float().mean()
        self.log(f"{split}/mesh_loss", loss, prog_bar=False, on_epoch=True, on_step=False)
        self.log(f"{split}/mesh_accuracy", acc, prog_bar=False, on_epoch=True, on_step=False)
        return loss

    def training_step(self, batch, batch_idx):
        return self._step(batch, "train")

    def validation_step(self, batch, batch_idx):
        self._step(batch, "val")

    def configure_optimizers(self):
        return torch.optim.Adam(self.net.parameters(), lr=self.lr, weight_decay=self.weight_decay)
