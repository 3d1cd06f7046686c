"""Reading and writing single triangle meshes with vertex order kept (trimesh, ``process=False``).

trimesh triangulates polygons silently while loading; :func:`read_mesh` compares the face count a
file declares with the triangles trimesh returns and rejects files with non-triangle faces, so that
the face list of every mesh of a data set stays comparable.
"""

from __future__ import annotations

import io
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from neuralcol.errors import MeshFileError
from neuralcol.geometry.topology import check_coordinates, check_face_indices

MESH_SUFFIXES = (".obj", ".ply", ".off")


def natural_key(name: str) -> list:
    """Sort key that orders ``2.obj`` before ``10.obj``."""
    return [int(tok) if tok.isdigit() else tok.lower() for tok in re.split(r"(\d+)", name)]


def _declared_face_count(path: Path) -> int | None:
    """Number of faces (any arity) the file declares, read from its text; None if unknown."""
    suffix = path.suffix.lower()
    if suffix == ".obj":
        with open(path, "rb") as fh:
            return sum(1 for line in fh if line.startswith(b"f ") or line.startswith(b"f\t"))
    if suffix == ".off":
        with open(path, "rb") as fh:
            tokens: list[bytes] = []
            for line in fh:
                line = line.split(b"#", 1)[0].strip()
                if not line:
                    continue
                tokens.extend(line.split())
                if len(tokens) >= 4:
                    break
        if tokens and tokens[0].upper().endswith(b"OFF"):
            tokens = tokens[1:]
        try:
            return int(tokens[1])
        except (IndexError, ValueError):
            return None
    if suffix == ".ply":
        with open(path, "rb") as fh:
            for raw in fh:
                line = raw.strip()
                if line.startswith(b"element face"):
                    return int(line.split()[2])
                if line == b"end_header":
                    return None
    return None


def _mesh_source(path: Path) -> Path | io.StringIO:
    """What trimesh reads: an OBJ or OFF file as text decoded here, bytes that are not UTF-8 (e.g. in a comment)
    replaced by U+FFFD, so that reading never depends on trimesh's optional encoding detector; PLY as the file."""
    if path.suffix.lower() in (".obj", ".off"):
        return io.StringIO(path.read_bytes().decode("utf-8", errors="replace"))
    return path


def read_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read one triangle mesh, keeping vertex and face order.

    Args:
        path: an ``.obj``, ``.ply`` or ``.off`` file.

    Returns:
        vertices (V, 3) float64 and faces (F, 3) int64.

    Raises:
        MeshFileError: the file is missing, unreadable, holds no triangle mesh, has non-triangle faces, faces
            outside its vertices, or non-finite or huge coordinates (``topology.check_coordinates``).
    """
    import trimesh  # local: keeps `import neuralcol` light

    path = Path(path)
    if not path.is_file():
        raise MeshFileError(f"{path}: no such file")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshFileError(f"{path}: unsupported mesh format '{path.suffix}'; use one of {', '.join(MESH_SUFFIXES)}")
    try:
        mesh = trimesh.load(_mesh_source(path), file_type=path.suffix.lower().lstrip("."), process=False,
                            maintain_order=True, force="mesh")
    except Exception as exc:  # trimesh raises many types for broken files
        reason = " ".join(str(exc).split())[:200]  # one line
        raise MeshFileError(f"{path}: cannot be read as a mesh ({type(exc).__name__}: {reason})") from exc
    vertices = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(vertices) == 0 or len(faces) == 0:
        raise MeshFileError(
            f"{path}: holds no triangle mesh ({len(vertices)} vertices, {len(faces)} faces); "
            "remove it from the data set folder"
        )
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise MeshFileError(f"{path}: vertices have shape {vertices.shape}, expected (V, 3): x y z on each vertex line")
    check_face_indices(faces, len(vertices), str(path))
    check_coordinates(vertices, str(path))
    declared = _declared_face_count(path)
    if declared is not None and declared != len(faces):
        raise MeshFileError(
            f"{path}: has non-triangle faces ({declared} faces in the file, {len(faces)} triangles after "
            "splitting); triangulate all meshes of the data set the same way before loading"
        )
    return vertices, faces


def write_mesh(path: str | Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    """Write one mesh; the format follows the suffix (``.obj``, ``.ply``, ``.off``, text with every coordinate
    exact: read back, it is the same float64 mesh). Written through a temporary file beside it, then renamed.

    Args:
        path: output file; parent folders are created.
        vertices: (V, 3) float (numpy or torch).
        faces: (F, 3) int.

    Returns:
        The written path.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _WRITERS:
        raise ValueError(f"{path}: cannot write '{suffix}' files; use one of {', '.join(_WRITERS)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    v = np.asarray(_to_numpy(vertices), np.float64)
    f = np.asarray(_to_numpy(faces), np.int64)
    text = _WRITERS[suffix](v, f)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)
    return path


def _coords(v: np.ndarray) -> list[str]:
    """Each vertex as ``x y z`` with the shortest decimals that read back to the same float64 (``repr``)."""
    return [f"{x!r} {y!r} {z!r}" for x, y, z in v.tolist()]


def _obj_text(v: np.ndarray, f: np.ndarray) -> str:
    return "".join([f"v {c}\n" for c in _coords(v)] + [f"f {a} {b} {c}\n" for a, b, c in (f + 1).tolist()])


def _off_text(v: np.ndarray, f: np.ndarray) -> str:
    return "".join([f"OFF\n{len(v)} {len(f)} 0\n"] + [f"{c}\n" for c in _coords(v)]
                   + [f"3 {a} {b} {c}\n" for a, b, c in f.tolist()])


def _ply_text(v: np.ndarray, f: np.ndarray) -> str:
    header = ("ply\nformat ascii 1.0\n"
              f"element vertex {len(v)}\nproperty double x\nproperty double y\nproperty double z\n"
              f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
    return "".join([header] + [f"{c}\n" for c in _coords(v)] + [f"3 {a} {b} {c}\n" for a, b, c in f.tolist()])


# Text formats written with every float64 exactly (``repr``): a mesh written and read back is the same mesh bit for
# bit, so a verdict on it holds for the file (trimesh's exporters round OBJ to 8 decimals and PLY to float32).
_WRITERS = {".obj": _obj_text, ".off": _off_text, ".ply": _ply_text}


def write_meshes(
    folder: str | Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    names: Sequence[str] | None = None,
    fmt: str = "obj",
) -> list[Path]:
    """Write a batch of meshes sharing one topology, one file each.

    Args:
        folder: output folder (created).
        vertices: (B, V, 3) float (numpy or torch).
        faces: (F, 3) int.
        names: B file stems; defaults to ``0, 1, ...``.
        fmt: ``obj``, ``ply`` or ``off``.

    Returns:
        The B written paths.
    """
    v = _to_numpy(vertices)
    if v.ndim != 3 or v.shape[-1] != 3:
        raise ValueError(f"vertices have shape {v.shape}, expected (B, V, 3)")
    names = [str(i) for i in range(len(v))] if names is None else list(names)
    if len(names) != len(v):
        raise ValueError(f"{len(names)} names for {len(v)} meshes")
    folder = Path(folder)
    return [write_mesh(folder / f"{Path(n).stem}.{fmt.lstrip('.')}", vi, faces) for n, vi in zip(names, v)]


def _to_numpy(x) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)
