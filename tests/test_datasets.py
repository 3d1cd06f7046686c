"""Mesh data set loading: formats, order, validation errors that name the file, export, caching."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuralcol import load_mesh_dataset, load_procedural_dataset, write_mesh, write_meshes
from neuralcol.data.datasets import save_mesh_dataset
from neuralcol.errors import DatasetNotFoundError, MeshFileError, UserInputError


def _deformed(verts, k):
    return verts * (1.0 + 0.05 * k) + 0.01 * k


@pytest.fixture
def sphere_folder(tmp_path, icosphere):
    verts, faces = icosphere
    folder = tmp_path / "ds"
    for k in (1, 2, 10, 11, 3):
        write_mesh(folder / f"{k}.obj", _deformed(verts, k), faces)
    return folder, verts, faces


def test_scape_loads_with_expected_shape(scape_dir):
    ds = load_mesh_dataset(scape_dir, expected_vertices=2161)
    assert ds.vertices.shape == (71, 2161, 3) and ds.vertices.dtype == torch.float32
    assert ds.faces.shape == (4318, 3) and ds.faces.dtype == torch.long
    assert ds.names[:3] == ["1", "2", "3"] and ds.names[9] == "10" and ds.names[-1] == "71"


def test_natural_order_and_values(sphere_folder):
    folder, verts, faces = sphere_folder
    ds = load_mesh_dataset(folder, dtype=torch.float64)
    assert ds.names == ["1", "2", "3", "10", "11"]
    for name, v in zip(ds.names, ds.vertices):
        np.testing.assert_allclose(v.numpy(), _deformed(verts, int(name)), atol=1e-6)
    np.testing.assert_array_equal(ds.faces.numpy(), faces)


@pytest.mark.parametrize("fmt", ["ply", "off"])
def test_other_formats(tmp_path, icosphere, fmt):
    verts, faces = icosphere
    write_meshes(tmp_path / "d", np.stack([verts, verts * 2]), faces, ["a", "b"], fmt=fmt)
    ds = load_mesh_dataset(tmp_path / "d", dtype=torch.float64)
    assert ds.names == ["a", "b"]
    np.testing.assert_allclose(ds.vertices[1].numpy(), verts * 2, atol=1e-6)
    np.testing.assert_array_equal(ds.faces.numpy(), faces)


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_array_files(tmp_path, icosphere, suffix):
    verts, faces = icosphere
    stack = np.stack([verts, verts * 1.1, verts * 0.9])
    path = save_mesh_dataset(tmp_path / f"data{suffix}", stack, faces, ["x", "y", "z"])
    ds = load_mesh_dataset(path, dtype=torch.float64)
    assert ds.names == ["x", "y", "z"]
    np.testing.assert_array_equal(ds.vertices.numpy(), stack)


def test_missing_and_empty(tmp_path):
    with pytest.raises(DatasetNotFoundError, match=r"nowhere: data set not found.*NEURALCOL_DATA"):
        load_mesh_dataset(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetNotFoundError, match=r"empty: no .obj/.ply/.off files"):
        load_mesh_dataset(tmp_path / "empty")


def _write_text(path, text):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_error_names_broken_file(sphere_folder):
    folder, verts, faces = sphere_folder
    _write_text(folder / "5.obj", "this is not a mesh\n")
    with pytest.raises(MeshFileError, match=r"5\.obj: holds no triangle mesh"):
        load_mesh_dataset(folder)


def test_non_mesh_file_in_folder(sphere_folder):
    folder, _, _ = sphere_folder
    _write_text(folder / "poses.csv", "1,2,3\n")
    with pytest.raises(MeshFileError, match=r"poses\.csv: not a mesh file"):
        load_mesh_dataset(folder)


def test_different_vertex_count(sphere_folder):
    folder, verts, faces = sphere_folder
    write_mesh(folder / "4.obj", np.concatenate([verts, [[5.0, 5.0, 5.0]]]), faces)
    with pytest.raises(MeshFileError, match=r"4\.obj: 43 vertices, 1\.obj has 42; .*one topology"):
        load_mesh_dataset(folder)


def test_different_faces(sphere_folder):
    folder, verts, faces = sphere_folder
    write_mesh(folder / "4.obj", verts, faces[:, [0, 2, 1]])
    with pytest.raises(MeshFileError, match=r"4\.obj: faces differ from 1\.obj"):
        load_mesh_dataset(folder)


def test_non_finite(sphere_folder):
    folder, verts, faces = sphere_folder
    bad = verts.copy()
    bad[7, 1] = np.nan
    write_mesh(folder / "4.obj", bad, faces)
    with pytest.raises(MeshFileError, match=r"4\.obj: vertex 7 has non-finite coordinates"):
        load_mesh_dataset(folder)


def test_quads_rejected(tmp_path):
    _write_text(tmp_path / "d" / "1.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nf 1 2 3 4\nf 1 2 5\n")
    with pytest.raises(MeshFileError, match=r"1\.obj: has non-triangle faces \(2 faces in the file, 3 triangles"):
        load_mesh_dataset(tmp_path / "d")
    _write_text(tmp_path / "e" / "1.off", "OFF\n5 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n4 0 1 2 3\n3 0 1 4\n")
    with pytest.raises(MeshFileError, match=r"1\.off: has non-triangle faces"):
        load_mesh_dataset(tmp_path / "e")


def test_non_manifold_edge(tmp_path):
    # three triangles on edge (0, 1)
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    write_mesh(tmp_path / "d" / "1.obj", verts, faces)
    with pytest.raises(MeshFileError, match=r"1\.obj: non-manifold mesh, edge \(0, 1\) is shared by 3 triangles"):
        load_mesh_dataset(tmp_path / "d")


def test_zero_area_face(sphere_folder):
    folder, verts, faces = sphere_folder
    bad = verts.copy()
    a, b, c = faces[4]
    bad[c] = 0.5 * (bad[a] + bad[b])  # collinear corners
    write_mesh(folder / "4.obj", bad, faces)
    with pytest.raises(MeshFileError, match=r"4\.obj: face \d+ = .* has zero area"):
        load_mesh_dataset(folder)


def test_array_file_errors(tmp_path, icosphere):
    verts, faces = icosphere
    np.savez(tmp_path / "a.npz", verts=verts[None], faces=faces)
    with pytest.raises(MeshFileError, match=r"a\.npz: missing array\(s\) \['vertices'\]"):
        load_mesh_dataset(tmp_path / "a.npz")
    np.savez(tmp_path / "b.npz", vertices=verts, faces=faces)
    with pytest.raises(MeshFileError, match=r"b\.npz: 'vertices' has shape \(42, 3\)"):
        load_mesh_dataset(tmp_path / "b.npz")
    (tmp_path / "c.h5").write_bytes(b"garbage")
    with pytest.raises(MeshFileError, match=r"c\.h5: cannot be read"):
        load_mesh_dataset(tmp_path / "c.h5")


def test_expected_vertices(sphere_folder):
    folder, _, _ = sphere_folder
    with pytest.raises(MeshFileError, match=r"42 vertices, this data set's config expects 2161"):
        load_mesh_dataset(folder, expected_vertices=2161)


def test_errors_are_user_errors():
    assert issubclass(MeshFileError, UserInputError) and issubclass(DatasetNotFoundError, UserInputError)


def test_procedural_cache(tmp_path, monkeypatch, icosphere):
    from neuralcol.data import procedural

    verts, faces = icosphere
    calls = []

    def gen(n_poses, seed, scale=1.0):
        calls.append(seed)
        rng = np.random.default_rng(seed)
        return verts[None] * (1 + 0.1 * rng.random((n_poses, 1, 1))) * scale, faces

    monkeypatch.setitem(procedural.GENERATORS, "toy", gen)
    a = load_procedural_dataset("toy", 4, seed=3, cache_dir=tmp_path, dtype=torch.float64)
    b = load_procedural_dataset("toy", 4, seed=3, cache_dir=tmp_path, dtype=torch.float64)
    assert calls == [3], "second load must come from the cache"
    torch.testing.assert_close(a.vertices, b.vertices, rtol=0, atol=0)
    assert a.names == b.names == ["pose_0000", "pose_0001", "pose_0002", "pose_0003"]
    c = load_procedural_dataset("toy", 4, seed=4, cache_dir=tmp_path, dtype=torch.float64)
    assert calls == [3, 4] and not torch.equal(a.vertices, c.vertices)
    load_procedural_dataset("toy", 4, seed=3, cache_dir=tmp_path, geometry={"scale": 2.0})
    assert calls == [3, 4, 3], "geometry arguments are part of the cache key"
    with pytest.raises(DatasetNotFoundError, match="unknown"):
        load_procedural_dataset("nope", 4, seed=0)
