"""Thin LightningModule training the neural collision detector with the loss of paper sec. 4.3."""

from __future__ import annotations

from collections.abc import Callable

import torch

from neuralcol.lit.base import SplitStepModule
from neuralcol.nn.detector import CollisionDetector, detector_losses
from neuralcol.nn.inference import batched_logits
from neuralcol.nn.part_geometry import DetectorOnCodes


class DetectorLitModule(SplitStepModule):
    """Trains a :class:`~neuralcol.nn.detector.CollisionDetector` on batches ``(z, pd, pd_sub, subset)`` (and the
    rows' pair features as a fifth tensor for a detector that reads the mesh too).

    Args:
        net: the detector.
        optimizer: partial of a torch optimizer taking ``(params, lr=...)`` (``detector.optimizer``).
        lr: its learning rate (changed between rounds with :meth:`set_lr`).
        w_pd, w_pdsum, w_r, w_ce, w_b: loss weights (paper: 5, 0.2, 2, 2, 0.5; ``supv`` uses w_b = 0).
        margin: ranking margin alpha (in PD target units).
        temperature: smooth-max temperature of the aggregated depth (PD target units).
        ce_on_boundary: cross-entropy on the D_b rows too (see :func:`~neuralcol.nn.detector.detector_losses`).
        boundary_reduction: how L_b averages its D_b rows, "boundary" (paper) or "batch" (same function).
        space: the latent space of the codes; needed by a detector that reads the mesh too, whose
            answers on codes alone (:attr:`on_codes`: the test set, the acquisition, the handler) decode the
            vertices its pair features read. Training reads the features D_c stores.
    """

    def __init__(self, net: CollisionDetector, optimizer: Callable, lr: float, w_pd: float, w_pdsum: float,
                 w_r: float, w_ce: float,
                 w_b: float, margin: float, temperature: float, ce_on_boundary: bool = False,
                 boundary_reduction: str = "boundary", space=None):
        super().__init__()
        self.save_hyperparameters(ignore=["net", "optimizer", "space"])
        self.net = net
        self._space = (space,)  # a tuple: not a submodule (the latent space is not trained here)
        if net.geometry is not None and space is None:
            raise ValueError("DetectorLitModule: a detector that reads the mesh needs the latent space (space=)")
        self.optimizer = optimizer
        self.lr = float(lr)
        self._sums: dict = {}  # split -> (weighted sums of the logged values, rows) of the running epoch
        self.loss_kwargs = dict(w_pd=w_pd, w_pdsum=w_pdsum, w_r=w_r, w_ce=w_ce, w_b=w_b, margin=margin,
                                temperature=temperature, ce_on_boundary=bool(ce_on_boundary),
                                boundary_reduction=str(boundary_reduction))

    @property
    def on_codes(self) -> torch.nn.Module:
        """The detector as a function of codes alone (:class:`~neuralcol.nn.part_geometry.DetectorOnCodes`)."""
        return DetectorOnCodes(self.net, self._space[0])

    def forward(self, z: torch.Tensor):
        return self.on_codes(z)

    LOGGED = ("loss", "loss_pd", "loss_rank", "loss_ce", "loss_b", "accuracy")  # ``<split>/<name>``, epoch means

    def training_step(self, batch, batch_idx):
        return self.step(batch, "train", batch_idx)

    def validation_step(self, batch, batch_idx):
        self.step(batch, "val", batch_idx)

    def step(self, batch, split: str, batch_idx: int | None = None) -> torch.Tensor:
        z, pd, pd_sub, subset, *geometry = batch  # geometry: the rows' pair features, for a detector reading them
        out = self.net(z, *geometry)
        losses = detector_losses(out, pd, pd_sub, subset, **self.loss_kwargs)
        acc = ((out.logit > 0) == (pd > 0)).float().mean()
        self._accumulate(split, torch.stack([losses.total, losses.pd, losses.rank, losses.ce, losses.boundary, acc]),
                         len(z), batch_idx)
        return losses.total

    def _accumulate(self, split: str, values: torch.Tensor, bs: int, batch_idx: int | None) -> None:
        """Add one batch's logged values (weighted by its rows) to the epoch's sums (restarted at batch 0); on the
        epoch's last batch log their means (what ``log(..., on_epoch=True, batch_size=bs)`` of every batch gives, up
        to round-off). One ``log_dict`` an epoch instead of six ``log`` calls a step: Lightning's per-call
        bookkeeping was about a third of a training step of the SCAPE detector. Where the epoch's batch
        count is unknown (or no batch index is given), every batch logs its own values."""
        n_batches = self._batches_in_epoch(split)
        if batch_idx is None or n_batches is None:
            self.log_dict({f"{split}/{k}": v for k, v in zip(self.LOGGED, values)}, on_step=False, on_epoch=True,
                          batch_size=bs)
            return
        sums, rows = (0.0, 0) if batch_idx == 0 else self._sums[split]
        sums, rows = values.detach() * bs + sums, rows + bs
        self._sums[split] = (sums, rows)
        if batch_idx + 1 >= n_batches:  # the epoch's last batch
            self.log_dict({f"{split}/{k}": v for k, v in zip(self.LOGGED, (sums / rows).tolist())}, on_step=False,
                          on_epoch=True, batch_size=1)

    def _batches_in_epoch(self, split: str) -> int | None:
        """Batches of this epoch's ``split`` (None where the trainer does not know)."""
        if self._trainer is None:
            return None
        n = self.trainer.num_training_batches if split == "train" else sum(self.trainer.num_val_batches or [0])
        return int(n) if n not in (None, float("inf")) and n > 0 else None

    def configure_optimizers(self):
        return self.optimizer(self.net.parameters(), lr=self.lr)

    def set_lr(self, lr: float) -> None:
        """Set the learning rate of the running optimizer (and of the next one configured)."""
        self.lr = float(lr)
        if self._trainer is not None:
            for opt in self.trainer.optimizers:
                for group in opt.param_groups:
                    group["lr"] = self.lr

    def reinitialize(self, seed: int) -> None:
        """Fresh weights (seeded) and a fresh optimizer state: training from scratch inside a running fit."""
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            for m in self.net.modules():
                if hasattr(m, "reset_parameters"):
                    m.reset_parameters()
        if self._trainer is not None:
            for opt in self.trainer.optimizers:
                opt.state.clear()

    def predict_logits(self, z: torch.Tensor, batch: int = 65536) -> torch.Tensor:
        """Logits of many codes (B,), evaluated in batches on the module's device, returned on the CPU."""
        return batched_logits(self.on_codes, z, batch=batch, mode_of=self.net)


def detector_module(net: CollisionDetector, det: dict, w_b: float, lr: float, space=None) -> DetectorLitModule:
    """The LightningModule of ``det`` (``conf/detector``: its ``optimizer`` and ``loss``) around ``net``
    (``space``: the latent space, for a detector that reads the mesh too)."""
    from hydra.utils import instantiate

    return DetectorLitModule(net, optimizer=instantiate(det["optimizer"]), lr=lr, w_b=float(w_b), space=space,
                             **det["loss"])
