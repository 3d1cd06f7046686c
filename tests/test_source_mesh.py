"""Users' files read with their own structure and written back with only the vertex positions changed: OBJ (quads,
uv, normals, groups, materials), OFF, PLY (ascii and binary, extra properties, triangle strips) and STL (ascii and
binary soups, corners merged exactly); and the CLI around them (--pairs, no overwriting of inputs)."""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import pytest

from neuralcol.cli import main
from neuralcol.errors import MeshFileError
from neuralcol.geometry.source_mesh import read_source

# two unit cubes of quads, the second shifted by 0.5 along x: they overlap (faces of the first cut the second)
CUBE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
QUADS = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])


def two_cubes(shift=0.5):
    v = np.concatenate([CUBE, CUBE + [shift, 0.13, 0.07]])
    return v, np.concatenate([QUADS, QUADS + 8])


def obj_text(v, quads):
    lines = ["# exported by a DCC tool\n", "mtllib cubes.mtl\n", "o first\n"]
    lines += [f"v {x} {y} {z}\n" for x, y, z in v[:8]]
    lines += ["vt 0 0\n", "vt 1 0\n", "vt 1 1\n", "vt 0 1\n"]
    lines += ["vn 0 0 -1\n", "vn 0 0 1\n", "vn 0 -1 0\n", "vn 1 0 0\n", "vn 0 1 0\n", "vn -1 0 0\n"]
    lines += ["usemtl red\n", "s off\n"]
    for k, q in enumerate(quads[:6]):
        lines.append("f " + " ".join(f"{i + 1}/{j + 1}/{k + 1}" for j, i in enumerate(q)) + "\n")
    lines += ["o second\n"] + [f"v {x} {y} {z} 0.5 0.5 0.5\n" for x, y, z in v[8:]]
    lines += ["g lid\n", "usemtl blue\n"] + ["f " + " ".join(str(i + 1) for i in q) + "\n" for q in quads[6:]]
    return "".join(lines)


def test_obj_quads_uv_normals_groups_written_back_with_positions_only(tmp_path):
    v, quads = two_cubes()
    src = tmp_path / "cubes.obj"
    src.write_text(obj_text(v, quads))
    mesh = read_source(src)
    assert mesh.vertices.shape == (16, 3) and mesh.faces.shape == (24, 3) and mesh.n_file_faces == 12
    np.testing.assert_array_equal(mesh.vertices, v)
    assert mesh.to_bytes(mesh.vertices) == src.read_bytes(), "unchanged positions: the file byte for byte"
    moved = v.copy()
    moved[9] += [0.25, 0.0, 0.0]  # a vertex of the second cube
    moved[1] += [1e-17 + 0.1, 0.2, 0.0]  # a vertex of the first (its faces carry vn)
    out = mesh.write(tmp_path / "out" / "cubes.obj", moved)
    again = read_source(out)
    np.testing.assert_array_equal(again.vertices, moved)  # exact coordinates
    np.testing.assert_array_equal(again.faces, mesh.faces)
    before, after = src.read_text().splitlines(), out.read_text().splitlines()
    assert len(before) == len(after)
    changed = [k for k, (a, b) in enumerate(zip(before, after)) if a != b]
    assert all(after[k].startswith(("v ", "vn ")) for k in changed)
    assert after[before.index("v 0.5 0.13 0.07 0.5 0.5 0.5") + 1].endswith(" 0.5 0.5 0.5"), "vertex colours kept"
    vn = [np.array(line.split()[1:], float) for line in after if line.startswith("vn ")]
    assert all(np.linalg.norm(n) == pytest.approx(1.0) for n in vn)
    # vertex 1 lies on faces 0 (vn 1), 2 (vn 3), 3 (vn 4): those normals are recomputed, the others kept
    assert [k for k, (a, b) in enumerate(zip(before, after)) if a.startswith("vn ") and a != b] == [
        before.index("vn 0 0 -1"), before.index("vn 0 -1 0"), before.index("vn 1 0 0")]
    assert vn[0][2] < 0, "the recomputed normal keeps the file's side"


def test_off_and_ply_polygons_and_properties(tmp_path):
    v, quads = two_cubes()
    off = tmp_path / "cubes.off"
    off.write_text("OFF\n# a comment\n16 12 0\n" + "".join(f"{x} {y} {z} # v{i}\n" for i, (x, y, z) in enumerate(v))
                   + "".join(f"4 {' '.join(map(str, q))} 255 0 0\n" for q in quads))
    ply = tmp_path / "cubes.ply"
    header = ("ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 16\nproperty float x\nproperty float y\n"
              "property float z\nproperty uchar red\nelement face 12\nproperty list uchar int vertex_indices\n"
              "property uchar flags\nend_header\n")
    ply.write_text(header + "".join(f"{x} {y} {z} 7\n" for x, y, z in v)
                   + "".join(f"4 {' '.join(map(str, q))} 3\n" for q in quads))
    moved = v + np.linspace(0, 1e-3, 48).reshape(16, 3)
    for path in (off, ply):
        mesh = read_source(path)
        assert mesh.faces.shape == (24, 3) and mesh.n_file_faces == 12
        out = mesh.write(tmp_path / "out" / path.name, moved)
        again = read_source(out)
        np.testing.assert_array_equal(again.faces, mesh.faces)
        np.testing.assert_array_equal(again.vertices, mesh.stored(moved))
        a, b = path.read_text().splitlines(), out.read_text().splitlines()
        assert [x.split()[3:] for x in a] == [y.split()[3:] for y in b], "everything after x y z kept"
    assert read_source(ply).stored(moved).dtype == np.float64
    np.testing.assert_array_equal(read_source(ply).stored(moved), moved.astype(np.float32))


def test_binary_ply_with_strips_and_extra_face_properties(tmp_path):
    v, quads = two_cubes()
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    head = (b"ply\nformat binary_little_endian 1.0\nelement vertex 16\nproperty double x\nproperty double y\n"
            b"property double z\nproperty float quality\nelement face 24\nproperty list uchar int vertex_indices\n"
            b"property uchar red\nend_header\n")
    body = b"".join(struct.pack("<dddf", *p, 0.5) for p in v)
    body += b"".join(struct.pack("<B3iB", 3, *t, 9) for t in tris)
    path = tmp_path / "cubes.ply"
    path.write_bytes(head + body)
    mesh = read_source(path)
    np.testing.assert_array_equal(mesh.faces, tris)
    moved = v + 1e-3
    out = read_source(mesh.write(tmp_path / "o.ply", moved))
    np.testing.assert_array_equal(out.vertices, moved)  # doubles: exact
    raw_in, raw_out = path.read_bytes(), (tmp_path / "o.ply").read_bytes()
    assert len(raw_in) == len(raw_out) and raw_in[len(head) + 16 * 28:] == raw_out[len(head) + 16 * 28:]
    strips = tmp_path / "strip.ply"  # one strip 0 1 2 3 -> triangles (0 1 2), (2 1 3)
    strips.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                       b"property float z\nelement tristrips 1\nproperty list int int vertex_indices\nend_header\n"
                       + struct.pack("<12f", 0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0) + struct.pack("<5i", 4, 0, 1, 2, 3))
    np.testing.assert_array_equal(read_source(strips).faces, [[0, 1, 2], [2, 1, 3]])


@pytest.mark.parametrize("binary", [True, False])
def test_stl_soup_corners_merged_exactly_and_written_back(tmp_path, binary):
    v, quads = two_cubes()
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    corners = v[tris].astype(np.float32)
    path = tmp_path / "cubes.stl"
    if binary:
        path.write_bytes(b"\0" * 80 + struct.pack("<I", len(tris)) + b"".join(
            struct.pack("<12fH", *np.zeros(3), *c.ravel(), 7) for c in corners))
    else:
        path.write_text("solid cubes\n" + "".join(
            "facet normal 0 0 0\nouter loop\n" + "".join(f"vertex {p[0]} {p[1]} {p[2]}\n" for p in c)
            + "endloop\nendfacet\n" for c in corners) + "endsolid cubes\n")
    mesh = read_source(path)
    assert len(mesh.vertices) == 16 and mesh.merged == 3 * 24 - 16 and mesh.n_file_faces == 24
    np.testing.assert_array_equal(mesh.vertices[mesh.faces], corners.astype(np.float64))
    moved = mesh.vertices + 0.01
    again = read_source(mesh.write(tmp_path / "o.stl", moved))
    np.testing.assert_array_equal(again.vertices[again.faces], mesh.stored(moved)[mesh.faces])
    if binary:
        assert (tmp_path / "o.stl").read_bytes()[:84] == path.read_bytes()[:84], "header and count kept"


def test_unreadable_files_name_the_file_in_one_line(tmp_path):
    bad = tmp_path / "bad.off"
    bad.write_text("NOT AN OFF\n")
    with pytest.raises(MeshFileError, match=r"bad\.off: does not start with OFF"):
        read_source(bad)
    (tmp_path / "x.fbx").write_text("{}")
    with pytest.raises(MeshFileError, match=r"unsupported mesh format '\.fbx'"):
        read_source(tmp_path / "x.fbx")
    (tmp_path / "x.gltf").write_text("{}")
    with pytest.raises(MeshFileError, match=r"x\.gltf: no triangle primitive"):
        read_source(tmp_path / "x.gltf")


def _cli(*argv):
    out, err = io.StringIO(), io.StringIO()
    return main(list(argv), out=out, err=err), out.getvalue(), err.getvalue()


def test_cli_pairs_in_file_faces_and_no_overwrite(tmp_path):
    v, quads = two_cubes()
    src = tmp_path / "cubes.obj"
    src.write_text(obj_text(v, quads))
    code, out, _ = _cli("check", str(src), "--json", "--pairs")
    row = json.loads(out)
    assert code == 1 and row["collides"] and row["pair_list"]
    pairs = np.array(row["pair_list"])
    assert pairs.max() < 12 and (pairs[:, 0] < 6).all() and (pairs[:, 1] >= 6).all(), "quads of one cube each"
    code, _, err = _cli("resolve", str(src), "--out", str(tmp_path), "--no-progress")
    assert code == 2 and "would overwrite this input" in err and src.read_text() == obj_text(v, quads)
    code, out, err = _cli("resolve", str(src), "--out", str(tmp_path / "fixed"), "--no-progress", "--json")
    assert code == 0, err
    fixed = read_source(tmp_path / "fixed" / "cubes.obj")
    np.testing.assert_array_equal(fixed.faces, read_source(src).faces)
    code, out, _ = _cli("check", str(tmp_path / "fixed" / "cubes.obj"))
    assert code == 0 and " free " in out


def test_handle_orders_a_folder_like_the_cli(tmp_path):
    """experiments.handle and neuralcol resolve read a folder's files in the same (natural) order."""
    from experiments.handle import expand_folders
    from neuralcol.geometry.mesh_files import expand_paths

    for name in ("10.obj", "2.obj", "1.OBJ", "b.ply"):
        (tmp_path / name).write_text("")
    assert [p.name for p in expand_folders([tmp_path])] == [e.path.name for e in expand_paths([str(tmp_path)])] == [
        "1.OBJ", "2.obj", "10.obj", "b.ply"]


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_gltf_nodes_transforms_and_normals_written_back(tmp_path, suffix):
    """A glTF scene of two nodes (one rotated and moved) is read in world coordinates as trimesh reads it; written
    back, only the moved vertices' positions (in each node's frame, float32) and their normals change, accessor
    bounds follow, and a .gltf's separate buffers are written beside the output."""
    import trimesh

    scene = trimesh.Scene()
    transform = trimesh.transformations.rotation_matrix(0.3, [0, 0, 1])
    transform[:3, 3] = [0.9, 0.1, 0.0]
    scene.add_geometry(trimesh.creation.icosphere(subdivisions=2), node_name="sphere")
    scene.add_geometry(trimesh.creation.box(extents=(1, 1, 1)), node_name="box", transform=transform)
    path = tmp_path / f"scene{suffix}"
    scene.export(path)
    mesh = read_source(path)
    reference = trimesh.load(path, force="mesh")
    assert mesh.vertices.shape == reference.vertices.shape and mesh.faces.shape == reference.faces.shape
    np.testing.assert_allclose(np.sort(mesh.vertices, axis=0), np.sort(reference.vertices, axis=0), atol=1e-6)
    moved = mesh.vertices.copy()
    moved[-3:] += [0.05, -0.02, 0.01]  # corners of the rotated box
    out = mesh.write(tmp_path / "out" / path.name, moved)
    again = read_source(out)
    np.testing.assert_array_equal(again.faces, mesh.faces)
    np.testing.assert_array_equal(again.vertices, mesh.stored(moved))
    np.testing.assert_array_equal(again.vertices[:-3], mesh.vertices[:-3])
    assert np.abs(again.vertices[-3:] - moved[-3:]).max() < 1e-6
    a, b = trimesh.load(path, force="mesh"), trimesh.load(out, force="mesh")
    assert a.vertex_normals.shape == b.vertex_normals.shape and not np.allclose(a.vertex_normals, b.vertex_normals)
    unchanged = mesh.write(tmp_path / "same" / path.name, mesh.vertices)
    assert unchanged.read_bytes() == path.read_bytes()


def test_gltf_instances_moved_apart_are_written_as_their_own_meshes(tmp_path):
    """One mesh placed by two nodes: read as two copies; moved alike, written into the one accessor; moved apart, the
    second node gets its own copy of the mesh with its own positions, and everything reads back as written."""
    v = CUBE.astype(np.float32)
    tris = np.concatenate([QUADS[:, [0, 1, 2]], QUADS[:, [0, 2, 3]]]).astype(np.uint32)
    blob = v.tobytes() + tris.tobytes()
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0, 1]}],
           "nodes": [{"mesh": 0}, {"mesh": 0, "translation": [0.5, 0.2, 0.1]}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
           "buffers": [{"byteLength": len(blob)}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": v.nbytes},
                           {"buffer": 0, "byteOffset": v.nbytes, "byteLength": tris.nbytes}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3",
                          "min": [0, 0, 0], "max": [1, 1, 1]},
                         {"bufferView": 1, "componentType": 5125, "count": 36, "type": "SCALAR"}]}
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    path = tmp_path / "two.glb"
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body)
    mesh = read_source(path)
    assert len(mesh.vertices) == 16 and len(mesh.faces) == 24
    np.testing.assert_allclose(mesh.vertices[8:], CUBE + [0.5, 0.2, 0.1], atol=1e-7)
    moved = mesh.vertices + 0.01  # both instances alike: one accessor holds it
    np.testing.assert_allclose(read_source(mesh.write(tmp_path / "same.glb", moved)).vertices, moved, atol=1e-6)
    moved[0] += 0.1
    moved[9] -= 0.05
    out = mesh.write(tmp_path / "o.glb", moved)
    again = read_source(out)
    np.testing.assert_array_equal(again.faces, mesh.faces)
    np.testing.assert_array_equal(again.vertices, mesh.stored(moved))
    doc = json.loads(out.read_bytes()[20:20 + struct.unpack("<I", out.read_bytes()[12:16])[0]])
    assert len(doc["meshes"]) == 2 and doc["nodes"][1]["mesh"] == 1 and len(doc["accessors"]) == 3


def test_npz_arrays_in_and_out(tmp_path):
    v, quads = two_cubes()
    path = tmp_path / "cubes.npz"
    np.savez(path, vertices=v.astype(np.float32), faces=quads, labels=np.arange(16))
    mesh = read_source(path)
    assert mesh.faces.shape == (24, 3) and mesh.n_file_faces == 12
    moved = mesh.vertices + 0.01
    with np.load(mesh.write(tmp_path / "o" / "cubes.npz", moved)) as z:
        assert z["vertices"].dtype == np.float32 and (z["faces"] == quads).all()
        assert (z["labels"] == np.arange(16)).all()
        np.testing.assert_array_equal(z["vertices"].astype(np.float64), mesh.stored(moved))
    bad = tmp_path / "only.npz"
    np.savez(bad, points=v)
    with pytest.raises(MeshFileError, match=r"only\.npz: holds arrays \['points'\]; save the mesh as vertices"):
        read_source(bad)
