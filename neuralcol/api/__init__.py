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

from __future__ import annotations

import importlib

# imported on first use, so that `neuralcol check` (neuralcol.api.anymesh) does not pay for torch and the run's modules
_EXPORTS = {
    "TRUSTED_TARGETS": "neuralcol.api.files", "check_run_dir": "neuralcol.api.files",
    "untrusted_targets": "neuralcol.api.files", "check_package": "neuralcol.api.package",
    "pack_run": "neuralcol.api.package", "OBJECTIVES": "neuralcol.api.results", "Detection": "neuralcol.api.results",
    "Resolved": "neuralcol.api.results", "TrainedRun": "neuralcol.api.run", "load_run": "neuralcol.api.run",
    "pretrained": "neuralcol.api.run",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'neuralcol.api' has no attribute '{name}'")
