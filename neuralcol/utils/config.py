"""Config helpers shared by the pipeline stages."""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf


def as_dict(cfg: DictConfig | dict) -> dict:
    """A plain dict of a Hydra config node (resolved) or of a mapping."""
    return OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else dict(cfg)
