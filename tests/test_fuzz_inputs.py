"""Seeded fuzzing of every reader of user files: mesh files, data set folders, NPZ/HDF5 data
sets, the labeler's command line and ``neuralcol.load_run``.

Each case starts from a small valid file (an octahedron in OBJ, OFF, ASCII and binary PLY; a folder of three of
them; an array data set; a tiny run directory built in code) and breaks it: truncated at a random offset, bytes
flipped or inserted, non-UTF-8 bytes, random bytes, an empty file, a number replaced by nan/inf/1e308/a huge or
negative int, a line dropped or repeated, and hand-written cases (faces beyond the vertex count, no faces, a
folder where a file should be, wrong keys, shapes and dtypes, mismatched topology). Every case must either load
(then the result is finite and its shapes agree) or raise a :class:`UserInputError` whose one-line message names
the broken file; any other exception, or a case running past ``CASE_SECONDS``, fails. The command line must
answer a broken file with one stderr line naming it and exit code 2, and still label the good mesh beside it.
"""

from __future__ import annotations

import io
import json
import math
import re
import signal
import subprocess
import sys
import zlib
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch
import trimesh

import neuralcol
from neuralcol.collision.__main__ import main as label_cli
from neuralcol.data.datasets import load_mesh_dataset
from neuralcol.errors import UserInputError
from neuralcol.geometry.mesh_io import read_mesh

ROOT = Path(__file__).resolve().parents[1]
SEED = 30
CASE_SECONDS = 30.0  # every case takes milliseconds once the kernels are compiled; a case past this hangs


@pytest.fixture(scope="module", autouse=True)
def _compiled_kernels():
    """Compile the labeler's numba kernels before any guarded case: on a fresh clone (no numba cache) the first
    label compiles for longer than a case may take, and an alarm inside numba's compiler is no test of the input."""
    from neuralcol.collision.labeler import ExactLabeler

    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    lab = ExactLabeler(faces, verts)
    lab.label(verts)
    lab.verdict(verts)


# ---------------------------------------------------------------------------------------------- the time guard
class CaseTimeout(BaseException):
    """A case ran past ``CASE_SECONDS`` (a BaseException: a loader's ``except Exception`` cannot swallow it)."""


@contextmanager
def time_limit(seconds: float = CASE_SECONDS):
    """Raise :class:`CaseTimeout` in the block when it runs longer than ``seconds`` (SIGALRM, main thread)."""

    def on_alarm(signum, frame):
        raise CaseTimeout(f"the case ran past {seconds} s")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def load_or_user_error(load: Callable, *args, names: tuple[str, ...]):
    """``load(*args)`` under the time guard: its result, or None when it raised a one-line UserInputError naming
    one of ``names`` (any other exception propagates and fails the case)."""
    with time_limit():
        try:
            return load(*args)
        except UserInputError as exc:
            msg = str(exc)
            assert any(n in msg for n in names), f"the error names none of {names}: {msg}"
            assert "\n" not in msg, f"the error is not one line: {msg!r}"
            return None


# ---------------------------------------------------------------------------------------------- valid seeds
def octahedron(scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A closed octahedron: vertices (6, 3) float64, faces (8, 3) int64."""
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)
    f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    return v * scale, f.astype(np.int64)


def mesh_text(fmt: str, verts, faces, n_verts: object = None, n_faces: object = None) -> bytes:
    """A mesh file of format ``obj``, ``off`` or ``ply_ascii`` from rows of tokens (numbers or strings), so
    that a case can write any token; ``n_verts`` / ``n_faces`` override the counts OFF and PLY declare."""
    nv = len(verts) if n_verts is None else n_verts
    nf = len(faces) if n_faces is None else n_faces
    row = " ".join
    if fmt == "obj":  # 1-based indices; string tokens are written as they are
        obj_index = [[str(i + 1) if isinstance(i, int) else i for i in f] for f in faces]
        lines = [f"v {row(map(str, v))}" for v in verts] + [f"f {row(f)}" for f in obj_index]
    elif fmt == "off":
        lines = ["OFF", f"{nv} {nf} 0"] + [row(map(str, v)) for v in verts] + [f"3 {row(map(str, f))}" for f in faces]
    else:
        lines = ["ply", "format ascii 1.0", f"element vertex {nv}", "property float x", "property float y",
                 "property float z", f"element face {nf}", "property list uchar int vertex_indices", "end_header"]
        lines += [row(map(str, v)) for v in verts] + [f"3 {row(map(str, f))}" for f in faces]
    return ("\n".join(lines) + "\n").encode()


MESH_FORMATS = ("obj", "off", "ply_ascii", "ply_binary")


def mesh_bytes(fmt: str, scale: float = 1.0) -> bytes:
    """The valid octahedron (scaled) as the bytes of a file of format ``fmt``."""
    v, f = octahedron(scale)
    if fmt == "ply_binary":
        return trimesh.Trimesh(v, f, process=False).export(file_type="ply", encoding="binary")
    return mesh_text(fmt, v.tolist(), f.tolist())


def suffix(fmt: str) -> str:
    return "." + fmt.split("_")[0]


# ---------------------------------------------------------------------------------------------- mutators
SPECIAL_NUMBERS = (b"nan", b"inf", b"-inf", b"1e308", b"-1e308", b"1e999", b"-1", b"-100", b"99999999999999999999",
                   b"4294967296", b"0", b"0.5", b"1e-320", b"x")
NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def truncate(data: bytes, rng: np.random.Generator) -> bytes:
    return data[:int(rng.integers(0, max(len(data), 1)))]


def flip_bytes(data: bytes, rng: np.random.Generator) -> bytes:
    out = bytearray(data)
    for pos in rng.integers(0, len(out), size=int(rng.integers(1, 5))):
        out[pos] ^= int(rng.integers(1, 256))
    return bytes(out)


def insert_bytes(data: bytes, rng: np.random.Generator) -> bytes:
    pos = int(rng.integers(0, len(data) + 1))
    return data[:pos] + rng.bytes(int(rng.integers(1, 17))) + data[pos:]


def non_utf8(data: bytes, rng: np.random.Generator) -> bytes:
    pos = int(rng.integers(0, len(data) + 1))
    return data[:pos] + b"\xff\xfe\x80\xc3" + data[pos:]


def random_bytes(data: bytes, rng: np.random.Generator) -> bytes:
    return rng.bytes(int(rng.integers(1, 2 * len(data) + 2)))


def empty(data: bytes, rng: np.random.Generator) -> bytes:
    return b""


def replace_number(data: bytes, rng: np.random.Generator) -> bytes:
    """One number token (a coordinate, an index or a count) becomes nan, inf, 1e308, a huge or negative int..."""
    spans = [m.span() for m in NUMBER.finditer(data)]
    if not spans:
        return data
    a, b = spans[int(rng.integers(len(spans)))]
    return data[:a] + SPECIAL_NUMBERS[int(rng.integers(len(SPECIAL_NUMBERS)))] + data[b:]


def drop_line(data: bytes, rng: np.random.Generator) -> bytes:
    lines = data.split(b"\n")
    del lines[int(rng.integers(len(lines)))]
    return b"\n".join(lines)


def repeat_line(data: bytes, rng: np.random.Generator) -> bytes:
    lines = data.split(b"\n")
    i = int(rng.integers(len(lines)))
    return b"\n".join(lines[:i + 1] + lines[i:])


BYTE_MUTATORS = {f.__name__: f for f in (truncate, flip_bytes, insert_bytes, non_utf8, random_bytes, empty)}
MUTATORS = {**BYTE_MUTATORS, **{f.__name__: f for f in (replace_number, drop_line, repeat_line)}}


def rng_for(*key) -> np.random.Generator:
    """The generator of one case: seeded by ``SEED`` and the case's id, so every case is reproducible alone."""
    return np.random.default_rng([SEED, *(zlib.crc32(str(k).encode()) for k in key)])


def mutant(fmt: str, mutator: str, rep: int) -> bytes:
    """The valid mesh of ``fmt`` broken by ``mutator`` (its ``rep``-th draw)."""
    return MUTATORS[mutator](mesh_bytes(fmt), rng_for(fmt, mutator, rep))


# ---------------------------------------------------------------------------------------------- mesh files
def hand_written_meshes(fmt: str) -> dict[str, bytes]:
    """Broken meshes written on purpose (text formats): indices out of range, no faces, bad numbers, counts."""
    v, f = octahedron()
    v, f = v.tolist(), f.tolist()
    cases = {
        "index_beyond": mesh_text(fmt, v, [*f[:-1], [0, 3, 10**6]]),
        "index_just_beyond": mesh_text(fmt, v, [*f[:-1], [0, 3, 6]]),
        "index_negative": mesh_text(fmt, v, [*f[:-1], [0, 3, -1]]) if fmt != "obj" else
        mesh_text(fmt, v, [*f[:-1], [1, 4, "-9"]]),
        "index_float": mesh_text(fmt, v, [*f[:-1], [0, 3, "5.5"]]),
        "no_faces": mesh_text(fmt, v, []),
        "no_vertices": mesh_text(fmt, [], f),
        "nan_vertex": mesh_text(fmt, [["nan", 0, 0], *v[1:]], f),
        "inf_vertex": mesh_text(fmt, [*v[:-1], [0, "-inf", 0]], f),
        "huge_vertex": mesh_text(fmt, [*v[:-1], [0, 0, "1e308"]], f),
        "overflow_vertex": mesh_text(fmt, [*v[:-1], [0, 0, "1e999"]], f),
        "two_coordinates": mesh_text(fmt, [*v[:-1], [0, 0]], f),
        "comment_non_utf8": b"# \xff\xfe caf\xe9\n" + mesh_text(fmt, v, f) if fmt == "obj" else
        mesh_text(fmt, v, f).replace(b"\n", b"\n# \xff\xfe caf\xe9\n", 1 if fmt == "off" else 0),
    }
    if fmt != "obj":
        cases["count_huge"] = mesh_text(fmt, v, f, n_verts=10**12)
        cases["count_faces_huge"] = mesh_text(fmt, v, f, n_faces=10**12)
        cases["count_negative"] = mesh_text(fmt, v, f, n_verts=-6)
        cases["count_too_small"] = mesh_text(fmt, v, f, n_verts=3)
    return cases


def binary_ply_cases() -> dict[str, bytes]:
    """Binary PLY whose header declares other counts than its body holds."""
    data = mesh_bytes("ply_binary")
    return {"count_huge": data.replace(b"element vertex 6", b"element vertex 999999999999"),
            "count_faces_huge": data.replace(b"element face 8", b"element face 2147483647"),
            "count_too_small": data.replace(b"element vertex 6", b"element vertex 2"),
            "header_only": data[:data.index(b"end_header") + len(b"end_header\n")]}


MESH_CASES = [(fmt, m, rep) for fmt in MESH_FORMATS for m in MUTATORS for rep in range(5)
              if not (fmt == "ply_binary" and m in ("drop_line", "repeat_line"))]
HAND_CASES = [(fmt, name) for fmt in MESH_FORMATS[:3] for name in hand_written_meshes(fmt)] + \
    [("ply_binary", name) for name in binary_ply_cases()]


def hand_written(fmt: str, name: str) -> bytes:
    return binary_ply_cases()[name] if fmt == "ply_binary" else hand_written_meshes(fmt)[name]


def assert_mesh(vertices: np.ndarray, faces: np.ndarray) -> None:
    """A loaded mesh: finite (V, 3) float64 vertices, (F, 3) int64 faces within 0..V-1."""
    assert vertices.ndim == 2 and vertices.shape[1] == 3 and len(vertices) > 0 and vertices.dtype == np.float64
    assert np.isfinite(vertices).all(), "a loaded mesh has non-finite coordinates"
    assert faces.ndim == 2 and faces.shape[1] == 3 and len(faces) > 0 and faces.dtype == np.int64
    assert faces.min() >= 0 and faces.max() < len(vertices), "a loaded mesh has faces outside its vertices"


def check_read_mesh(path: Path) -> None:
    loaded = load_or_user_error(read_mesh, path, names=(str(path),))
    if loaded is not None:
        assert_mesh(*loaded)


@pytest.mark.parametrize(("fmt", "mutator", "rep"), MESH_CASES, ids=lambda x: str(x))
def test_mutated_mesh_file(tmp_path, fmt, mutator, rep):
    path = tmp_path / f"pose{suffix(fmt)}"
    path.write_bytes(mutant(fmt, mutator, rep))
    check_read_mesh(path)


@pytest.mark.parametrize(("fmt", "name"), HAND_CASES, ids=lambda x: str(x))
def test_hand_written_mesh_file(tmp_path, fmt, name):
    path = tmp_path / f"pose{suffix(fmt)}"
    path.write_bytes(hand_written(fmt, name))
    check_read_mesh(path)


@pytest.mark.parametrize("fmt", MESH_FORMATS[:2])
def test_non_utf8_comment_reads_like_the_clean_file(tmp_path, fmt):
    """Bytes that are not UTF-8 in a comment of an OBJ or OFF file (a Latin-1 export) do not matter."""
    path = tmp_path / f"pose{suffix(fmt)}"
    path.write_bytes(hand_written(fmt, "comment_non_utf8"))
    v, f = read_mesh(path)
    np.testing.assert_array_equal(v, octahedron()[0])
    np.testing.assert_array_equal(f, octahedron()[1])


@pytest.mark.parametrize("fmt", MESH_FORMATS)
def test_folder_named_like_a_mesh(tmp_path, fmt):
    path = tmp_path / f"pose{suffix(fmt)}"
    path.mkdir()
    assert load_or_user_error(read_mesh, path, names=(str(path),)) is None


# ---------------------------------------------------------------------------------------------- data set folders
def assert_dataset(ds, n: int) -> None:
    """A loaded data set of ``n`` meshes: finite vertices (n, V, 3), faces within 0..V-1, n names."""
    assert ds.vertices.ndim == 3 and ds.vertices.shape[0] == n and ds.vertices.shape[2] == 3
    assert bool(torch.isfinite(ds.vertices).all()), "a loaded data set has non-finite coordinates"
    faces = ds.faces.numpy()
    assert faces.ndim == 2 and faces.shape[1] == 3 and faces.min() >= 0 and faces.max() < ds.vertices.shape[1]
    assert len(ds.names) == n


def mesh_folder(root: Path, fmt: str) -> list[Path]:
    """A data set folder of three valid octahedra (``1``, ``2``, ``3``) in format ``fmt``; their paths."""
    root.mkdir()
    paths = [root / f"{k}{suffix(fmt)}" for k in (1, 2, 3)]
    for k, p in enumerate(paths, 1):
        p.write_bytes(mesh_bytes(fmt, 1 + 0.1 * k))
    return paths


def check_folder(folder: Path, broken: Path) -> None:
    ds = load_or_user_error(load_mesh_dataset, folder, names=(broken.name,))
    if ds is not None:
        assert_dataset(ds, 3)


FOLDER_CASES = [(fmt, m, rep) for fmt in MESH_FORMATS for m in MUTATORS for rep in range(2)
                if not (fmt == "ply_binary" and m in ("drop_line", "repeat_line"))]


@pytest.mark.parametrize(("fmt", "mutator", "rep"), FOLDER_CASES, ids=lambda x: str(x))
def test_mutated_file_in_folder(tmp_path, fmt, mutator, rep):
    paths = mesh_folder(tmp_path / "ds", fmt)
    broken = paths[0] if rep == 0 else paths[2]  # the first mesh (the template) or a later one
    broken.write_bytes(mutant(fmt, mutator, 10 + rep))
    check_folder(tmp_path / "ds", broken)


def _other_topology(path: Path, fmt: str) -> None:
    v, f = octahedron()
    path.write_bytes(mesh_text(fmt, v.tolist(), f[[1, 0, *range(2, 8)]].tolist()))


def _tetrahedron(path: Path, fmt: str) -> None:
    v = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    path.write_bytes(mesh_text(fmt, v, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))


def _no_faces(path: Path, fmt: str) -> None:
    path.write_bytes(mesh_text(fmt, octahedron()[0].tolist(), []))


def _nan(path: Path, fmt: str) -> None:
    v, f = octahedron()
    v[2, 1] = np.nan
    path.write_bytes(mesh_text(fmt, v.tolist(), f.tolist()))


def _other_format(path: Path, fmt: str) -> None:
    path.write_bytes(mesh_bytes("off" if fmt != "off" else "obj"))


FOLDER_BREAKS = {f.__name__.strip("_"): f for f in (_other_topology, _tetrahedron, _no_faces, _nan, _other_format)}


@pytest.mark.parametrize("fmt", MESH_FORMATS[:3])
@pytest.mark.parametrize("break_name", FOLDER_BREAKS)
def test_hand_written_folder(tmp_path, fmt, break_name):
    paths = mesh_folder(tmp_path / "ds", fmt)
    FOLDER_BREAKS[break_name](paths[2], fmt)
    check_folder(tmp_path / "ds", paths[2])


def test_folder_with_a_subfolder_named_like_a_mesh(tmp_path):
    mesh_folder(tmp_path / "ds", "obj")
    (tmp_path / "ds" / "4.obj").mkdir()
    assert_dataset(load_or_user_error(load_mesh_dataset, tmp_path / "ds", names=("4.obj",)), 3)


# ---------------------------------------------------------------------------------------------- NPZ / HDF5 data sets
def write_arrays(path: Path, arrays: dict) -> None:
    """An array data set file with exactly ``arrays`` (NPZ or HDF5 by the suffix)."""
    if path.suffix == ".npz":
        np.savez(path, **arrays)
    else:
        with h5py.File(path, "w") as h5:  # HDF5 stores text as bytes
            for k, a in arrays.items():
                h5[k] = a.astype("S") if a.dtype.kind == "U" else a


def valid_arrays() -> dict:
    v, f = octahedron()
    return {"vertices": np.stack([v * s for s in (1.0, 1.1, 1.2)]), "faces": f, "names": np.array(["a", "b", "c"])}


def _with(**changes) -> Callable[[], dict]:
    return lambda: {**valid_arrays(), **changes}


def _without(*keys) -> Callable[[], dict]:
    return lambda: {k: a for k, a in valid_arrays().items() if k not in keys}


V3, F0 = valid_arrays()["vertices"], octahedron()[1]
ARRAY_BREAKS = {
    "no_vertices": _without("vertices"),
    "no_faces": _without("faces"),
    "no_names": _without("names"),
    "renamed": lambda: {"verts": V3, "tris": F0},
    "vertices_2d": _with(vertices=V3[0]),
    "vertices_4d": _with(vertices=V3[None]),
    "vertices_xy": _with(vertices=V3[..., :2]),
    "vertices_scalar": _with(vertices=np.float64(1.0)),
    "vertices_zero_meshes": _with(vertices=V3[:0], names=np.array([], dtype=str)),
    "vertices_zero_vertices": _with(vertices=V3[:, :0]),
    "vertices_strings": _with(vertices=V3.astype(str)),
    "vertices_bytes": _with(vertices=V3.astype("S8")),
    "vertices_complex": _with(vertices=V3 + 1j),
    "vertices_bool": _with(vertices=V3 > 0),
    "vertices_int": _with(vertices=(V3 * 10).astype(np.int32)),
    "vertices_float16": _with(vertices=V3.astype(np.float16)),
    "vertices_nan": _with(vertices=np.where(np.arange(V3.size).reshape(V3.shape) == 7, np.nan, V3)),
    "vertices_inf": _with(vertices=np.where(np.arange(V3.size).reshape(V3.shape) == 40, -np.inf, V3)),
    "vertices_1e308": _with(vertices=V3 * 1e308),
    "faces_float": _with(faces=F0.astype(np.float64)),
    "faces_float_nan": _with(faces=np.where(F0 == 3, np.nan, F0)),
    "faces_strings": _with(faces=F0.astype(str)),
    "faces_bool": _with(faces=F0 > 2),
    "faces_quads": _with(faces=np.concatenate([F0, F0[:, :1]], 1)),
    "faces_1d": _with(faces=F0.ravel()),
    "faces_empty": _with(faces=F0[:0]),
    "faces_beyond": _with(faces=np.where(F0 == 5, 6, F0)),
    "faces_huge": _with(faces=np.where(F0 == 5, 2**62, F0)),
    "faces_negative": _with(faces=np.where(F0 == 5, -1, F0)),
    "faces_uint64_huge": _with(faces=np.where(F0 == 5, np.uint64(2**64 - 1), F0.astype(np.uint64))),
    "faces_uint8": _with(faces=F0.astype(np.uint8)),
    "names_short": _with(names=np.array(["a"])),
    "names_long": _with(names=np.array(list("abcdef"))),
    "names_2d": _with(names=np.array([["a", "b", "c"]])),
    "names_scalar": _with(names=np.array("abc")),
    "names_numbers": _with(names=np.arange(3.0)),
    "names_non_utf8": _with(names=np.array([b"\xff\xfe", b"b", b"c"])),
}
ARRAY_CASES = [(sfx, m, rep) for sfx in (".npz", ".h5") for m in BYTE_MUTATORS for rep in range(3)]


def check_array_file(path: Path) -> None:
    ds = load_or_user_error(load_mesh_dataset, path, names=(str(path),))
    if ds is not None:
        assert_dataset(ds, len(ds.vertices))
        assert len(ds.vertices) > 0


@pytest.mark.parametrize(("sfx", "mutator", "rep"), ARRAY_CASES, ids=lambda x: str(x))
def test_mutated_array_file(tmp_path, sfx, mutator, rep):
    path = tmp_path / f"ds{sfx}"
    write_arrays(path, valid_arrays())
    path.write_bytes(BYTE_MUTATORS[mutator](path.read_bytes(), rng_for(sfx, mutator, rep)))
    check_array_file(path)


@pytest.mark.parametrize("sfx", [".npz", ".h5"])
@pytest.mark.parametrize("break_name", ARRAY_BREAKS)
def test_hand_written_array_file(tmp_path, sfx, break_name):
    path = tmp_path / f"ds{sfx}"
    write_arrays(path, ARRAY_BREAKS[break_name]())
    check_array_file(path)


@pytest.mark.parametrize("sfx", [".npz", ".h5"])
def test_array_file_with_objects_or_groups(tmp_path, sfx):
    """An NPZ holding a pickled object array, an HDF5 whose 'vertices' is a group: refused, naming the file."""
    path = tmp_path / f"ds{sfx}"
    if sfx == ".npz":
        np.savez(path, vertices=np.array([V3, None], dtype=object), faces=F0)
    else:
        with h5py.File(path, "w") as h5:
            h5.create_group("vertices")["x"] = V3
            h5["faces"] = F0
    assert load_or_user_error(load_mesh_dataset, path, names=(str(path),)) is None


def test_array_file_is_a_folder(tmp_path):
    (tmp_path / "ds.npz").mkdir()
    assert load_or_user_error(load_mesh_dataset, tmp_path / "ds.npz", names=("ds.npz",)) is None


# ---------------------------------------------------------------------------------------------- the labeler CLI
def run_label_cli(*paths: Path) -> tuple[int, list[str], list[str]]:
    """``python -m neuralcol.collision PATH...`` in this process: exit code, stdout and stderr lines."""
    out, err = io.StringIO(), io.StringIO()
    with time_limit():
        code = label_cli([str(p) for p in paths], out, err)
    return code, out.getvalue().splitlines(), err.getvalue().splitlines()


def assert_labelled(line: str, path: Path) -> None:
    name, collides, pairs, pd = line.split()
    assert name == str(path) and collides in ("collides", "free") and pairs.startswith("pairs=")
    assert math.isfinite(float(pd.removeprefix("pd="))), line


CLI_CASES = [(fmt, m, rep) for fmt in MESH_FORMATS for m in MUTATORS for rep in range(2)
             if not (fmt == "ply_binary" and m in ("drop_line", "repeat_line"))]


def check_cli(bad: Path, good: Path) -> None:
    """The broken file gets one stderr line and exit code 2 (or, if it reads, a label), the good one a label."""
    code, out, err = run_label_cli(bad, good)
    assert code in (0, 1, 2), (code, err)
    if code == 2:
        assert len(err) == 1 and err[0].startswith(f"{bad}: "), err
        assert len(out) == 1, out
        assert_labelled(out[0], good)
    else:
        assert err == [] and len(out) == 2, (out, err)
        assert_labelled(out[0], bad)
        assert_labelled(out[1], good)


@pytest.mark.parametrize(("fmt", "mutator", "rep"), CLI_CASES, ids=lambda x: str(x))
def test_label_cli_mutated(tmp_path, fmt, mutator, rep):
    good, bad = tmp_path / f"good{suffix(fmt)}", tmp_path / f"bad{suffix(fmt)}"
    good.write_bytes(mesh_bytes(fmt))
    bad.write_bytes(mutant(fmt, mutator, 20 + rep))
    check_cli(bad, good)


@pytest.mark.parametrize(("fmt", "name"), HAND_CASES, ids=lambda x: str(x))
def test_label_cli_hand_written(tmp_path, fmt, name):
    good, bad = tmp_path / f"good{suffix(fmt)}", tmp_path / f"bad{suffix(fmt)}"
    good.write_bytes(mesh_bytes(fmt))
    bad.write_bytes(hand_written(fmt, name))
    check_cli(bad, good)


def test_label_cli_broken_rest_mesh(tmp_path):
    good, rest = tmp_path / "good.obj", tmp_path / "rest.obj"
    good.write_bytes(mesh_bytes("obj"))
    rest.write_bytes(mutant("obj", "truncate", 0)[:20])
    out, err = io.StringIO(), io.StringIO()
    with time_limit():
        code = label_cli([str(good), "--rest", str(rest)], out, err)
    assert code == 2 and out.getvalue() == ""
    lines = err.getvalue().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{rest}: "), lines


def test_label_cli_process_reports_broken_files_without_traceback(tmp_path):
    """The real command line (one subprocess): each broken path one stderr line, exit 2, the good mesh labelled."""
    good = tmp_path / "good.obj"
    good.write_bytes(mesh_bytes("obj"))
    broken = {tmp_path / "cut.ply": mesh_bytes("ply_binary")[:150], tmp_path / "noise.off": rng_for(1).bytes(300),
              tmp_path / "nan.obj": hand_written("obj", "nan_vertex"),
              tmp_path / "far.obj": hand_written("obj", "index_beyond")}
    for p, data in broken.items():
        p.write_bytes(data)
    (tmp_path / "dir.obj").mkdir()
    args = [*broken, tmp_path / "dir.obj", good, tmp_path / "missing.obj"]
    proc = subprocess.run([sys.executable, "-m", "neuralcol.collision", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    err = proc.stderr.splitlines()
    assert [line.split(": ", 1)[0] for line in err] == [str(p) for p in args if p != good], err
    assert len(proc.stdout.splitlines()) == 1
    assert_labelled(proc.stdout.splitlines()[0], good)


# ---------------------------------------------------------------------------------------------- load_run
def write_tiny_run(root: Path) -> Path:
    """A finished run directory with an untrained latent space and detector of the octahedron (milliseconds):
    ``.hydra/config.yaml``, ``metrics.json``, ``detector.pt`` and the cached ``latent_space.pt``. Returns the run
    directory."""
    from omegaconf import OmegaConf

    from neuralcol.nn.autoencoder import BilevelAutoencoder, Level1Autoencoder
    from neuralcol.nn.detector import detector_for_space, save_detector
    from neuralcol.nn.latent_space import LatentSpace
    from neuralcol.nn.normalizer import FeatureNormalizer
    from neuralcol.rundir import CacheDir, RunDir

    torch.manual_seed(SEED)
    v, f = octahedron()
    norm = FeatureNormalizer()
    norm.center, norm.half_range = torch.zeros(len(v), 9), torch.ones(len(v), 9)
    space = LatentSpace(BilevelAutoencoder(Level1Autoencoder(len(v), 2, hidden=4)), norm, v, f, {},
                        -torch.ones(2), torch.ones(2), torch.tensor([0, 0, 0, 1, 1, 1]), {"fuzz": True})
    run, cache = root / "run", root / "cache"
    space.save(CacheDir(cache).latent_space("k0"))
    rd = RunDir(run)
    rd.config.parent.mkdir(parents=True)
    OmegaConf.save(OmegaConf.create({"dataset": {"name": "octahedron"}, "labeling": {}, "handler": {},
                                     "detector": {"loss": {"temperature": 0.1}}, "paths": {"cache_dir": str(cache)}}),
                   rd.config)
    rd.metrics.write_text(json.dumps({"autoencoder": {"cache_key": "k0"}, "detector": {"pd_unit": 0.01}}))
    save_detector(rd.detector, detector_for_space(space, state_dim=4, hidden=8), {"net": {"state_dim": 4, "hidden": 8}},
                  {"name": "supv"}, 0.01)
    return run


RUN_FILES = {"config": ".hydra/config.yaml", "metrics": "metrics.json", "detector": "detector.pt",
             "latent_space": "../cache/autoencoders/k0/latent_space.pt"}


@pytest.fixture(scope="module")
def tiny_run_bytes(tmp_path_factory) -> dict[str, bytes]:
    """The files of the tiny run, by their key in ``RUN_FILES``."""
    run = write_tiny_run(tmp_path_factory.mktemp("tiny_run"))
    return {k: (run / rel).read_bytes() for k, rel in RUN_FILES.items()}


def tiny_run(root: Path, files: dict[str, bytes], changes: dict[str, bytes | None]) -> Path:
    """The tiny run written under ``root`` with ``changes`` (None: the file is missing). Returns the run dir."""
    from omegaconf import OmegaConf

    run = root / "run"
    for key, rel in RUN_FILES.items():
        data = changes.get(key, files[key])
        if data is None:
            continue
        (run / rel).parent.mkdir(parents=True, exist_ok=True)
        (run / rel).write_bytes(data)
    cfg_path = run / RUN_FILES["config"]
    if "config" not in changes:  # the cache of this copy
        cfg = OmegaConf.load(cfg_path)
        cfg.paths.cache_dir = str(root / "cache")
        OmegaConf.save(cfg, cfg_path)
    return run


def check_load_run(run: Path, names: tuple[str, ...]) -> None:
    """load_run either refuses naming one of ``names``, or gives a run whose detector answers finitely."""
    loaded = load_or_user_error(neuralcol.load_run, run, names=names)
    if loaded is None:
        return
    with loaded, time_limit():
        det = loaded.detect(torch.zeros(2, loaded.dim))
        assert det.prob.shape == (2,) and bool(torch.isfinite(det.prob).all() and torch.isfinite(det.pd).all())
        assert bool(torch.isfinite(loaded.decode(torch.zeros(1, loaded.dim))).all())


def test_tiny_run_loads(tmp_path, tiny_run_bytes):
    run = tiny_run(tmp_path, tiny_run_bytes, {})
    with neuralcol.load_run(run) as loaded:
        assert loaded.dim == 2


@pytest.mark.parametrize("stray", [b"", b"\x80\x04junk", b"PK\x03\x04 not a zip"])
def test_a_stray_mesh_detector_file_is_never_read(tmp_path, tiny_run_bytes, stray):
    """Older runs may hold mesh_detector.pt (the separate mesh detector, folded into the run's detector):
    whatever it holds, load_run ignores it."""
    run = tiny_run(tmp_path, tiny_run_bytes, {})
    (run / "mesh_detector.pt").write_bytes(stray)
    check_load_run(run, ())  # (names nothing: any UserInputError fails the case)


RUN_CASES = [(key, m, rep) for key in RUN_FILES for m in BYTE_MUTATORS for rep in range(3)]


def run_error_names(keys) -> tuple[str, ...]:
    """The file names an error about the run files ``keys`` may name: the files themselves, and the latent space
    where the config or the metrics changed (a changed cache_dir or cache key points at a missing one)."""
    names = tuple(Path(RUN_FILES[k]).name for k in keys)
    return names + (("latent_space.pt",) if {"config", "metrics"} & set(keys) else ())


@pytest.mark.parametrize(("key", "mutator", "rep"), RUN_CASES, ids=lambda x: str(x))
def test_mutated_run_file(tmp_path, tiny_run_bytes, key, mutator, rep):
    data = BYTE_MUTATORS[mutator](tiny_run_bytes[key], rng_for(key, mutator, rep))
    run = tiny_run(tmp_path, tiny_run_bytes, {key: data})
    check_load_run(run, run_error_names([key]))


def _torch_bytes(obj) -> bytes:
    buf = io.BytesIO()
    torch.save(obj, buf)
    return buf.getvalue()


def _detector_blob(files: dict, **changes) -> bytes:
    blob = torch.load(io.BytesIO(files["detector"]), weights_only=False)
    return _torch_bytes({**blob, **changes})


RUN_BREAKS = {
    "config_missing": lambda files: {"config": None},
    "metrics_missing": lambda files: {"metrics": None},
    "detector_missing": lambda files: {"detector": None},
    "latent_space_missing": lambda files: {"latent_space": None},
    "config_list": lambda files: {"config": b"- 1\n- 2\n"},
    "config_scalar": lambda files: {"config": b"just text\n"},
    "config_no_paths": lambda files: {"config": b"dataset: {}\nlabeling: {}\ndetector: {}\nhandler: {}\n"},
    "config_paths_scalar": lambda files: {"config": b"dataset: {}\nlabeling: {}\ndetector: 3\nhandler: {}\npaths: 3\n"},
    "config_interpolation": lambda files: {"config": files["config"].replace(b"temperature: 0.1",
                                                                              b"temperature: ${nowhere}")},
    "config_temperature_text": lambda files: {"config": files["config"].replace(b"temperature: 0.1",
                                                                                 b"temperature: hot")},
    "metrics_list": lambda files: {"metrics": b"[1, 2]"},
    "metrics_nan": lambda files: {"metrics": b'{"autoencoder": {"cache_key": "k0"}, "detector": {"pd_unit": NaN}}'},
    "metrics_key_number": lambda files: {"metrics": b'{"autoencoder": {"cache_key": 5}, "detector": {}}'},
    "metrics_key_path": lambda files: {"metrics": b'{"autoencoder": {"cache_key": "../../x"}, "detector": {}}'},
    "metrics_no_pd_unit": lambda files: {"metrics": b'{"autoencoder": {"cache_key": "k0"}, "detector": {}}',
                                         "detector": _detector_blob(files, pd_unit=None)},
    "metrics_non_utf8": lambda files: {"metrics": b'{"autoencoder": {"cache_key": "k\xff"}, "detector": {}}'},
    "detector_tensor": lambda files: {"detector": _torch_bytes(torch.zeros(3))},
    "detector_empty_dict": lambda files: {"detector": _torch_bytes({})},
    "detector_wrong_sizes": lambda files: {"detector": _detector_blob(files, n_components=3)},
    "detector_no_state": lambda files: {"detector": _detector_blob(files, state={})},
    "detector_nan_weights": lambda files: {"detector": _detector_blob(files, state={
        k: torch.full_like(t, float("nan")) if t.is_floating_point() else t
        for k, t in torch.load(io.BytesIO(files["detector"]), weights_only=False)["state"].items()})},
    "detector_pd_unit_text": lambda files: {"detector": _detector_blob(files, pd_unit="big")},
    "latent_space_list": lambda files: {"latent_space": _torch_bytes([1, 2])},
}


@pytest.mark.parametrize("break_name", RUN_BREAKS)
def test_hand_written_run(tmp_path, tiny_run_bytes, break_name):
    changes = RUN_BREAKS[break_name](tiny_run_bytes)
    run = tiny_run(tmp_path, tiny_run_bytes, changes)
    check_load_run(run, run_error_names(changes))


def test_run_file_is_a_folder(tmp_path, tiny_run_bytes):
    run = tiny_run(tmp_path, tiny_run_bytes, {"detector": None})
    (run / "detector.pt").mkdir()
    check_load_run(run, ("detector.pt",))
