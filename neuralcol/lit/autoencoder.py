"""Thin LightningModule training the bilevel autoencoder, one level per stage."""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
import torch.nn.functional as F

from neuralcol.lit.base import SplitStepModule
from neuralcol.nn.autoencoder import BilevelAutoencoder


class AutoencoderLitModule(SplitStepModule):
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
        code_noise: latent noise while training: the decoder reconstructs from ``z + code_noise * std(z) * e``
            (``e ~ N(0, 1)``, ``std`` per latent entry over the batch, not differentiated), so it has to be smooth
            at the scale of the codes' spread instead of switching between training codes. 0 turns it off. Applied
            to Z_0 in stage 1 and to the level-2 codes in stage 2; never at validation. See docs/autoencoder.md.
        interp_ratio: ACAP-feature interpolation while training: each training batch of B
            meshes gains ``ceil(interp_ratio * B)`` rows ``(1 - t) x_i + t x_j`` of two of its meshes, ``t ~
            U(interp_t)``, so the autoencoder also learns the poses between (and, for t outside [0, 1], slightly
            beyond) its training meshes, the meshes a user brings. The features are normalised by an affine map,
            so this is the interpolation of the raw ACAP features. 0 turns it off; never at validation.
        interp_t: (lo, hi) range of t.
    """

    def __init__(self, net: BilevelAutoencoder, stage: int, optimizer: Callable, scheduler: Callable | None = None,
                 edges: torch.Tensor | None = None, w_sparsity: float = 0.0, w_smoothness: float = 0.0,
                 w_balance: float = 0.0, code_noise: float = 0.0, interp_ratio: float = 0.0,
                 interp_t: tuple[float, float] = (0.0, 1.0)):
        super().__init__()
        if stage not in (1, 2):
            raise ValueError(f"stage={stage}: must be 1 or 2")
        if code_noise < 0:
            raise ValueError(f"code_noise={code_noise}: must be >= 0")
        if interp_ratio < 0:
            raise ValueError(f"interp_ratio={interp_ratio}: must be >= 0")
        interp_t = tuple(float(t) for t in interp_t)
        if len(interp_t) != 2 or not interp_t[0] <= interp_t[1]:
            raise ValueError(f"interp_t={interp_t}: must be [lo, hi] with lo <= hi")
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

    def _noisy(self, z: torch.Tensor, split: str) -> torch.Tensor:
        """(B, D) codes plus latent noise while training (identity at validation or with code_noise = 0)."""
        sigma = float(self.hparams.code_noise)
        if split != "train" or sigma == 0.0 or z.shape[0] < 2:
            return z
        std = z.detach().std(0, keepdim=True)  # (1, D)
        return z + sigma * std * torch.randn_like(z)

    def _interpolated(self, x: torch.Tensor, split: str) -> torch.Tensor:
        """(B, ...) training features plus ``ceil(interp_ratio * B)`` interpolations of random pairs of them."""
        ratio = float(self.hparams.interp_ratio)
        if split != "train" or ratio == 0.0 or x.shape[0] < 2:
            return x
        n, m = x.shape[0], math.ceil(ratio * x.shape[0])
        i = torch.randint(n, (m,), device=x.device)
        j = (i + torch.randint(1, n, (m,), device=x.device)) % n  # j != i
        lo, hi = self.hparams.interp_t
        t = (lo + (hi - lo) * torch.rand(m, device=x.device, dtype=x.dtype)).view(-1, *([1] * (x.dim() - 1)))
        return torch.cat([x, (1 - t) * x[i] + t * x[j]], 0)

    def step(self, batch, split: str) -> torch.Tensor:
        (x,) = batch
        x = self._interpolated(x, split)
        if self.stage == 1:
            recon = self.net.level1.decode(self._noisy(self.net.level1.encode(x), split))
            mse = F.mse_loss(recon, x)
            pri = self.attention_priors()
            loss = (mse + self.hparams.w_sparsity * pri["entropy"] + self.hparams.w_smoothness * pri["smoothness"]
                    + self.hparams.w_balance * pri["balance"])
            for name, val in pri.items():
                self.log(f"{split}/{name}", val, on_epoch=True, on_step=False)
        else:
            z = self.net.encode(x)
            k = self.net.level1.n_components
            recon = self.net.decode(torch.cat([z[:, :k], self._noisy(z[:, k:], split)], dim=1))
            mse = F.mse_loss(recon, x)
            loss = mse
        self.log(f"{split}/mse", mse, on_epoch=True, on_step=False, prog_bar=split == "train")
        self.log(f"{split}/loss", loss, on_epoch=True, on_step=False)
        return loss

    def configure_optimizers(self):
        params = [p for p in self.net.parameters() if p.requires_grad]
        opt = self.hparams.optimizer(params=params)
        if self.hparams.scheduler is None:
            return opt
        return {"optimizer": opt, "lr_scheduler": {"scheduler": self.hparams.scheduler(optimizer=opt),
                                                    "interval": "epoch"}}
