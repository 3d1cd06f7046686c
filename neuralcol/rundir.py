"""Every file name of a run directory and of the cache directory, in one place.

A run directory (``python -m experiments.run``'s Hydra output directory) and the cache (``paths.cache_dir``)
are read and written by the pipeline's stages, by :func:`neuralcol.load_run`, by the reports and by the
benchmarks; they all name files through :class:`RunDir` and :class:`CacheDir`, so a name is spelled once.

Run directory (one run)::

    .hydra/config.yaml          the composed config (Hydra)
    metrics.json                every stage's results; written last, so its presence marks a finished run
    detector.pt                 the final detector (older runs may hold a mesh_detector.pt: not read)
    detector_rounds.json        round records (rewritten each round; ``finished`` when done)
    sittings.json               one record per invocation (max_minutes): wall time per stage, where it stopped
    dc.h5                       D_c, the labeled training samples  checkpoints/detector.ckpt  resume state
    geometry.npz                the contact pairs of a detector over code and mesh (detector.inputs=code_and_mesh)
    test_predictions.npz        the detector on the U(Z) test set  realistic_predictions.npz  on the realistic set
    cascade.npz                 the detector's logits on the cascade's calibration set and their exact labels
    handling/  examples/  round_examples/  subdomains.png  speed_accuracy.png  tensorboard/<stage>/
    round_detectors/round_<k>.pt  each round's detector as tested (detector.pt's format, at logit 0)
    realistic_renders/          resolve on the realistic set, before and after, one input per kind of collision
    package.json  latent_space.pt   a packed run only (neuralcol.api.package: pretrained/<name>/)

Cache directory (shared by runs)::

    features/                   ACAP features of data sets
    autoencoders/<key>/latent_space.pt, report.json      trained autoencoders (key: data + settings + seed)
    collision/<key>/            labeled samples of one latent space and labeler (neuralcol.samples.cache)
"""

from __future__ import annotations

import os
from pathlib import Path


class _File:
    """A path inside the directory of the object it is read from (``RunDir.metrics`` -> ``<run dir>/metrics.json``)."""

    def __init__(self, *parts: str):
        self.parts = parts

    def __get__(self, obj, owner=None):
        return self if obj is None else obj.path.joinpath(*self.parts)


class RunDir:
    """The files of one run directory (paths only; nothing is created)."""

    config = _File(".hydra", "config.yaml")
    overrides = _File(".hydra", "overrides.yaml")
    metrics = _File("metrics.json")  # written last: marks a finished run (neuralcol.utils.resume)
    resumed_in = _File("resumed_in.txt")  # an interrupted run that was continued elsewhere names that directory
    detector = _File("detector.pt")
    detector_rounds = _File("detector_rounds.json")
    sittings = _File("sittings.json")  # one record per invocation: stages' wall times, where it stopped
    dc = _File("dc.h5")
    geometry = _File("geometry.npz")  # the contact pairs a detector over code and mesh reads
    checkpoint = _File("checkpoints", "detector.ckpt")
    test_predictions = _File("test_predictions.npz")
    realistic_predictions = _File("realistic_predictions.npz")
    realistic_renders = _File("realistic_renders")  # resolve before/after, one colliding input per kind
    cascade = _File("cascade.npz")  # calibration logits + labels of the certified cascade (neuralcol.stages.cascade)
    handling = _File("handling")
    examples = _File("examples")
    round_examples = _File("round_examples")
    round_detectors = _File("round_detectors")  # round_<k>.pt: each round's tested detector (paper Fig. 5 post hoc)

    def round_detector(self, k: int) -> Path:
        """``round_detectors/round_<k>.pt``: round k's detector, with the weights it was tested with."""
        return self.round_detectors / f"round_{int(k)}.pt"
    subdomains_png = _File("subdomains.png")
    speed_accuracy_png = _File("speed_accuracy.png")  # throughput against accuracy and FNR (neuralcol.stages.speed)
    tensorboard = _File("tensorboard")
    latent_space = _File("latent_space.pt")  # a packed run's own latent space (neuralcol.api.package), else the cache's
    package = _File("package.json")  # a packed run's manifest: source, figures, each file's size and SHA-256

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)

    def __fspath__(self) -> str:
        return str(self.path)

    def __truediv__(self, name: str) -> Path:
        return self.path / name

    def __repr__(self) -> str:
        return f"RunDir({self.path})"

    def is_finished(self) -> bool:
        return self.metrics.is_file()


class CacheDir:
    """The folders of the cache directory (``paths.cache_dir``)."""

    features = _File("features")

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"CacheDir({self.path})"

    def autoencoder(self, key: str) -> Path:
        return self.path / "autoencoders" / str(key)

    def latent_space(self, key: str) -> Path:
        return self.autoencoder(key) / "latent_space.pt"

    def samples(self, key: str) -> Path:
        return self.path / "collision" / str(key)
