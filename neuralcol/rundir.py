"""Every file name of a run directory and of the cache directory, in one place.

A run directory (``python -m experiments.run``'s Hydra output directory) and the cache (``paths.cache_dir``)
are read and written by the pipeline's stages, by :func:`neuralcol.load_run`, by the reports and by the
benchmarks; they all name files through :class:`RunDir` and :class:`CacheDir`, so a name is spelled once.

Run directory (one run)::

    .hydra/config.yaml          the composed config (Hydra)
    metrics.json                every stage's results; written last, so its presence marks a finished run
    detector.pt                 the final latent detector         mesh_detector.pt   the detector that reads meshes
    detector_rounds.json        round records (rewritten each round; ``finished`` when done)
    dc.h5                       D_c, the labeled training samples  checkpoints/detector.ckpt  resume state
    test_predictions.npz        the detector on the U(Z) test set  realistic_predictions.npz  on the realistic set
    handling/  examples/  round_examples/  subdomains.png  tensorboard/<stage>/

Cache directory (shared by runs)::

    features/                   ACAP features of data sets
    autoencoders/<key>/latent_space.pt, report.json      trained autoencoders (key: data + settings + seed)
    collision/<key>/            labeled samples of one latent space and labeler (neuralcol.samples.cache)
"""

from __future__ import annotations

import os
from pathlib import Path


class RunDir:
    """The files of one run directory (paths only; nothing is created)."""

    METRICS = "metrics.json"  # written last: marks a finished run (neuralcol.utils.resume)
    RESUMED_IN = "resumed_in.txt"

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)

    def __fspath__(self) -> str:
        return str(self.path)

    def __truediv__(self, name: str) -> Path:
        return self.path / name

    def __repr__(self) -> str:
        return f"RunDir({self.path})"

    @property
    def config(self) -> Path:
        return self.path / ".hydra" / "config.yaml"

    @property
    def overrides(self) -> Path:
        return self.path / ".hydra" / "overrides.yaml"

    @property
    def metrics(self) -> Path:
        return self.path / self.METRICS

    @property
    def resumed_in(self) -> Path:
        return self.path / self.RESUMED_IN

    @property
    def detector(self) -> Path:
        return self.path / "detector.pt"

    @property
    def mesh_detector(self) -> Path:
        return self.path / "mesh_detector.pt"

    @property
    def detector_rounds(self) -> Path:
        return self.path / "detector_rounds.json"

    @property
    def dc(self) -> Path:
        return self.path / "dc.h5"

    @property
    def checkpoint(self) -> Path:
        return self.path / "checkpoints" / "detector.ckpt"

    @property
    def test_predictions(self) -> Path:
        return self.path / "test_predictions.npz"

    @property
    def realistic_predictions(self) -> Path:
        return self.path / "realistic_predictions.npz"

    @property
    def handling(self) -> Path:
        return self.path / "handling"

    @property
    def examples(self) -> Path:
        return self.path / "examples"

    @property
    def round_examples(self) -> Path:
        return self.path / "round_examples"

    @property
    def subdomains_png(self) -> Path:
        return self.path / "subdomains.png"

    @property
    def tensorboard(self) -> Path:
        return self.path / "tensorboard"

    def is_finished(self) -> bool:
        return self.metrics.is_file()


class CacheDir:
    """The folders of the cache directory (``paths.cache_dir``)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"CacheDir({self.path})"

    @property
    def features(self) -> Path:
        return self.path / "features"

    def autoencoder(self, key: str) -> Path:
        return self.path / "autoencoders" / str(key)

    def latent_space(self, key: str) -> Path:
        return self.autoencoder(key) / "latent_space.pt"

    def samples(self, key: str) -> Path:
        return self.path / "collision" / str(key)
