"""The mesh files a command line names: folders expanded in natural order, each file read with a one-line reason
when it cannot be, and meshes grouped by topology. Used by ``python -m neuralcol.collision`` and ``neuralcol``."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from neuralcol.geometry.mesh_io import natural_key
from neuralcol.geometry.source_mesh import SOURCE_SUFFIXES, SourceMesh, read_source


class MeshEntry(NamedTuple):
    """One mesh file to label: ``name`` as printed (the path as given, or joined to its folder); ``error`` is
    set for a PATH that names no mesh file (reported in its place)."""

    name: str
    path: Path
    error: str | None = None


def expand_paths(paths: Sequence[str]) -> list[MeshEntry]:
    """Mesh files named by the PATH arguments, in the order given (folders in natural order).

    Returns:
        The entries; a missing path or a folder without mesh files gives one entry with ``error`` set.
    """
    entries = []
    for arg in paths:
        path = Path(arg)
        if path.is_dir():
            names = sorted((p.name for p in path.iterdir() if p.is_file() and p.suffix.lower() in SOURCE_SUFFIXES),
                           key=natural_key)
            if not names:
                entries.append(MeshEntry(arg, path, f"folder holds no mesh files ({', '.join(SOURCE_SUFFIXES)})"))
            entries += [MeshEntry(os.path.join(arg, n), path / n) for n in names]
        elif path.exists():
            entries.append(MeshEntry(arg, path))
        else:
            entries.append(MeshEntry(arg, path, "no such file or folder; check the path"))
    return entries


def failure_reason(name: str, path: Path, exc: BaseException) -> str:
    """One-line reason of a read failure, without the path prefix that MeshFileError messages carry."""
    msg = str(exc)
    for prefix in (f"{path}: ", f"{name}: "):
        if msg.startswith(prefix):
            msg = msg[len(prefix):]
            break
    return " ".join(msg.split()) or type(exc).__name__


def read_source_entry(entry: MeshEntry) -> SourceMesh:
    """Read one mesh file with its structure (:func:`~neuralcol.geometry.source_mesh.read_source`: OBJ, OFF, PLY,
    STL; polygons fan-triangulated, kept for writing back) and check that its vertices are finite."""
    mesh = read_source(entry.path)
    if not np.isfinite(mesh.vertices).all():
        raise ValueError("vertices contain NaN or inf; cannot label")
    return mesh


def read_entry(entry: MeshEntry) -> tuple[np.ndarray, np.ndarray]:
    """:func:`read_source_entry`'s vertices (V, 3) float64 and triangles (F, 3) int64."""
    mesh = read_source_entry(entry)
    return mesh.vertices, mesh.faces


def topology_key(vertices: np.ndarray, faces: np.ndarray) -> tuple[int, tuple[int, ...], bytes]:
    """Hashable topology of a mesh with vertices (V, 3) and faces (F, 3): meshes of one labeler share it."""
    return len(vertices), faces.shape, np.ascontiguousarray(faces, dtype=np.int64).tobytes()
