"""neuralcol: active learning of neural collision handlers for deforming 3D meshes.

Reproduces and extends Tan et al., "Active Learning of Neural Collision Handler for Complex 3D Mesh
Deformations" (AAAI 2022).
"""

from neuralcol.data.datasets import MeshDataset, load_mesh_dataset, load_procedural_dataset
from neuralcol.geometry.acap import ACAP
from neuralcol.geometry.mesh_io import read_mesh, write_mesh, write_meshes

__all__ = [
    "ACAP",
    "MeshDataset",
    "load_mesh_dataset",
    "load_procedural_dataset",
    "read_mesh",
    "write_mesh",
    "write_meshes",
]
__version__ = "0.1.0"
