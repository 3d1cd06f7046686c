"""The run context: one run's chain, built once from its config.

data set -> ACAP features -> latent space (-> its fitted box) -> exact labelers -> label pool -> oracle. The pipeline
(:mod:`neuralcol.pipeline.run`), the diagnosis, the benchmarks and the studies all take these pieces from a
:class:`RunContext` instead of assembling them; each piece is built on first use and kept. The stages themselves
(``neuralcol/stages/``) receive what they need as arguments. File names come from :mod:`neuralcol.rundir`.

    ctx = RunContext(cfg, run_dir)
    ds, feats = ctx.dataset, ctx.features
    space = ctx.latent_space().space
    labeler = ctx.sample_labeler()
    with ctx.pool(labeler) as pool:
        latent = ctx.fit_box(pool, labeler)   # a new space with the fitted box (or the same stage: box_fit off)
        oracle = ctx.oracle(pool, latent)
"""

from __future__ import annotations

import json
from functools import cached_property
from pathlib import Path
from typing import NamedTuple

import numpy as np
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from neuralcol.collision.backends import build_labeler
from neuralcol.collision.pool import LabelPool
from neuralcol.data.features import DatasetFeatures, dataset_features
from neuralcol.errors import UserInputError
from neuralcol.nn.latent_space import LatentSpace
from neuralcol.rundir import CacheDir, RunDir
from neuralcol.samples.cache import samples_cache_dir
from neuralcol.samples.oracle import LatentOracle
from neuralcol.stages.autoencoder import reference_spaces, train_or_load_latent_space
from neuralcol.stages.box_check import probe_share
from neuralcol.stages.box_fit import fit_box, fitted_key, fitted_space
from neuralcol.utils.files import write_json_atomic
from neuralcol.utils.hashing import settings_key


class LatentStage(NamedTuple):
    """The latent space of a run: the space, the autoencoder's report (``cache_key`` names the caches of its
    labeled samples; ``box_fit`` the fit of a fitted box) and whether the autoencoder was loaded from the cache."""

    space: LatentSpace
    report: dict
    from_cache: bool


class RunContext:
    """One run's pipeline pieces, built from ``cfg`` on first use.

    Args:
        cfg: a composed ``experiments.run`` config (``conf/config.yaml``).
        run_dir: the run directory (None: pieces that need none only).
    """

    def __init__(self, cfg: DictConfig, run_dir: str | Path | None = None):
        self.cfg = cfg
        self.run_dir = None if run_dir is None else RunDir(run_dir)
        self.cache = CacheDir(cfg.paths.cache_dir)
        self._latent: LatentStage | None = None
        self._fitted: LatentStage | None = None

    # ------------------------------------------------------------------ data
    @cached_property
    def dataset(self):
        """The data set (``dataset.source``), loaded and validated."""
        return instantiate(self.cfg.dataset.source)

    @cached_property
    def features(self) -> DatasetFeatures:
        """ACAP features of the data set (cached under ``<cache>/features``)."""
        acap_cfg = OmegaConf.to_container(self.cfg.acap, resolve=True)
        norm_cfg = acap_cfg.pop("normalizer")
        return dataset_features(self.dataset, self.cfg.dataset.reference_index, acap_cfg, norm_cfg,
                                cache_dir=self.cache.features)

    @property
    def faces(self) -> np.ndarray:
        """(F, 3) int triangles of the data set's topology."""
        return self.dataset.faces.numpy()

    @property
    def rest(self) -> np.ndarray:
        """(V, 3) float64 rest mesh (the data set's reference mesh)."""
        return self.dataset.vertices[self.cfg.dataset.reference_index].numpy().astype("float64")

    # ------------------------------------------------------------------ latent space
    def latent_space(self, logger_factory=None) -> LatentStage:
        """The bilevel autoencoder's latent space, trained or loaded from the cache (built once).

        ``logger_factory``: ``stage -> Lightning logger`` for the autoencoder's training (None: no logging).
        """
        if self._latent is None:
            space, report, cached = train_or_load_latent_space(
                self.dataset, self.features, self.cfg.autoencoder, self.cfg.dataset.latent,
                int(self.cfg.autoencoder_seed), self.cache.path, logger_factory, threads=self.cfg.get("threads", 1))
            self._latent = LatentStage(space, report, cached)
        return self._latent

    def use_latent_space_file(self, path: str | Path) -> LatentStage:
        """Use the latent space saved at ``path`` (a ``latent_space.pt`` of the cache) instead of training one."""
        path = Path(path)
        if not path.is_file():
            raise UserInputError(f"{path}: no such file; give a latent_space.pt of "
                                 f"{self.cache.autoencoder('<key>')}/")
        space = LatentSpace.load(path)
        if space.rest_vertices.shape[0] != self.dataset.n_vertices:
            raise UserInputError(f"{path}: {space.rest_vertices.shape[0]} vertices, the data set "
                                 f"{self.cfg.dataset.name} has {self.dataset.n_vertices}")
        return self.use_latent_space(space, {**space.meta, "cache_key": path.parent.name})

    def use_latent_space(self, space: LatentSpace, report: dict) -> LatentStage:
        """Use an already loaded latent space (``report["cache_key"]`` names its caches)."""
        self._latent = LatentStage(space, report, True)
        self._fitted = None
        return self._latent

    def fit_box(self, pool: LabelPool, labeler) -> LatentStage:
        """The latent space with its box fitted to ``box_fit.band`` with labels from ``pool``
        (:mod:`~neuralcol.stages.box_fit`; the probe is ``box_check``'s size and seed), fitted once per context.

        The fitted space is a new object (:func:`~neuralcol.stages.box_fit.fitted_space`; the space of
        :meth:`latent_space` keeps the paper's box) with its own cache key, saved there, so its test set, D_c and
        :class:`~neuralcol.api.TrainedRun` never meet the paper's box; ``report["box_fit"]`` holds the fit. The fit
        itself is cached beside the paper box's labeled samples. With ``box_fit`` off: :meth:`latent_space`.

        ``labeler``: the labeler behind ``pool`` (it names the cache of labeled samples).
        """
        bf, bc = self.cfg.get("box_fit"), self.cfg.box_check
        stage = self.latent_space()
        if bf is None or not bf.enabled:
            return stage
        if self._fitted is not None:
            return self._fitted
        space, report, key = stage.space, stage.report, stage.report["cache_key"]
        band, shrink, grow = (list(map(float, bf[k])) for k in ("band", "shrink", "grow"))
        n, seed = int(bc.n_probe), int(bc.seed)
        settings = {"band": band, "shrink": shrink, "grow": grow, "n_probe": n, "seed": seed}
        tag = settings_key(settings, 12)
        fit_file = self.samples_dir(labeler) / f"box_fit_{tag}.json"
        if fit_file.is_file():
            fit = json.loads(fit_file.read_text())
        else:
            fit = fit_box(space, lambda sp: probe_share(sp, pool, n, seed, desc="fitting the box Z"), band,
                          shrink, grow)
            write_json_atomic(fit_file, {**fit, "settings": settings})
        fitted = fitted_space(space, fit["factor"])  # (factor 1 too: the box as scaled_box rounds it)
        new_key = fitted_key(key, fit["factor"])
        path = self.cache.latent_space(new_key)
        if new_key != key:
            fitted.meta = {**space.meta, "box_fit": {"factor": fit["factor"], "from": key}}
            if not path.is_file():
                path.parent.mkdir(parents=True, exist_ok=True)
                fitted.save(path)
        self._fitted = LatentStage(fitted, {**report, "cache_key": new_key, "box_fit": fit}, stage.from_cache)
        return self._fitted

    @property
    def space(self) -> LatentSpace:
        return self.latent_space().space

    @cached_property
    def references(self) -> tuple[dict, dict]:
        """The latent space's PCA references: ``({name: PCALatentSpace}, {name: errors})`` for PCA of the
        vertex positions and of the ACAP features at the same |Z_all| and training meshes
        (:func:`~neuralcol.stages.autoencoder.reference_spaces`)."""
        stage = self.latent_space()
        return reference_spaces(self.dataset, self.features, stage.space, stage.report)

    # ------------------------------------------------------------------ labels
    def labeler(self, partition: np.ndarray | None = None):
        """The exact labeler of ``labeling`` for the data set's topology (PD_i over ``partition``)."""
        return build_labeler(self.cfg.labeling, self.faces, self.rest, partition=partition)

    def sample_labeler(self):
        """The labeler of decoded samples: PD_i over the latent space's sub-domains (topology and rest mesh from
        the latent space, which holds the data set's; no data set needs loading)."""
        space = self.space
        return build_labeler(self.cfg.labeling, space.faces.cpu().numpy(), space.rest_vertices.cpu().numpy(),
                             partition=space.partition.cpu().numpy())

    def pool(self, labeler, **overrides) -> LabelPool:
        """A label pool (``labeling.pool``, with ``overrides``) over ``labeler``; use it as a context manager."""
        kw = {**OmegaConf.to_container(self.cfg.labeling.pool, resolve=True), **overrides}
        return LabelPool(labeler, **kw)

    def oracle(self, pool: LabelPool, latent: LatentStage | None = None) -> LatentOracle:
        """Codes of ``latent``'s space (default: :meth:`latent_space`) -> decoded meshes -> exact labels, through
        ``pool``."""
        return LatentOracle((latent or self.latent_space()).space, pool)

    def samples_dir(self, labeler, latent: LatentStage | None = None) -> Path:
        """``<cache>/collision/<key>``: the labeled samples of ``latent`` (default: :meth:`latent_space`; its
        report's ``cache_key``) and ``labeler``."""
        return samples_cache_dir(self.cache.path, (latent or self.latent_space()).report["cache_key"], labeler)
