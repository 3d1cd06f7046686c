"""Thin LightningModule training the bilevel autoencoder, one level per stage."""

from __future__ import annotations

from collections.abc import Callable

import lightning as L
import torch
import torch.nn.functional as F

from neuralcol.nn.autoencoder import BilevelAutoencoder


class AutoencoderLitModule(L.LightningModule):
    """Trains level 1 (``stage=1``) or level 2 with level 1 frozen (``stage=2``) of a bilevel autoencoder.

    Stage-1 loss: ``mse + w_sparsity * H(A) + w_smoothness * mean_edges |A_i - A_j|^2 + w_balance * KL``,
    with H the mean per-vertex entropy of the attention A (K, V), the smoothness over mesh edges, and KL
    the divergence of the components' mean attention from uniform (keeps every component in use).
    Stage-2 loss: reconstruction mse of ``D_0(Z_0) + sum_k D_k(Z_k)``.

    Args:
        net: the bilevel autoencoder (``net.level2`` must exist for stage 2).
        stage: 1 or 2.
        optimizer: partial of a torch optimizer (``_partial_: true`` in the config).
        scheduler: partial of a LR scheduler, or None.
        edges: (E, 2) long mesh edges for the smoothness prior.
        w_sparsity, w_smoothness, w_balance: prior weights (stage 1).
    """

    def __init__(self, net: BilevelAutoencoder, stage: int, optimizer: Callable, scheduler: Callable | None = None,
                 edges: torch.Tensor | None = None, w_sparsity: float = 0.0, w_smoothness: float = 0.0,
                 w_balance: float = 0.0):
        super().__init__()
        if stage not in (1, 2):
            raise ValueError(f"stage={stage}: must be 1 or 2")
        if stage == 2 and net.level2 is None:
            raise ValueError("stage 2 needs net.level2")
        self.save_hyperparameters(ignore=["net", "edges"])
        self.net = net
        self.stage = stage
        self.register_buffer("edges", torch.zeros(0, 2, dtype=torch.long) if edges is None else edges.long())
        if stage == 2:
            self.net.level1.requires_grad_(False)

    def attention_priors(self) -> dict[str, torch.Tensor]:
        att = self.net.level1.attention()  # (K, V)
        entropy = -(att * torch.log(att.clamp_min(1e-12))).sum(0).mean()
        if self.edges.numel():
            smooth = ((att[:, self.edges[:, 0]] - att[:, self.edges[:, 1]]) ** 2).sum(0).mean()
        else:
            smooth = att.new_zeros(())
        usage = att.mean(1)  # (K,)
        k = usage.numel()
        balance = (torch.full_like(usage, 1.0 / k) * torch.log((1.0 / k) / usage.clamp_min(1e-12))).sum()
        return {"entropy": entropy, "smoothness": smooth, "balance": balance}

    def step(self, batch, split: str) -> torch.Tensor:
        (x,) = batch
        if self.stage == 1:
            _, recon = self.net.level1(x)
            mse = F.mse_loss(recon, x)
            pri = self.attention_priors()
            loss = (mse + self.hparams.w_sparsity * pri["entropy"] + self.hparams.w_smoothness * pri["smoothness"]
                    + self.hparams.w_balance * pri["balance"])
            for name, val in pri.items():
                self.log(f"{split}/{name}", val, on_epoch=True, on_step=False)
        else:
            recon = self.net.decode(self.net.encode(x))
            mse = F.mse_loss(recon, x)
            loss = mse
        self.log(f"{split}/mse", mse, on_epoch=True, on_step=False, prog_bar=split == "train")
        self.log(f"{split}/loss", loss, on_epoch=True, on_step=False)
        return loss

    def training_step(self, batch, batch_idx):
        return self.step(batch, "train")

    def validation_step(self, batch, batch_idx):
        self.step(batch, "val")

    def configure_optimizers(self):
        params = [p for p in self.net.parameters() if p.requires_grad]
        opt = self.hparams.optimizer(params=params)
        if self.hparams.scheduler is None:
            return opt
        return {"optimizer": opt, "lr_scheduler": {"scheduler": self.hparams.scheduler(optimizer=opt),
                                                    "interval": "epoch"}}
