"""A finished run as one object: ``run = neuralcol.load_run(RUN_DIR)``.

``RUN_DIR`` is the directory of a finished ``python -m experiments.run`` (it holds ``.hydra/config.yaml``,
``detector.pt`` and ``metrics.json``; the latent space comes from the run's autoencoder cache). The
:class:`TrainedRun` it returns maps meshes to latent codes and back, asks the detector, labels exactly and
resolves self-collisions::

    run = neuralcol.load_run("outputs/2024-01-01/12-00-00")
    det = run.detect(vertices)          # (B, V, 3) meshes or (B, D) codes -> Detection (prob, logit, pd, pd_sub)
    det = run.detect(vertices, certify=0.01)  # the certified cascade: exact labels where the detector is in doubt
    out = run.resolve(vertices)         # Resolved: vertices, codes, exact PD before and after
    run.close()                         # (or `with neuralcol.load_run(...) as run:`) stops the label workers
    run = neuralcol.pretrained("scape")  # the SCAPE model shipped in pretrained/scape (no training, no data set)

Symbols: B batch, V vertices, D = |Z_all| latent size, K sub-domains. PD is the exact penetration depth in
the units of the mesh (> 0: self-penetrating; docs/labels.md).
"""

from neuralcol.api.files import TRUSTED_TARGETS, check_run_dir, untrusted_targets
from neuralcol.api.package import check_package, pack_run
from neuralcol.api.results import OBJECTIVES, Detection, Resolved
from neuralcol.api.run import TrainedRun, load_run, pretrained

__all__ = ["OBJECTIVES", "TRUSTED_TARGETS", "Detection", "Resolved", "TrainedRun", "check_package", "check_run_dir",
           "load_run", "pack_run", "pretrained", "untrusted_targets"]
