"""LightningDataModule over the normalised ACAP features of a data set's meshes."""

from __future__ import annotations

import lightning as L
import torch
from torch.utils.data import DataLoader, TensorDataset


class FeatureDataModule(L.LightningDataModule):
    """Train / validation loaders over normalised features.

    Args:
        features: (N, V, 9) normalised features.
        train_index: indices of the training meshes.
        val_index: indices of the validation meshes.
        batch_size: meshes per batch.
        seed: shuffling seed (explicit generator, no global RNG).
    """

    def __init__(self, features: torch.Tensor, train_index, val_index, batch_size: int = 128, seed: int = 0):
        super().__init__()
        self.features = features.float()
        self.train_index = torch.as_tensor(train_index, dtype=torch.long)
        self.val_index = torch.as_tensor(val_index, dtype=torch.long)
        self.batch_size = batch_size
        self.seed = seed

    def train_dataloader(self):
        g = torch.Generator().manual_seed(self.seed)
        return DataLoader(TensorDataset(self.features[self.train_index]), batch_size=self.batch_size,
                          shuffle=True, generator=g)

    def val_dataloader(self):
        idx = self.val_index if len(self.val_index) else self.train_index
        return DataLoader(TensorDataset(self.features[idx]), batch_size=self.batch_size)
