"""``training``: seconds per epoch of the SCAPE autoencoder and of the detector (CPU presets)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from bench.context import BenchContext
from bench.timing import repeat, summarize


def measure(ctx: BenchContext) -> dict:
    """Seconds per epoch: the SCAPE autoencoder (CPU preset) and the detector (CPU preset, 10 000 rows).

    Each is timed at two epoch counts; the per-epoch figure is the slope, so set-up costs (Trainer, data,
    partition) cancel."""
    from lightning.pytorch import Trainer

    from neuralcol.lit.detector import DetectorLitModule
    from neuralcol.nn.detector import build_detector
    from neuralcol.samples.datamodule import CollisionDataModule
    from neuralcol.samples.store import CollisionStore
    from neuralcol.stages.autoencoder import train_latent_space
    from neuralcol.utils.config import as_dict

    cfg = ctx.cfg
    ds, feats = ctx.pipeline.dataset, ctx.pipeline.features
    ae = as_dict(cfg.autoencoder)
    lo_e, hi_e = (5, 15) if ctx.quick else (10, 40)

    def train_ae(epochs: int):
        a = {**ae, "level1": {**ae["level1"], "epochs": epochs}, "level2": {**ae["level2"], "epochs": epochs}}
        return train_latent_space(ds, feats, a, as_dict(cfg.dataset.latent), 0)

    reps = max(2, ctx.reps // 3)
    t_lo = repeat(lambda: train_ae(lo_e), reps, warmup=0)
    t_hi = repeat(lambda: train_ae(hi_e), reps, warmup=0)
    # per level-epoch: both levels run `epochs` epochs
    ae_epoch = [(b - a) / (2 * (hi_e - lo_e)) for a, b in zip(t_lo, t_hi)]
    space, _ = train_ae(2)
    # detector: 10 000 random rows of the SCAPE latent box, the CPU preset's network, batch and loss
    det = as_dict(cfg.detector)
    n = 10_000
    gen = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        store = CollisionStore(Path(tmp) / "dc.h5", space.dim, space.n_parts)
        pd_sub = gen.normal(0, 0.01, size=(n, space.n_parts))
        pd = pd_sub.max(1)
        store.append(space.sample(n).numpy(), pd, pd_sub, pd > 0, np.where(pd > 0, 0, 1), 0, np.zeros(n))
        store.close()
        dm = CollisionDataModule(Path(tmp) / "dc.h5", space.dim, space.n_parts, int(det["batch_size"]), 0.01,
                                 float(det["targets"]["pd_clip"]))
        dm.refresh()
        loss = det["loss"]

        def train_det(epochs: int):
            net = build_detector(space, det)
            module = DetectorLitModule(net, lr=float(det["lr"]), w_pd=loss["w_pd"], w_pdsum=loss["w_pdsum"],
                                       w_r=loss["w_r"], w_ce=loss["w_ce"], w_b=1.0, margin=loss["margin"],
                                       temperature=loss["temperature"])
            Trainer(max_epochs=epochs, accelerator="cpu", logger=False, enable_checkpointing=False,
                    enable_progress_bar=False, enable_model_summary=False).fit(module, datamodule=dm)

        d_lo, d_hi = (1, 3) if ctx.quick else (2, 6)
        t_dlo = repeat(lambda: train_det(d_lo), reps, warmup=0)
        t_dhi = repeat(lambda: train_det(d_hi), reps, warmup=0)
        dm.store.close()
    det_epoch = [(b - a) / (d_hi - d_lo) for a, b in zip(t_dlo, t_dhi)]
    ctx.notes["training"] = (f"autoencoder: SCAPE, CPU preset, slope between {lo_e} and {hi_e} epochs per level "
                             f"(seconds per epoch of one level); detector: CPU preset on {n} rows (80 % trained, "
                             f"20 % validated each epoch), slope between {d_lo} and {d_hi} epochs")
    return {"ae_epoch_s": summarize(ae_epoch), "detector_epoch_s_per_10k": summarize(det_epoch)}
