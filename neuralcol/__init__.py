"""neuralcol: active learning of neural collision handlers for deforming 3D meshes.

Reproduces and extends Tan et al., "N-Penetrate: Active Learning of Neural Collision Handler for Complex 3D
Mesh Deformations" (ICML 2022). Top-level names are imported lazily, so that light modules (e.g. the exact
labeler in worker processes) do not pay for importing torch.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "ACAP": "neuralcol.geometry.acap",
    "MeshDataset": "neuralcol.data.datasets",
    "load_mesh_dataset": "neuralcol.data.datasets",
    "load_procedural_dataset": "neuralcol.data.datasets",
    "read_mesh": "neuralcol.geometry.mesh_io",
    "write_mesh": "neuralcol.geometry.mesh_io",
    "write_meshes": "neuralcol.geometry.mesh_io",
    "ExactLabeler": "neuralcol.collision.labeler",
    "LabelPool": "neuralcol.collision.pool",
    "load_run": "neuralcol.api",
    "pretrained": "neuralcol.api",
    "pack_run": "neuralcol.api",
    "TrainedRun": "neuralcol.api",
    "check": "neuralcol.api.anymesh",
    "resolve": "neuralcol.api.anymesh",
    "resolve_sequence": "neuralcol.api.anymesh",
}

__all__ = sorted(_EXPORTS)
__version__ = "0.1.0"


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'neuralcol' has no attribute '{name}'")


def __dir__():
    return sorted(list(globals()) + __all__)
