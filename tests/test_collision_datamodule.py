"""D_c's loaders: whole batches by one index per tensor give the batches of the row-by-row DataLoader."""

import torch
from torch.utils.data import DataLoader, SequentialSampler, TensorDataset

from neuralcol.samples.datamodule import EpochShuffle, batched_loader


def test_batched_loader_gives_the_row_by_row_batches():
    gen = torch.Generator().manual_seed(0)
    n = 1037  # not a multiple of the batch size: the last batch is short in both
    tensors = (torch.randn(n, 5, generator=gen), torch.randn(n, generator=gen), torch.randn(n, 3, generator=gen),
               torch.randint(0, 3, (n,), generator=gen))
    for sampler in (EpochShuffle(n, seed=3, epoch=lambda: 2), SequentialSampler(range(n))):
        old = list(DataLoader(TensorDataset(*tensors), batch_size=128, sampler=sampler))
        new = list(batched_loader(tensors, sampler, 128))
        assert len(new) == len(old) == 9
        for a, b in zip(old, new):
            assert len(a) == len(b) == 4
            for x, y in zip(a, b):
                assert x.dtype == y.dtype and torch.equal(x, y)


def test_validation_batches_follow_the_training_batch_size(tmp_path):
    """The validation loader's batches are the training batch size unless one is given (the ranking term
    compares a batch's rows, so at 8192 validation cost most of a paper-scale epoch); a bad size is one clear error."""
    import numpy as np
    import pytest

    from neuralcol.samples.datamodule import CollisionDataModule

    rng = np.random.default_rng(0)
    n = 400
    pd = rng.normal(size=n) * 0.01
    dm = CollisionDataModule(tmp_path / "dc.h5", 3, 1, batch_size=16, pd_unit=0.01, pd_clip=0.25)
    dm.append(rng.normal(size=(n, 3)).astype(np.float32), pd, pd[:, None], pd > 0, np.where(pd > 0, 0, 1), 0, 0)
    n_val = len(dm._val[0])
    assert 0 < n_val < n
    sizes = [len(b[0]) for b in dm.val_dataloader()]
    assert sizes[0] == 16 and sum(sizes) == n_val
    dm.batch_size = 32  # fine-tuning's larger batch: validation follows it
    assert len(next(iter(dm.val_dataloader()))[0]) == 32
    dm.close()
    fixed = CollisionDataModule(tmp_path / "dc.h5", 3, 1, batch_size=16, pd_unit=0.01, pd_clip=0.25,
                                val_batch_size=64)
    fixed.setup()
    assert len(next(iter(fixed.val_dataloader()))[0]) == min(64, n_val)
    fixed.close()
    with pytest.raises(ValueError, match="val_batch_size=0"):
        CollisionDataModule(tmp_path / "x.h5", 3, 1, batch_size=16, pd_unit=0.01, pd_clip=0.25, val_batch_size=0)


def test_detector_module_logs_the_epoch_means_of_its_batches(tmp_path):
    """The detector's module logs each epoch's row-weighted means of its batches' losses and accuracy once, on the
    last batch, and the round callback's reading of ``val/accuracy`` after validation sees them: the
    values equal the losses recomputed batch by batch with the trained weights, short last batch included."""
    import lightning as L
    import numpy as np
    import pytest

    from neuralcol.lit.detector import DetectorLitModule
    from neuralcol.nn.detector import CollisionDetector, detector_losses
    from neuralcol.samples.datamodule import CollisionDataModule

    torch.manual_seed(0)
    rng = np.random.default_rng(1)
    n = 203
    pd = rng.normal(size=n) * 0.01
    dm = CollisionDataModule(tmp_path / "dc.h5", 4, 2, batch_size=16, pd_unit=0.01, pd_clip=0.25)
    dm.append(rng.normal(size=(n, 4)).astype(np.float32), pd, np.stack([pd, -pd], 1), pd > 0,
              rng.integers(0, 3, n), 0, 0)
    det = CollisionDetector(2, 1, state_dim=4, hidden=8)
    kw = dict(w_pd=5.0, w_pdsum=0.2, w_r=2.0, w_ce=2.0, w_b=0.5, margin=0.01, temperature=0.1)
    module = DetectorLitModule(det, optimizer=torch.optim.Adam, lr=1e-2, **kw)
    seen = {}

    class Reader(L.Callback):  # like RoundCallback: reads the metric in its own on_validation_epoch_end
        def on_validation_epoch_end(self, trainer, pl_module):
            seen["val/accuracy"] = float(trainer.callback_metrics["val/accuracy"])

    L.Trainer(max_epochs=2, logger=False, enable_checkpointing=False, enable_progress_bar=False, callbacks=[Reader()],
              enable_model_summary=False, num_sanity_val_steps=0, accelerator="cpu").fit(module, datamodule=dm)
    n_val = len(dm._val[0])
    assert n_val % 16 != 0  # a short last batch
    sums, rows = torch.zeros(6, dtype=torch.float64), 0
    det.eval()
    with torch.no_grad():
        for z, p, ps, sub in dm.val_dataloader():
            out = det(z)
            lo = detector_losses(out, p, ps, sub, **kw)
            acc = ((out.logit > 0) == (p > 0)).float().mean()
            sums += torch.stack([lo.total, lo.pd, lo.rank, lo.ce, lo.boundary, acc]).double() * len(z)
            rows += len(z)
    expected = dict(zip(DetectorLitModule.LOGGED, (sums / rows).tolist()))
    for name, value in expected.items():
        assert float(module.trainer.callback_metrics[f"val/{name}"]) == pytest.approx(value, rel=1e-5, abs=1e-7)
    assert seen["val/accuracy"] == pytest.approx(expected["accuracy"], abs=1e-7)
    assert {f"train/{k}" for k in DetectorLitModule.LOGGED} <= set(module.trainer.callback_metrics)
    dm.close()
