"""A detector training epoch through Lightning the former way and as now, alternated in one process:
``PYTHONPATH=. python research/paper_scale/epoch_bench.py [DETECTOR_PT] [--rows 20000] [--batch 1024] [--reps 3]``.

Before: six ``log`` calls a step, validation batches of 8192 rows. Now: one ``log_dict`` an epoch of the batches'
row-weighted means, validation batches of the training batch size. (The ranking term is the masked sum in both:
``train_step_bench.py`` measures that change.) Random codes in the box, random pair features and targets, 80/20
split, one epoch a fit (training and validation); prints the median seconds an epoch of each and their ratio.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import lightning as L
import numpy as np
import torch

from neuralcol.lit.detector import DetectorLitModule
from neuralcol.nn.detector import load_detector
from neuralcol.samples.datamodule import CollisionDataModule


class StepLogging(DetectorLitModule):
    """The module's former logging: every batch logs its six values (Lightning averages them)."""

    def _accumulate(self, split, values, bs, batch_idx=None):
        self.log_dict({f"{split}/{k}": v for k, v in zip(self.LOGGED, values)}, on_step=False, on_epoch=True,
                      batch_size=bs)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("detector", nargs="?", default="pretrained/scape/detector.pt")
    ap.add_argument("--rows", type=int, default=20000)
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--reps", type=int, default=3)
    a = ap.parse_args(argv)
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    net, _ = load_detector(a.detector)
    k, n = net.n_components, a.rows
    lo, hi = (net.center - net.half_range).numpy(), (net.center + net.half_range).numpy()
    z = rng.uniform(lo, hi, size=(n, net.latent_dim)).astype(np.float32)
    pd = rng.normal(size=n) * 0.01
    geo = rng.normal(size=(n, net.geometry.n_pairs, 3)).astype(np.float32) if net.geometry is not None else None
    kw = dict(w_pd=5.0, w_pdsum=0.2, w_r=2.0, w_ce=2.0, w_b=0.5, margin=0.01, temperature=0.1)
    with tempfile.TemporaryDirectory() as tmp:
        dms = {}
        for name, val_batch in (("before", 8192), ("now", None)):
            dm = CollisionDataModule(Path(tmp) / f"{name}.h5", net.latent_dim, k, batch_size=a.batch, pd_unit=0.01,
                                     pd_clip=0.25, val_batch_size=val_batch,
                                     n_pairs=0 if geo is None else net.geometry.n_pairs)
            dm.append(z, pd, np.repeat(pd[:, None], k, 1), pd > 0, rng.integers(0, 3, n), 0, 0, geometry=geo)
            dms[name] = dm
        seconds = {"before": [], "now": []}
        for _ in range(a.reps):
            for name, cls in (("before", StepLogging), ("now", DetectorLitModule)):
                module = cls(net, optimizer=torch.optim.Adam, lr=1e-4, space=object(), **kw)
                trainer = L.Trainer(max_epochs=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                                    enable_model_summary=False, num_sanity_val_steps=0, accelerator="cpu")
                t = time.perf_counter()
                trainer.fit(module, datamodule=dms[name])
                seconds[name].append(time.perf_counter() - t)
        for dm in dms.values():
            dm.close()
    before, now = statistics.median(seconds["before"]), statistics.median(seconds["now"])
    print(f"{n} rows, batch {a.batch}: an epoch {before:.2f} s before, {now:.2f} s now, {before / now:.2f}x "
          f"({torch.get_num_threads()} threads)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
