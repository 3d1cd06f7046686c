"""``training``: seconds per epoch of the SCAPE autoencoder and of the detector (CPU presets).
:func:`ae_epoch_seconds` and :func:`detector_epoch_seconds` are shared with the GPU kit (``bench.gpu_check``)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bench.context import BenchContext
from bench.timing import repeat, summarize

if TYPE_CHECKING:
    from neuralcol.nn.latent_space import LatentSpace


def ae_epoch_seconds(ds, feats, ae: dict, latent: dict, epochs: tuple[int, int],
                     reps: int) -> tuple[list[float], LatentSpace]:
    """Seconds per epoch of one autoencoder level (the ``ae`` settings, its ``accelerator`` included): both levels
    trained for ``epochs[0]`` and for ``epochs[1]`` epochs, ``reps`` times each; the per-epoch figure is the slope,
    so set-up costs (Trainer, data, partition) cancel; one short warm-up run goes first. Returns the ``reps``
    slopes and the last latent space trained (``epochs[1]`` epochs per level)."""
    from neuralcol.stages.autoencoder import train_latent_space

    lo_e, hi_e = epochs
    last = []

    def train_ae(n: int):
        a = {**ae, "level1": {**ae["level1"], "epochs": n}, "level2": {**ae["level2"], "epochs": n}}
        last[:] = [train_latent_space(ds, feats, a, latent, 0)[0]]

    # one warm-up run of the short length: on CUDA the first training pays the context, cuBLAS and allocator
    # set-up, which made the slope negative on an H100 (2026-11-27: -0.0016 s per epoch)
    t_lo = repeat(lambda: train_ae(lo_e), reps, warmup=1)
    t_hi = repeat(lambda: train_ae(hi_e), reps, warmup=0)
    return [(b - a) / (2 * (hi_e - lo_e)) for a, b in zip(t_lo, t_hi)], last[0]  # both levels ran n epochs


def detector_epoch_seconds(space, det: dict, n: int, epochs: tuple[int, int], reps: int,
                           accelerator: str = "cpu") -> list[float]:
    """Seconds per epoch of the detector ``det`` configures (network, batch, loss) on ``n`` random rows of the box
    of ``space`` (80 % trained, 20 % validated each epoch) on ``accelerator``: the slope between ``epochs[0]`` and
    ``epochs[1]`` epochs, ``reps`` times."""
    from lightning.pytorch import Trainer

    from neuralcol.lit.detector import detector_module
    from neuralcol.nn.detector import build_detector
    from neuralcol.samples.datamodule import CollisionDataModule
    from neuralcol.samples.store import CollisionStore

    gen = np.random.default_rng(0)
    d_lo, d_hi = epochs
    with tempfile.TemporaryDirectory() as tmp:
        store = CollisionStore(Path(tmp) / "dc.h5", space.dim, space.n_parts)
        pd_sub = gen.normal(0, 0.01, size=(n, space.n_parts))
        pd = pd_sub.max(1)
        store.append(space.sample(n).numpy(), pd, pd_sub, pd > 0, np.where(pd > 0, 0, 1), 0, np.zeros(n))
        store.close()
        dm = CollisionDataModule(Path(tmp) / "dc.h5", space.dim, space.n_parts, int(det["batch_size"]), 0.01,
                                 float(det["targets"]["pd_clip"]))
        dm.refresh()

        def train_det(n_epochs: int):
            module = detector_module(build_detector(space, det), det, w_b=1.0, lr=float(det["lr"]))
            Trainer(max_epochs=n_epochs, accelerator=accelerator, devices=1, logger=False, enable_checkpointing=False,
                    enable_progress_bar=False, enable_model_summary=False).fit(module, datamodule=dm)

        t_dlo = repeat(lambda: train_det(d_lo), reps, warmup=0)
        t_dhi = repeat(lambda: train_det(d_hi), reps, warmup=0)
        dm.store.close()
    return [(b - a) / (d_hi - d_lo) for a, b in zip(t_dlo, t_dhi)]


def measure(ctx: BenchContext) -> dict:
    """Seconds per epoch: the SCAPE autoencoder (CPU preset) and the detector (CPU preset, 10 000 rows).

    Each is timed at two epoch counts; the per-epoch figure is the slope, so set-up costs (Trainer, data,
    partition) cancel."""
    from neuralcol.utils.config import as_dict

    cfg = ctx.cfg
    ae_epochs = (5, 15) if ctx.quick else (10, 40)
    det_epochs = (1, 3) if ctx.quick else (2, 6)
    reps = max(2, ctx.reps // 3)
    n = 10_000
    ae_epoch, space = ae_epoch_seconds(ctx.pipeline.dataset, ctx.pipeline.features, as_dict(cfg.autoencoder),
                                       as_dict(cfg.dataset.latent), ae_epochs, reps)
    det_epoch = detector_epoch_seconds(space, as_dict(cfg.detector), n, det_epochs, reps)
    ctx.notes["training"] = (f"autoencoder: SCAPE, CPU preset, slope between {ae_epochs[0]} and {ae_epochs[1]} "
                             "epochs per level (seconds per epoch of one level); detector: CPU preset on "
                             f"{n} rows (80 % trained, 20 % validated each epoch), slope between {det_epochs[0]} "
                             f"and {det_epochs[1]} epochs")
    return {"ae_epoch_s": summarize(ae_epoch), "detector_epoch_s_per_10k": summarize(det_epoch)}
