"""Mesh data sets of one topology: loading, validation and caching.

A data set is either a folder of ``.obj``/``.ply``/``.off`` files (natural sort order, ``2.obj`` before
``10.obj``), or one ``.h5``/``.npz`` file holding ``vertices (N, V, 3)`` and ``faces (F, 3)`` (and
optionally ``names (N,)``), or one of the procedural data sets (``proc_hand``, ``proc_cloth``) that are
generated on first use and cached.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from neuralcol.errors import DatasetNotFoundError, MeshFileError
from neuralcol.geometry.mesh_io import MESH_SUFFIXES, natural_key, read_mesh
from neuralcol.geometry.topology import check_faces, check_vertices
from neuralcol.utils.files import atomic_path
from neuralcol.utils.hashing import settings_key

ARRAY_SUFFIXES = (".h5", ".hdf5", ".npz")
DEFAULT_REL_AREA_TOL = 1e-10


@dataclass(frozen=True)
class MeshDataset:
    """Meshes sharing one triangulation.

    Attributes:
        vertices: (N, V, 3) float tensor.
        faces: (F, 3) long tensor.
        names: N names (file stems or ``pose_0000`` ...).
        source: where the data came from (path or generator description).
    """

    vertices: torch.Tensor
    faces: torch.Tensor
    names: list[str]
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[1])

    def subset(self, index) -> MeshDataset:
        """A data set with the meshes at ``index`` (int sequence or slice)."""
        idx = torch.as_tensor(np.arange(len(self))[index])
        return MeshDataset(self.vertices[idx], self.faces, [self.names[i] for i in idx.tolist()],
                           self.source, dict(self.meta))


def validate_meshes(vertices: np.ndarray, faces: np.ndarray, names: list[str],
                    rel_area_tol: float = DEFAULT_REL_AREA_TOL) -> None:
    """Check a stack of meshes of one topology; raise MeshFileError naming the first bad mesh.

    Args:
        vertices: (N, V, 3) float.
        faces: (F, 3) int.
        names: N names used in messages.
        rel_area_tol: faces with area <= rel_area_tol * mean face area count as zero-area.
    """
    check_faces(faces, vertices.shape[1], names[0] if names else "faces")
    for v, name in zip(vertices, names):
        check_vertices(v, faces, name, rel_area_tol)


def _load_folder(folder: Path, rel_area_tol: float) -> tuple[np.ndarray, np.ndarray, list[str]]:
    files = sorted((p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".")),
                   key=lambda p: natural_key(p.name))
    mesh_files = [p for p in files if p.suffix.lower() in MESH_SUFFIXES]
    others = [p for p in files if p.suffix.lower() not in MESH_SUFFIXES
              and p.suffix.lower() not in (".md", ".txt", ".json", ".yaml", ".yml")]
    if others:
        raise MeshFileError(
            f"{others[0]}: not a mesh file ({len(others)} such files in {folder}); a data set folder holds "
            f"only {'/'.join(MESH_SUFFIXES)} files (and README/.txt/.json notes): move it out"
        )
    if not mesh_files:
        raise DatasetNotFoundError(
            f"{folder}: no {'/'.join(MESH_SUFFIXES)} files in this folder; put the data set's meshes there "
            "or point the config at the right folder"
        )
    v0, f0 = read_mesh(mesh_files[0])
    check_faces(f0, len(v0), str(mesh_files[0]))
    verts = np.empty((len(mesh_files), *v0.shape), dtype=np.float64)
    for i, path in enumerate(mesh_files):
        v, f = (v0, f0) if i == 0 else read_mesh(path)
        if v.shape != v0.shape:
            raise MeshFileError(
                f"{path}: {len(v)} vertices, {mesh_files[0].name} has {len(v0)}; all meshes of a data set "
                "must share one topology"
            )
        if f.shape != f0.shape or not np.array_equal(f, f0):
            nd = int((f != f0).any(axis=1).sum()) if f.shape == f0.shape else abs(len(f) - len(f0))
            raise MeshFileError(
                f"{path}: faces differ from {mesh_files[0].name} ({len(f)} vs {len(f0)} faces, {nd} differ); "
                "all meshes of a data set must share one topology"
            )
        check_vertices(v, f0, str(path), rel_area_tol)
        verts[i] = v
    return verts, f0, [p.stem for p in mesh_files]


def _array_names(names: np.ndarray | None, n: int, path: Path) -> list[str]:
    """The N mesh names of an array data set from its optional ``names`` array (N,) of str or bytes."""
    if names is None:
        return [f"{i}" for i in range(n)]
    names = np.asarray(names)
    if names.shape != (n,):
        raise MeshFileError(f"{path}: 'names' has shape {names.shape}, expected ({n},): one name per mesh "
                            "(or leave 'names' out)")
    return [x.decode(errors="replace") if isinstance(x, bytes) else str(x) for x in names.tolist()]


def _load_array_file(path: Path, rel_area_tol: float) -> tuple[np.ndarray, np.ndarray, list[str]]:
    try:
        if path.suffix.lower() == ".npz":
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        else:
            import h5py

            with h5py.File(path, "r") as h5:
                data = {k: h5[k][()] for k in h5.keys()}
    except Exception as exc:
        raise MeshFileError(f"{path}: cannot be read ({type(exc).__name__}: {exc})") from exc
    missing = [k for k in ("vertices", "faces") if k not in data]
    if missing:
        raise MeshFileError(
            f"{path}: missing array(s) {missing}; found {sorted(data)}; an array data set holds "
            "'vertices' (N, V, 3) and 'faces' (F, 3)"
        )
    verts = np.asarray(data["vertices"])
    if verts.dtype.kind not in "iuf":
        raise MeshFileError(f"{path}: 'vertices' has dtype {verts.dtype}, expected real (float) coordinates")
    verts = verts.astype(np.float64)
    faces = np.asarray(data["faces"])
    if verts.ndim != 3 or verts.shape[-1] != 3 or len(verts) == 0:
        raise MeshFileError(f"{path}: 'vertices' has shape {verts.shape}, expected (N, V, 3) with N > 0")
    names = _array_names(data.get("names"), len(verts), path)
    check_faces(faces, verts.shape[1], f"{path}['faces']")
    for i, v in enumerate(verts):
        check_vertices(v, faces, f"{path}[vertices][{i}]", rel_area_tol)
    return verts, faces.astype(np.int64), names


def load_mesh_dataset(
    path: str | os.PathLike,
    dtype: torch.dtype = torch.float32,
    rel_area_tol: float = DEFAULT_REL_AREA_TOL,
    expected_vertices: int | None = None,
) -> MeshDataset:
    """Load a data set of meshes with one topology.

    Args:
        path: a folder of OBJ/PLY/OFF files, or an ``.h5``/``.npz`` file with ``vertices`` and ``faces``.
        dtype: float dtype of the returned vertices.
        rel_area_tol: faces with area <= ``rel_area_tol`` x the mesh's mean face area are rejected.
        expected_vertices: if given, the vertex count V the meshes must have (e.g. the paper's version).

    Returns:
        MeshDataset with vertices (N, V, 3), faces (F, 3), names.

    Raises:
        DatasetNotFoundError: the path does not exist or holds no meshes.
        MeshFileError: a file is unreadable or breaks a rule; the message names it and the fix.
    """
    p = Path(path).expanduser()
    if not p.exists():
        raise DatasetNotFoundError(
            f"{p}: data set not found; put the meshes there (a folder of .obj/.ply/.off files or one "
            ".h5/.npz file), or point to it with dataset.source.path=DIR (or NEURALCOL_DATA / paths.data_dir for "
            "the folder that holds the data sets)"
        )
    if p.is_dir():
        verts, faces, names = _load_folder(p, rel_area_tol)
    elif p.suffix.lower() in ARRAY_SUFFIXES:
        verts, faces, names = _load_array_file(p, rel_area_tol)
    elif p.suffix.lower() in MESH_SUFFIXES:
        raise MeshFileError(f"{p}: a single mesh file; a data set is a folder of meshes or an .h5/.npz file")
    else:
        raise MeshFileError(f"{p}: unsupported data set file; use a folder of meshes or an .h5/.npz file")
    if expected_vertices is not None and verts.shape[1] != expected_vertices:
        raise MeshFileError(
            f"{p}: meshes have {verts.shape[1]} vertices, this data set's config expects {expected_vertices}; "
            "check that this is the right data set, or set dataset.source.expected_vertices=null"
        )
    return MeshDataset(torch.as_tensor(verts, dtype=dtype), torch.as_tensor(faces, dtype=torch.long),
                       names, str(p))


def save_mesh_dataset(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray,
                      names: list[str] | None = None) -> Path:
    """Write a data set as one ``.npz`` or ``.h5`` file readable by :func:`load_mesh_dataset`.

    Args:
        path: output file (suffix chooses the format).
        vertices: (N, V, 3) float.
        faces: (F, 3) int.
        names: N names (optional).
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    v = np.asarray(vertices.detach().cpu() if hasattr(vertices, "detach") else vertices)
    f = np.asarray(faces.detach().cpu() if hasattr(faces, "detach") else faces)
    names_arr = np.asarray(names if names is not None else [str(i) for i in range(len(v))])
    with atomic_path(p) as tmp:  # procedural data sets are cached with this: concurrent runs may write one
        if p.suffix.lower() == ".npz":
            np.savez(tmp, vertices=v, faces=f, names=names_arr)
        else:
            import h5py

            with h5py.File(tmp, "w") as h5:
                h5["vertices"] = v
                h5["faces"] = f
                h5["names"] = names_arr.astype("S")
    return p


def load_procedural_dataset(
    name: str,
    n_poses: int,
    seed: int,
    cache_dir: str | os.PathLike | None = None,
    dtype: torch.dtype = torch.float32,
    geometry: dict | None = None,
) -> MeshDataset:
    """Generate (or read from cache) a procedural data set.

    Args:
        name: ``proc_hand`` or ``proc_cloth``.
        n_poses: number of meshes N.
        seed: generator seed; same arguments give identical meshes.
        cache_dir: folder for the cached ``.npz``; None disables caching.
        dtype: float dtype of the vertices.
        geometry: extra keyword arguments of the generator.

    Returns:
        MeshDataset with names ``pose_0000`` ...
    """
    from neuralcol.data.procedural import GENERATORS

    if name not in GENERATORS:
        raise DatasetNotFoundError(f"procedural data set '{name}' unknown; choose one of {sorted(GENERATORS)}")
    if n_poses < 1:
        raise ValueError(f"n_poses={n_poses}: must be >= 1")
    geometry = dict(geometry or {})
    key = settings_key([name, n_poses, seed, geometry], 10)
    cache = Path(cache_dir).expanduser() / f"{name}_n{n_poses}_s{seed}_{key}.npz" if cache_dir else None
    if cache is not None and cache.is_file():
        try:
            ds = load_mesh_dataset(cache, dtype=dtype)
            return MeshDataset(ds.vertices, ds.faces, ds.names, f"{name}(n={n_poses}, seed={seed})",
                               {"cache": str(cache)})
        except MeshFileError:
            cache.unlink()  # stale or corrupted cache: regenerate
    verts, faces = GENERATORS[name](n_poses=n_poses, seed=seed, **geometry)
    names = [f"pose_{i:04d}" for i in range(len(verts))]
    validate_meshes(verts, faces, [f"{name}:{n}" for n in names])
    if cache is not None:
        save_mesh_dataset(cache, verts, faces, names)
    return MeshDataset(torch.as_tensor(verts, dtype=dtype), torch.as_tensor(faces, dtype=torch.long), names,
                       f"{name}(n={n_poses}, seed={seed})", {"cache": str(cache) if cache else ""})
