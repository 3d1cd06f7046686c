"""Seeding without global surprises: explicit generators for library code, one call for entry points."""

from __future__ import annotations

import random

import numpy as np
import torch


def seed_everything(seed: int | None) -> None:
    """Seed Python, NumPy and torch for an entry point (library code takes explicit generators).

    ``None`` leaves the generators unseeded; seed 0 is a valid seed.
    """
    if seed is None:
        return
    random.seed(seed)
    np.random.seed(seed % 2**32)  # noqa: NPY002 (third-party code may use the legacy global RNG)
    torch.manual_seed(seed)
