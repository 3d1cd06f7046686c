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
