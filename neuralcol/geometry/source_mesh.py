"""A user's mesh file read with its own structure and written back with only the vertex positions changed.

``neuralcol check`` and ``neuralcol resolve`` read what DCC tools, scanners and game assets write: OBJ (triangles,
quads, polygons, with ``vt``/``vn``/groups/materials, several objects), OFF, PLY (ascii and binary, any extra vertex
and face properties, faces or triangle strips), STL (ascii and binary triangle soups), glTF/GLB (the default scene's
triangle primitives, placed by their nodes) and arrays (``.npz`` with ``vertices`` and ``faces``; its other arrays are
written back as they were). :func:`read_source` gives the
mesh the labeler needs, with vertices in the file's order and each polygon fan-triangulated, and keeps the file's
bytes; :meth:`SourceMesh.write` writes the same file with the vertex positions replaced and nothing else changed:
faces in the file's order (quads stay quads), texture coordinates, materials, groups, colours, comments and PLY
properties as they were, OBJ normals (``vn``) recomputed where a moved vertex's faces use them, STL facet normals
recomputed. Positions are written exactly: as the shortest decimal that reads back to the same float64 in text
formats, as the file's own type (float32 in most PLY and every binary STL) in binary ones, which
:meth:`SourceMesh.stored` gives so a caller can check what the file will hold.

An STL file stores each triangle's three corners apart; corners at exactly the same coordinates are merged into one
vertex (``merged`` says how many), so the verdict sees the mesh's real topology, and each corner is written back
from its vertex.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from neuralcol.errors import MeshFileError
from neuralcol.geometry.topology import check_coordinates, check_face_indices

SOURCE_SUFFIXES = (".obj", ".off", ".ply", ".stl", ".glb", ".gltf", ".npz")


@dataclass
class SourceMesh:
    """One mesh file as read (module docstring).

    Attributes:
        path: the file. kind: ``obj``, ``off``, ``ply`` or ``stl``.
        vertices: (V, 3) float64 positions in the file's vertex order (STL: the merged corners, in first-use order).
        faces: (F, 3) int64 triangles, each file face fan-triangulated in the file's face order.
        face_of_triangle: (F,) int64 the file face each triangle comes from.
        n_file_faces: faces (polygons, strips' triangles, facets) in the file.
        merged: STL only: corners merged into vertices (3 x facets - V); 0 elsewhere.
    """

    path: Path
    kind: str
    vertices: np.ndarray
    faces: np.ndarray
    face_of_triangle: np.ndarray
    n_file_faces: int
    merged: int = 0
    _data: bytes = field(default=b"", repr=False)
    _state: dict = field(default_factory=dict, repr=False)

    @property
    def sidecars(self) -> bool:
        """The file refers to files beside it (a .gltf's separate buffers), which a copy must take along."""
        return self.kind == "gltf" and not self._state["binary"] and any(
            "uri" in b and not b["uri"].startswith("data:") for b in self._state["doc"].get("buffers", []))

    @property
    def polygons(self) -> bool:
        """Some file face is not a triangle."""
        return len(self.faces) != self.n_file_faces or self.kind == "ply" and self._state.get("strips", False)

    def stored(self, vertices: np.ndarray) -> np.ndarray:
        """``vertices`` (V, 3) as this file will hold them once written: rounded to the file's float32 where its
        positions are float32 (binary STL, PLY with ``float`` coordinates, glTF: in each node's own frame), as they
        are otherwise."""
        v = np.asarray(vertices, np.float64)
        if self.kind == "gltf":
            return _gltf_stored(self, v)
        return v.astype(np.float32).astype(np.float64) if self._state.get("float32", False) else v.copy()

    def file_pairs(self, pairs: np.ndarray, keep_self: bool = False) -> np.ndarray:
        """Triangle pairs (P, 2) as pairs of the file's faces (sorted, unique). A pair within one file face is dropped
        (a polygon's own triangles), unless ``keep_self`` and the pair is a triangle with itself (CGAL's rule reports a
        degenerate face so)."""
        t = np.asarray(pairs, np.int64).reshape(-1, 2)
        p = np.sort(self.face_of_triangle[t], axis=1)
        p = p[(p[:, 0] != p[:, 1]) | (keep_self & (t[:, 0] == t[:, 1]))]
        return np.unique(p, axis=0) if len(p) else np.zeros((0, 2), np.int64)

    def to_bytes(self, vertices: np.ndarray) -> bytes:
        """The file with its vertex positions replaced by ``vertices`` (V, 3) (module docstring)."""
        v = np.asarray(vertices, np.float64)
        if v.shape != self.vertices.shape:
            raise ValueError(f"{self.path}: vertices have shape {v.shape}, expected {self.vertices.shape}")
        if np.array_equal(v, self.vertices):
            return self._data
        return _WRITERS[self.kind](self, v)

    def write(self, path: str | Path, vertices: np.ndarray, overwrite: bool = False) -> Path:
        """Write the file with ``vertices`` to ``path`` (through a temporary file beside it, then renamed). Writing
        over the file that was read needs ``overwrite``."""
        path = Path(path)
        if not overwrite and path.exists() and path.resolve() == self.path.resolve():
            raise MeshFileError(f"{path}: is the input file; write the result elsewhere (or ask to overwrite it)")
        path.parent.mkdir(parents=True, exist_ok=True)
        files = {path: self.to_bytes(vertices)}
        if self.kind == "gltf" and not self._state["binary"]:  # a .gltf's separate buffers go beside it
            if files[path] is self._data:  # unchanged: its buffers as read
                self._state["external"] = {b["uri"]: bytes(self._state["buffers"][k])
                                           for k, b in enumerate(self._state["doc"].get("buffers", []))
                                           if "uri" in b and not b["uri"].startswith("data:")}
            for uri, blob in self._state["external"].items():
                target = path.parent / uri
                if not overwrite and target.exists() and target.resolve() == (self.path.parent / uri).resolve():
                    raise MeshFileError(f"{target}: is the input's buffer; write the result elsewhere (or ask to "
                                        "overwrite it)")
                files[target] = blob
        for target, blob in files.items():
            tmp = target.with_name(target.name + ".tmp")
            tmp.write_bytes(blob)
            tmp.replace(target)
        return path


def read_source(path: str | Path) -> SourceMesh:
    """Read one mesh file with its structure (module docstring); MeshFileError with a one-line reason otherwise."""
    path = Path(path)
    if not path.is_file():
        raise MeshFileError(f"{path}: no such file")
    kind = path.suffix.lower().lstrip(".")
    if f".{kind}" not in SOURCE_SUFFIXES:
        raise MeshFileError(f"{path}: unsupported mesh format '{path.suffix}'; use one of {', '.join(SOURCE_SUFFIXES)}")
    data = path.read_bytes()
    try:
        mesh = _READERS[kind](path, data)
    except MeshFileError as exc:
        raise MeshFileError(f"{path}: {exc}") from exc
    except Exception as exc:  # a malformed file: one line, naming the file
        reason = " ".join(str(exc).split())[:200]
        raise MeshFileError(f"{path}: cannot be read as a {kind.upper()} mesh ({type(exc).__name__}: "
                            f"{reason})") from exc
    if len(mesh.vertices) == 0 or len(mesh.faces) == 0:
        raise MeshFileError(f"{path}: holds no triangle mesh ({len(mesh.vertices)} vertices, {len(mesh.faces)} "
                            "triangles)")
    check_face_indices(mesh.faces, len(mesh.vertices), str(path))
    check_coordinates(mesh.vertices, str(path))
    return mesh


# --------------------------------------------------------------------------------------------- shared pieces
def _fan(polygons: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    """Each polygon (v0, v1, ..., vk) as the triangles (v0, vi, vi+1): (F, 3) and the polygon of each."""
    tris, owner = [], []
    for k, poly in enumerate(polygons):
        for i in range(1, len(poly) - 1):
            tris.append((poly[0], poly[i], poly[i + 1]))
            owner.append(k)
    return np.array(tris, np.int64).reshape(-1, 3), np.array(owner, np.int64)


def _fmt(x: float) -> str:
    """The shortest decimal that reads back to the same float64."""
    return repr(float(x))


def _replace_xyz(line: str, xyz: np.ndarray, first: int) -> str:
    """``line`` with its whitespace-separated tokens ``first``..``first + 2`` replaced by ``xyz``; its other tokens,
    the whitespace before the first token and the line ending kept."""
    body = line.rstrip("\r\n")
    ending = line[len(body):]
    lead = body[:len(body) - len(body.lstrip())]
    tokens = body.split()
    tokens[first:first + 3] = [_fmt(c) for c in xyz]
    return lead + " ".join(tokens) + ending


def _decode(data: bytes) -> str:
    """Text of a text mesh file; bytes that are not UTF-8 survive the round trip (surrogate escapes)."""
    return data.decode("utf-8", errors="surrogateescape")


def _encode(text: str) -> bytes:
    return text.encode("utf-8", errors="surrogateescape")


def _unit(n: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


# --------------------------------------------------------------------------------------------- OBJ
def _obj_index(token: str, count: int, what: str) -> int:
    """A corner's 0-based index into the ``count`` elements defined so far (OBJ: 1-based, negative relative)."""
    i = int(token)
    if i < 0:
        i += count  # relative to the elements read so far
    else:
        i -= 1
    if not 0 <= i < count:
        raise MeshFileError(f"a face refers to {what} {token}, outside the {count} defined before it")
    return i


def _obj_normal(token: str, count: int) -> int:
    """A corner's ``vn`` index, or -1 where it names none that exists (the geometry does not depend on it)."""
    i = int(token)
    i = i + count if i < 0 else i - 1
    return i if 0 <= i < count else -1


def _read_obj(path: Path, data: bytes) -> SourceMesh:
    lines = _decode(data).splitlines(keepends=True)
    v_lines, vn_lines, xyz = [], [], []
    polygons, normals = [], []  # per face: vertex ids; normal ids (-1: none)
    pending = ""
    for k, line in enumerate(lines):
        if line.rstrip().endswith("\\"):  # a statement continued on the next line
            pending += line.rstrip()[:-1] + " "
            continue
        tok = (pending + line).split()
        pending = ""
        if not tok:
            continue
        head = tok[0]
        if head == "v":
            xyz.append((float(tok[1]), float(tok[2]), float(tok[3])))
            v_lines.append(k)
        elif head == "vn":
            vn_lines.append(k)
        elif head == "f":
            ids, nids = [], []
            for corner in tok[1:]:
                parts = corner.split("/")
                ids.append(_obj_index(parts[0], len(xyz), "vertex"))
                nids.append(_obj_normal(parts[2], len(vn_lines)) if len(parts) > 2 and parts[2] else -1)
            if len(ids) < 3:
                continue  # a face of fewer than three corners bounds nothing (kept in the file as it is)
            polygons.append(ids)
            normals.append(nids)
    faces, owner = _fan(polygons)
    mesh = SourceMesh(path, "obj", np.array(xyz, np.float64).reshape(-1, 3), faces, owner, len(polygons), _data=data)
    mesh._state.update(lines=lines, v_lines=v_lines, vn_lines=vn_lines, polygons=polygons, normals=normals)
    return mesh


def _write_obj(mesh: SourceMesh, v: np.ndarray) -> bytes:
    st = mesh._state
    lines = list(st["lines"])
    moved = np.flatnonzero((v != mesh.vertices).any(1))
    for i in moved:
        lines[st["v_lines"][i]] = _replace_xyz(lines[st["v_lines"][i]], v[i], 1)
    if st["vn_lines"] and len(moved):
        for n, value in _obj_normals(mesh, v, moved).items():
            lines[st["vn_lines"][n]] = _replace_xyz(lines[st["vn_lines"][n]], value, 1)
    return _encode("".join(lines))


def _obj_normals(mesh: SourceMesh, v: np.ndarray, moved: np.ndarray) -> dict[int, np.ndarray]:
    """The ``vn`` entries used by a face corner at a moved vertex's faces, recomputed: the area-weighted sum of the
    normals of every face corner that uses the entry (a smooth vertex normal, a flat face normal or a hard-edge
    group's, as the file shares it), its sign that of the file's normal."""
    st = mesh._state
    is_moved = np.zeros(len(v), bool)
    is_moved[moved] = True
    touched = {n for poly, ns in zip(st["polygons"], st["normals"]) if is_moved[poly].any() for n in ns if n >= 0}
    if not touched:
        return {}
    acc_new = {n: np.zeros(3) for n in touched}
    acc_old = {n: np.zeros(3) for n in touched}
    for poly, ns in zip(st["polygons"], st["normals"]):
        if not any(n in touched for n in ns):
            continue
        p_new, p_old = v[poly], mesh.vertices[poly]
        n_new = sum(np.cross(p_new[i] - p_new[0], p_new[i + 1] - p_new[0]) for i in range(1, len(poly) - 1))
        n_old = sum(np.cross(p_old[i] - p_old[0], p_old[i + 1] - p_old[0]) for i in range(1, len(poly) - 1))
        for n in ns:
            if n in touched:
                acc_new[n] += n_new
                acc_old[n] += n_old
    out = {}
    for n in touched:
        tok = st["lines"][st["vn_lines"][n]].split()
        stated = np.array([float(t) for t in tok[1:4]])
        sign = -1.0 if float(acc_old[n] @ stated) < 0 else 1.0  # the file's normals may face the other way
        out[n] = sign * _unit(acc_new[n])
    return out


# --------------------------------------------------------------------------------------------- OFF
def _read_off(path: Path, data: bytes) -> SourceMesh:
    lines = _decode(data).splitlines(keepends=True)
    records = [(k, line.split("#", 1)[0].split()) for k, line in enumerate(lines)]
    records = [(k, tok) for k, tok in records if tok]
    if not records:
        raise MeshFileError("an empty file")
    _, head = records[0]
    glued = re.match(r"^([A-Za-z]*OFF)(\S+)$", head[0])
    if glued:  # "OFF8 6 12": the vertex count written against the keyword
        head = [glued.group(1), glued.group(2), *head[1:]]
    if not head[0].upper().endswith("OFF"):
        raise MeshFileError(f"does not start with OFF (found {head[0]!r})")
    counts = head[1:] if len(head) > 1 else records[1][1]
    start = 1 if len(head) > 1 else 2
    n_v, n_f = int(counts[0]), int(counts[1])
    body = records[start:]
    if len(body) < n_v + n_f:
        raise MeshFileError(f"declares {n_v} vertices and {n_f} faces, holds {len(body)} records")
    v_lines = [k for k, _ in body[:n_v]]
    xyz = np.array([[float(t) for t in tok[:3]] for _, tok in body[:n_v]], np.float64).reshape(-1, 3)
    polygons = []
    for _, tok in body[n_v:n_v + n_f]:
        n = int(tok[0])
        polygons.append([int(t) for t in tok[1:1 + n]])
    faces, owner = _fan(polygons)
    mesh = SourceMesh(path, "off", xyz, faces, owner, n_f, _data=data)
    mesh._state.update(lines=lines, v_lines=v_lines)
    return mesh


def _write_off(mesh: SourceMesh, v: np.ndarray) -> bytes:
    lines = list(mesh._state["lines"])
    for i in np.flatnonzero((v != mesh.vertices).any(1)):
        k = mesh._state["v_lines"][i]
        body = lines[k].rstrip("\r\n")
        ending = lines[k][len(body):]
        cut = body.find("#")
        head, tail = (body, "") if cut < 0 else (body[:cut], body[cut:])
        lines[k] = _replace_xyz(head, v[i], 0).rstrip() + (" " + tail if tail else "") + ending
    return _encode("".join(lines))


# --------------------------------------------------------------------------------------------- PLY
_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _ply_header(data: bytes):
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise MeshFileError("no PLY header (ply ... end_header)")
    stop = data.find(b"\n", end) + 1
    header = data[:stop].decode("ascii", errors="replace").splitlines()
    fmt, elements = None, []
    for line in header:
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            elements.append({"name": tok[1], "count": int(tok[2]), "props": []})
        elif tok[0] == "property":
            if not elements:
                raise MeshFileError("a property before any element")
            if tok[1] == "list":
                elements[-1]["props"].append((tok[4], "list", _PLY_TYPES[tok[2]], _PLY_TYPES[tok[3]]))
            else:
                elements[-1]["props"].append((tok[2], _PLY_TYPES[tok[1]]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise MeshFileError(f"unknown PLY format {fmt!r}")
    return fmt, elements, stop


def _read_ply(path: Path, data: bytes) -> SourceMesh:
    fmt, elements, offset = _ply_header(data)
    state = {"fmt": fmt, "elements": elements}
    values: dict[str, list] = {}
    if fmt == "ascii":
        lines = _decode(data[offset:]).splitlines(keepends=True)
        row = 0
        for el in elements:
            recs, el["rows"] = [], []
            for _ in range(el["count"]):
                while row < len(lines) and not lines[row].split():
                    row += 1
                recs.append(lines[row].split())
                el["rows"].append(row)
                row += 1
            values[el["name"]] = (el, recs)
        state.update(lines=lines, head=data[:offset])
    else:
        end = "<" if fmt == "binary_little_endian" else ">"
        for el in elements:
            el["offset"] = offset
            if all(p[1] != "list" for p in el["props"]):
                dt = np.dtype([(p[0], end + p[1]) for p in el["props"]])
                arr = np.frombuffer(data, dt, el["count"], offset)
                offset += dt.itemsize * el["count"]
                values[el["name"]] = (el, arr)
            else:
                recs, offset = _ply_binary_lists(data, el, offset, end)
                values[el["name"]] = (el, recs)
            el["end"] = offset
    vert = values.get("vertex")
    if vert is None:
        raise MeshFileError("no vertex element")
    el, recs = vert
    names = [p[0] for p in el["props"]]
    if not {"x", "y", "z"} <= set(names):
        raise MeshFileError("the vertex element has no x, y, z")
    if fmt == "ascii":
        cols = [names.index(c) for c in "xyz"]
        if any(p[1] == "list" for p in el["props"]):
            raise MeshFileError("list properties on vertices are not supported")
        xyz = np.array([[r[c] for c in cols] for r in recs], np.float64).reshape(-1, 3)
        kinds = {p[0]: p[1] for p in el["props"]}
        for j, c in enumerate("xyz"):  # a float32 coordinate is the float32 nearest its text, as the file types it
            if kinds[c] == "f4":
                with np.errstate(over="ignore"):  # (a value past float32's range is inf: refused below)
                    xyz[:, j] = xyz[:, j].astype(np.float32)
    else:
        xyz = np.stack([np.asarray(recs[c], np.float64) for c in "xyz"], 1)
    types = {p[0]: p[1] for p in el["props"] if p[1] != "list"}
    state["float32"] = any(types[c] == "f4" for c in "xyz")
    polygons, strips = _ply_faces(values, fmt)
    state["strips"] = strips
    faces, owner = _fan(polygons)
    mesh = SourceMesh(path, "ply", xyz, faces, owner, len(polygons), _data=data)
    mesh._state.update(state)
    return mesh


def _ply_binary_lists(data: bytes, el: dict, offset: int, end: str):
    """Records of an element with list properties, as dicts; all lists of one length read at once, else one by
    one."""
    props = el["props"]
    n = el["count"]
    if len(props) >= 1 and props[0][1] == "list" and n:
        count_t = np.dtype(end + props[0][2])
        k = int(np.frombuffer(data, count_t, 1, offset)[0])
        fields = [("n", end + props[0][2]), (props[0][0], end + props[0][3], (k,))]
        if all(p[1] != "list" for p in props[1:]):
            fields += [(p[0], end + p[1]) for p in props[1:]]
            dt = np.dtype(fields)
            if offset + dt.itemsize * n <= len(data):
                arr = np.frombuffer(data, dt, n, offset)
                if (arr["n"] == k).all():
                    return [{props[0][0]: row} for row in arr[props[0][0]]], offset + dt.itemsize * n
    recs = []
    for _ in range(n):
        rec = {}
        for p in props:
            if p[1] == "list":
                ct, it = np.dtype(end + p[2]), np.dtype(end + p[3])
                m = int(np.frombuffer(data, ct, 1, offset)[0])
                offset += ct.itemsize
                rec[p[0]] = np.frombuffer(data, it, m, offset)
                offset += it.itemsize * m
            else:
                t = np.dtype(end + p[1])
                rec[p[0]] = np.frombuffer(data, t, 1, offset)[0]
                offset += t.itemsize
        recs.append(rec)
    return recs, offset


def _ply_faces(values: dict, fmt: str) -> tuple[list[list[int]], bool]:
    """Polygons of the face element, or the triangles of a tristrips element (strips split at -1, every other
    triangle flipped to keep the winding)."""
    for name, strips in (("face", False), ("tristrips", True)):
        if name not in values:
            continue
        el, recs = values[name]
        lists = [p for p in el["props"] if p[1] == "list"]
        if not lists:
            continue
        key = next((p[0] for p in lists if p[0] in ("vertex_indices", "vertex_index")), lists[0][0])
        col = [p[0] for p in el["props"]].index(key)
        if fmt == "ascii":
            rows = []
            for r in recs:  # (a list: its count, then its items; scalars before it are one token each)
                at = 0
                for p in el["props"][:col]:
                    at += 1 if p[1] != "list" else 1 + int(r[at])
                m = int(r[at])
                rows.append([int(t) for t in r[at + 1:at + 1 + m]])
        else:
            rows = [[int(i) for i in rec[key]] for rec in recs]
        if not strips:
            return rows, False
        tris = []
        for row in rows:
            run: list[int] = []
            for i in [*row, -1]:
                if i >= 0:
                    run.append(i)
                    continue
                for j in range(len(run) - 2):
                    a, b, c = run[j], run[j + 1], run[j + 2]
                    if a != b and b != c and a != c:
                        tris.append([a, b, c] if j % 2 == 0 else [b, a, c])
                run = []
        return tris, True
    return [], False


def _write_ply(mesh: SourceMesh, v: np.ndarray) -> bytes:
    st = mesh._state
    el = next(e for e in st["elements"] if e["name"] == "vertex")
    if st["fmt"] == "ascii":
        lines = list(st["lines"])
        names = [p[0] for p in el["props"]]
        types = {p[0]: p[1] for p in el["props"]}
        for i in np.flatnonzero((v != mesh.vertices).any(1)):
            k = el["rows"][i]
            tok = lines[k].rstrip("\r\n").split()
            for c, value in zip("xyz", v[i]):  # float32 coordinates as the shortest text of their float32
                tok[names.index(c)] = str(np.float32(value)) if types[c] == "f4" else _fmt(value)
            ending = lines[k][len(lines[k].rstrip("\r\n")):]
            lines[k] = " ".join(tok) + ending
        return st["head"] + _encode("".join(lines))
    end = "<" if st["fmt"] == "binary_little_endian" else ">"
    buf = bytearray(mesh._data)
    dt = np.dtype([(p[0], end + p[1]) for p in el["props"]])
    arr = np.frombuffer(buf, dt, el["count"], el["offset"])
    for j, c in enumerate("xyz"):
        arr[c] = v[:, j].astype(arr.dtype[c])
    return bytes(buf)


# --------------------------------------------------------------------------------------------- STL
def _read_stl(path: Path, data: bytes) -> SourceMesh:
    binary = len(data) >= 84 and 84 + 50 * struct.unpack("<I", data[80:84])[0] == len(data)
    if binary:
        n = struct.unpack("<I", data[80:84])[0]
        dt = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attr", "<u2")])
        rec = np.frombuffer(data, dt, n, 84)
        corners = rec["corners"].astype(np.float64).reshape(-1, 3)
    else:
        text = _decode(data)
        if not text.lstrip().lower().startswith("solid"):
            raise MeshFileError("neither binary STL (size 84 + 50 x facets) nor ASCII STL (solid ...)")
        nums = re.findall(r"^\s*vertex\s+(\S+)\s+(\S+)\s+(\S+)", text, re.M | re.I)
        corners = np.array(nums, np.float64).reshape(-1, 3)
        if len(corners) % 3:
            raise MeshFileError(f"{len(corners)} vertex lines: not three per facet")
        n = len(corners) // 3
    uniq, first, inverse = np.unique(corners, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # vertices in the order the file first uses them
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    vertices = uniq[order]
    corner_vertex = rank[np.asarray(inverse).reshape(-1)]
    faces = corner_vertex.reshape(-1, 3)
    mesh = SourceMesh(path, "stl", vertices, faces, np.arange(n, dtype=np.int64), n, merged=int(3 * n - len(vertices)),
                      _data=data)
    mesh._state.update(binary=binary, float32=binary, corner_vertex=corner_vertex)
    return mesh


def _write_stl(mesh: SourceMesh, v: np.ndarray) -> bytes:
    corners = v[mesh._state["corner_vertex"]].reshape(-1, 3, 3)
    if mesh._state["binary"]:
        c32 = corners.astype(np.float32)
        buf = bytearray(mesh._data)
        dt = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attr", "<u2")])
        rec = np.frombuffer(buf, dt, len(corners), 84)
        c = c32.astype(np.float64)
        rec["normal"] = _unit(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])).astype(np.float32)
        rec["corners"] = c32
        return bytes(buf)
    text = _decode(mesh._data)
    first = text.lstrip().splitlines()[0].strip()
    name = first[5:].strip() if first.lower().startswith("solid") else ""
    normals = _unit(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
    out = [f"solid {name}".rstrip() + "\n"]
    for n, tri in zip(normals, corners):
        out.append(f"  facet normal {_fmt(n[0])} {_fmt(n[1])} {_fmt(n[2])}\n    outer loop\n")
        out += [f"      vertex {_fmt(p[0])} {_fmt(p[1])} {_fmt(p[2])}\n" for p in tri]
        out.append("    endloop\n  endfacet\n")
    out.append(f"endsolid {name}".rstrip() + "\n")
    return _encode("".join(out))


# --------------------------------------------------------------------------------------------- glTF / GLB
_GLTF_TYPES = {5120: "i1", 5121: "u1", 5122: "i2", 5123: "u2", 5125: "u4", 5126: "f4"}
_GLTF_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def _gltf_parts(path: Path, data: bytes) -> tuple[dict, list[bytearray], bool]:
    """The glTF JSON, its buffers (bytearrays) and whether the file is binary (GLB)."""
    import base64
    import json

    if data[:4] == b"glTF":
        length = struct.unpack("<I", data[8:12])[0]
        at, doc, chunks = 12, None, []
        while at < min(length, len(data)):
            size, kind = struct.unpack("<II", data[at:at + 8])
            body = data[at + 8:at + 8 + size]
            if kind == 0x4E4F534A:
                doc = json.loads(body.decode("utf-8"))
            elif kind == 0x004E4942:
                chunks.append(bytearray(body))
            at += 8 + size
        if doc is None:
            raise MeshFileError("a GLB without a JSON chunk")
        buffers = []
        for buf in doc.get("buffers", []):
            buffers.append(chunks[0] if "uri" not in buf and chunks else _gltf_uri(path, buf, base64))
        return doc, buffers, True
    doc = json.loads(data.decode("utf-8"))
    return doc, [_gltf_uri(path, buf, base64) for buf in doc.get("buffers", [])], False


def _gltf_uri(path: Path, buf: dict, base64) -> bytearray:
    uri = buf.get("uri", "")
    if uri.startswith("data:"):
        return bytearray(base64.b64decode(uri.split(",", 1)[1]))
    target = path.parent / uri
    if not target.is_file():
        raise MeshFileError(f"its buffer {uri!r} is not beside it")
    return bytearray(target.read_bytes())


def _gltf_view(doc: dict, buffers: list, index: int) -> np.ndarray:
    """Accessor ``index`` as a (count, width) array view into its buffer (strided views kept writable)."""
    acc = doc["accessors"][index]
    if "sparse" in acc or "bufferView" not in acc:
        raise MeshFileError(f"accessor {index} is sparse or has no buffer view: not supported")
    view = doc["bufferViews"][acc["bufferView"]]
    dtype = np.dtype("<" + _GLTF_TYPES[acc["componentType"]])
    width = _GLTF_WIDTH[acc["type"]]
    stride = view.get("byteStride") or dtype.itemsize * width
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    buf = buffers[view["buffer"]]
    return np.ndarray((acc["count"], width), dtype, buffer=buf, offset=start, strides=(stride, dtype.itemsize))


def _gltf_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.array(node["matrix"], np.float64).reshape(4, 4).T  # column-major in the file
    t = np.array(node.get("translation", [0, 0, 0]), np.float64)
    x, y, z, w = node.get("rotation", [0, 0, 0, 1])
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = r * np.array(node.get("scale", [1, 1, 1]), np.float64)[None, :]
    m[:3, 3] = t
    return m


def _read_gltf(path: Path, data: bytes) -> SourceMesh:
    doc, buffers, binary = _gltf_parts(path, data)
    scenes = doc.get("scenes", [])
    roots = scenes[doc.get("scene", 0)]["nodes"] if scenes else list(range(len(doc.get("nodes", []))))
    blocks, xyz, tris, owner = [], [], [], []
    stack = [(n, np.eye(4)) for n in roots]
    while stack:
        n, parent = stack.pop(0)
        node = doc["nodes"][n]
        world = parent @ _gltf_matrix(node)
        stack += [(c, world) for c in node.get("children", [])]
        if "mesh" not in node:
            continue
        for pk, prim in enumerate(doc["meshes"][node["mesh"]]["primitives"]):
            mode = prim.get("mode", 4)
            if mode not in (4, 5, 6) or "POSITION" not in prim["attributes"]:
                continue  # points and lines bound nothing
            local = _gltf_view(doc, buffers, prim["attributes"]["POSITION"]).astype(np.float64)
            idx = (_gltf_view(doc, buffers, prim["indices"])[:, 0].astype(np.int64) if "indices" in prim
                   else np.arange(len(local)))
            if mode == 4:
                t = idx.reshape(-1, 3)
            elif mode == 5:  # strip: every other triangle flipped to keep the winding
                t = np.array([(idx[i], idx[i + 1], idx[i + 2]) if i % 2 == 0 else (idx[i + 1], idx[i], idx[i + 2])
                              for i in range(len(idx) - 2)], np.int64).reshape(-1, 3)
            else:  # fan
                t = np.array([(idx[0], idx[i], idx[i + 1]) for i in range(1, len(idx) - 1)], np.int64).reshape(-1, 3)
            base = sum(len(x) for x in xyz)
            xyz.append(local @ world[:3, :3].T + world[:3, 3])
            tris.append(t + base)
            owner.append(np.full(len(t), len(blocks)))
            blocks.append({"accessor": prim["attributes"]["POSITION"], "normal": prim["attributes"].get("NORMAL"),
                           "world": world, "start": base, "count": len(local), "tris": t, "node": n, "prim": pk})
    if not blocks:
        raise MeshFileError("no triangle primitive in its scene")
    faces = np.concatenate(tris)
    mesh = SourceMesh(path, "gltf", np.concatenate(xyz), faces, np.arange(len(faces), dtype=np.int64), len(faces),
                      _data=data)
    mesh._state.update(doc=doc, buffers=buffers, binary=binary, blocks=blocks, float32=True)
    return mesh


def _gltf_local(block: dict, world_xyz: np.ndarray) -> np.ndarray:
    m = block["world"]
    return (world_xyz - m[:3, 3]) @ np.linalg.inv(m[:3, :3]).T


def _gltf_stored(mesh: SourceMesh, v: np.ndarray) -> np.ndarray:
    out = v.copy()
    for b in mesh._state["blocks"]:
        sl = slice(b["start"], b["start"] + b["count"])
        local = _gltf_local(b, v[sl]).astype(np.float32).astype(np.float64)
        out[sl] = local @ b["world"][:3, :3].T + b["world"][:3, 3]
    moved_not = (v == mesh.vertices).all(1)
    out[moved_not] = mesh.vertices[moved_not]  # unmoved vertices are written back as they were read
    return out


def _write_gltf(mesh: SourceMesh, v: np.ndarray) -> bytes:
    import base64
    import copy
    import json

    st = mesh._state
    doc = copy.deepcopy(st["doc"])
    buffers = [bytearray(b) for b in st["buffers"]]
    written: dict[int, np.ndarray] = {}
    own_mesh: dict[int, int] = {}  # node -> the mesh copy it was given
    for b in st["blocks"]:
        sl = slice(b["start"], b["start"] + b["count"])
        if not (v[sl] != mesh.vertices[sl]).any():
            continue
        view = _gltf_view(doc, buffers, b["accessor"])
        local = _gltf_local(b, v[sl]).astype(np.float32)
        still = (v[sl] == mesh.vertices[sl]).all(1)
        local[still] = view[still]  # a vertex that did not move keeps its stored value, bit for bit
        position, normal = b["accessor"], b["normal"]
        if position in written and not np.array_equal(written[position], local):
            del view  # (a view pins the buffer's size)
            # a mesh several nodes (or primitives) share, moved differently here: this node gets its own copy of the
            # mesh, and this primitive its own positions (and normals), appended to the first buffer
            node = doc["nodes"][b["node"]]
            if b["node"] not in own_mesh:
                doc["meshes"].append(copy.deepcopy(doc["meshes"][node["mesh"]]))
                own_mesh[b["node"]] = node["mesh"] = len(doc["meshes"]) - 1
            prim = doc["meshes"][node["mesh"]]["primitives"][b["prim"]]
            position = prim["attributes"]["POSITION"] = _gltf_append(doc, buffers, position)
            if normal is not None:
                normal = prim["attributes"]["NORMAL"] = _gltf_append(doc, buffers, normal)
            view = _gltf_view(doc, buffers, position)
        written[position] = local
        old = view.astype(np.float64).copy()
        view[:] = local
        acc = doc["accessors"][position]
        acc["min"], acc["max"] = local.min(0).tolist(), local.max(0).tolist()
        if normal is not None:
            _gltf_normals(doc, buffers, {**b, "normal": normal}, old, local.astype(np.float64))
    if st["binary"]:
        text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
        text += b" " * (-len(text) % 4)
        out = bytearray(struct.pack("<II", len(text), 0x4E4F534A)) + text
        if buffers and "uri" not in doc["buffers"][0]:
            body = bytes(buffers[0]) + b"\0" * (-len(buffers[0]) % 4)
            out += struct.pack("<II", len(body), 0x004E4942) + body
        return b"glTF" + struct.pack("<II", 2, 12 + len(out)) + bytes(out)
    st["external"] = {}  # separate buffer files, written beside the output (SourceMesh.write)
    for k, buf in enumerate(doc.get("buffers", [])):
        if buf.get("uri", "").startswith("data:"):
            buf["uri"] = buf["uri"].split(",", 1)[0] + "," + base64.b64encode(bytes(buffers[k])).decode("ascii")
        elif "uri" in buf:
            st["external"][buf["uri"]] = bytes(buffers[k])
    return json.dumps(doc, indent=2).encode("utf-8")


def _gltf_append(doc: dict, buffers: list, index: int) -> int:
    """A copy of accessor ``index``'s data, tightly packed at the end of the first buffer, as a new accessor; its
    index."""
    data = _gltf_view(doc, buffers, index).copy()  # (a copy: a view would pin the buffer's size)
    buf = buffers[0]
    buf.extend(b"\0" * (-len(buf) % 4))
    offset = len(buf)
    buf.extend(data.tobytes())
    doc["buffers"][0]["byteLength"] = len(buf)
    doc["bufferViews"].append({"buffer": 0, "byteOffset": offset, "byteLength": data.nbytes})
    acc = {k: val for k, val in doc["accessors"][index].items() if k not in ("byteOffset", "sparse")}
    acc["bufferView"] = len(doc["bufferViews"]) - 1
    doc["accessors"].append(acc)
    return len(doc["accessors"]) - 1


def _gltf_normals(doc: dict, buffers: list, block: dict, old: np.ndarray, new: np.ndarray) -> None:
    """A primitive's vertex normals recomputed where its moved vertices' triangles touch them: area-weighted, on the
    side of the file's normal."""
    t = block["tris"]
    moved = (old != new).any(1)
    hit = np.zeros(len(new), bool)
    hit[t[moved[t].any(1)].ravel()] = True
    face_n = np.cross(new[t[:, 1]] - new[t[:, 0]], new[t[:, 2]] - new[t[:, 0]])
    acc = np.zeros_like(new)
    for k in range(3):
        np.add.at(acc, t[:, k], face_n)
    view = _gltf_view(doc, buffers, block["normal"])
    stated = view.astype(np.float64)
    n = _unit(acc)
    n[(n * stated).sum(1) < 0] *= -1
    view[hit] = n[hit].astype(view.dtype)


# --------------------------------------------------------------------------------------------- arrays
_NPZ_KEYS = (("vertices", "faces"), ("v", "f"), ("verts", "faces"))


def _read_npz(path: Path, data: bytes) -> SourceMesh:
    import io

    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    keys = next((k for k in _NPZ_KEYS if k[0] in arrays and k[1] in arrays), None)
    if keys is None:
        raise MeshFileError(f"holds arrays {sorted(arrays)}; save the mesh as vertices (V, 3) and faces (F, 3) "
                            "(np.savez(path, vertices=..., faces=...))")
    v, f = arrays[keys[0]], arrays[keys[1]]
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] < 3 or not np.issubdtype(f.dtype, np.integer):
        raise MeshFileError(f"{keys[0]} {v.shape} and {keys[1]} {f.shape} {f.dtype}: give vertices (V, 3) and "
                            "integer faces (F, 3) or polygons (F, k)")
    faces, owner = _fan([list(map(int, row)) for row in f]) if f.shape[1] > 3 else (f.astype(np.int64),
                                                                                      np.arange(len(f)))
    mesh = SourceMesh(path, "npz", v.astype(np.float64), faces, np.asarray(owner, np.int64), len(f), _data=data)
    mesh._state.update(arrays=arrays, key=keys[0], float32=v.dtype == np.float32)
    return mesh


def _write_npz(mesh: SourceMesh, v: np.ndarray) -> bytes:
    import io

    arrays = dict(mesh._state["arrays"])
    arrays[mesh._state["key"]] = v.astype(arrays[mesh._state["key"]].dtype)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


_READERS = {"obj": _read_obj, "off": _read_off, "ply": _read_ply, "stl": _read_stl, "glb": _read_gltf,
            "gltf": _read_gltf, "npz": _read_npz}
_WRITERS = {"obj": _write_obj, "off": _write_off, "ply": _write_ply, "stl": _write_stl, "gltf": _write_gltf,
            "npz": _write_npz}

__all__ = ["SOURCE_SUFFIXES", "SourceMesh", "read_source"]
