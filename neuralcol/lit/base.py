"""What every neuralcol LightningModule shares: one ``step(batch, split)`` for training and validation."""

from __future__ import annotations

import lightning as L
import torch


class SplitStepModule(L.LightningModule):
    """A LightningModule whose training and validation steps are one :meth:`step` (``split`` names the logs)."""

    def step(self, batch, split: str) -> torch.Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def training_step(self, batch, batch_idx):
        return self.step(batch, "train")

    def validation_step(self, batch, batch_idx):
        self.step(batch, "val")
