"""Procedural data sets (neuralcol.data.procedural): shapes, determinism, topology, and self-intersections.

Self-intersections are judged by an independent reference, MeshLab's ``Select Self Intersecting Faces``
filter (through pymeshlab): it flags faces that intersect a face with which they share no edge (faces that
share only a vertex are tested too). Data-set poses must have no flagged face; linear extrapolations
between two data-set poses ``a + t (b - a)`` with ``t ~ U(1.5, 2.0)`` must intersect in at least 20 % of
random pairs, and so must the poses pushed beyond their range in parameter space (hand joint angles x 2,
skirt fold scale x 2).
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from neuralcol.data.procedural import GENERATORS, cloth, hand
from neuralcol.data.procedural.cloth import make_proc_cloth
from neuralcol.data.procedural.hand import make_proc_hand
from neuralcol.data.procedural.options import merge_kwargs
from neuralcol.errors import UserInputError

N_POSES = 16  # data-set poses checked per generator
N_EXTRAP = 24  # extrapolated samples per generator
EXTRAP_T = (1.5, 2.0)  # extrapolation factor t of a + t (b - a), drawn uniformly
MIN_COLLIDING = 0.2  # fraction of extrapolated samples that must self-intersect
REL_AREA = 1e-6  # a face is degenerate below this fraction of the mean face area
NAMES = ("proc_hand", "proc_cloth")


@pytest.fixture(scope="module")
def data() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return {name: GENERATORS[name](n_poses=N_POSES, seed=0) for name in NAMES}


def _edge_counts(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges (E, 2) and the number of faces on each (E,)."""
    half = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(half, axis=1), axis=0, return_counts=True)


def _n_components(n_vertices: int, edges: np.ndarray) -> int:
    """Connected components of the graph with vertices 0..n_vertices-1 and (E, 2) edges."""
    adj = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n_vertices, n_vertices))
    return int(connected_components(adj, directed=False)[0])


def _areas(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(..., F) triangle areas of (..., V, 3) vertices."""
    tri = verts[..., faces, :]
    return 0.5 * np.linalg.norm(np.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]), axis=-1)


def _flagged(verts: np.ndarray, faces: np.ndarray) -> int:
    """Number of faces MeshLab flags as self-intersecting."""
    pymeshlab = pytest.importorskip("pymeshlab")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(verts, dtype=np.float64),
                               face_matrix=np.ascontiguousarray(faces, dtype=np.int32)))
    ms.compute_selection_by_self_intersections_per_face()
    return int(ms.current_mesh().selected_face_number())


def test_registry():
    from neuralcol.data.procedural.body import make_anny_body

    assert GENERATORS == {"proc_hand": make_proc_hand, "proc_cloth": make_proc_cloth, "anny_body": make_anny_body}


@pytest.mark.parametrize("name", NAMES)
def test_shapes_dtypes_finite(data, name):
    v, f = data[name]
    assert v.dtype == np.float64 and f.dtype == np.int64, (v.dtype, f.dtype)
    assert v.ndim == 3 and v.shape[0] == N_POSES and v.shape[2] == 3, v.shape
    assert f.ndim == 2 and f.shape[1] == 3, f.shape
    assert 2000 <= v.shape[1] <= 3000, f"{name}: {v.shape[1]} vertices, expected 2000..3000"
    assert f.min() == 0 and f.max() == v.shape[1] - 1, "faces must use every vertex index"
    assert np.isfinite(v).all()
    assert len(np.unique(f)) == v.shape[1], "every vertex must belong to a face"


@pytest.mark.parametrize("name", NAMES)
def test_deterministic(data, name):
    gen = GENERATORS[name]
    v0, f0 = data[name]
    v1, f1 = gen(n_poses=N_POSES, seed=0)
    np.testing.assert_array_equal(v1, v0)  # bit-identical
    np.testing.assert_array_equal(f1, f0)
    v2, f2 = gen(n_poses=N_POSES, seed=1)
    np.testing.assert_array_equal(f2, f0)  # topology does not depend on the seed
    diff = np.abs(v2 - v0).max(axis=(1, 2))
    assert (diff > 1e-3).all(), f"seed 1 repeats seed 0 poses: per-pose max diff {diff}"
    assert np.abs(v0[1:] - v0[:1]).max(axis=(1, 2)).min() > 1e-3, "poses of one seed must differ"


def test_hand_topology(data):
    v, f = data["proc_hand"]
    edges, counts = _edge_counts(f)
    bad = edges[counts != 2]
    assert len(bad) == 0, f"{len(bad)} edges not shared by exactly two triangles, e.g. {bad[:3].tolist()}"
    half = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    assert len(np.unique(half, axis=0)) == len(half), "inconsistent orientation: a directed edge repeats"
    assert v.shape[1] - len(edges) + len(f) == 2, "Euler characteristic of a closed genus-0 surface is 2"
    assert _n_components(v.shape[1], edges) == 1
    tri = v[:, f]  # (N, F, 3, 3)
    vol = np.einsum("nfi,nfi->nf", tri[:, :, 0], np.cross(tri[:, :, 1], tri[:, :, 2])).sum(1) / 6
    assert (vol > 0).all(), f"signed volumes {vol}: faces must be oriented outward"


def test_cloth_topology(data):
    v, f = data["proc_cloth"]
    edges, counts = _edge_counts(f)
    assert counts.max() <= 2, f"non-manifold edges: {edges[counts > 2][:3].tolist()}"
    half = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    assert len(np.unique(half, axis=0)) == len(half), "inconsistent orientation: a directed edge repeats"
    assert _n_components(v.shape[1], edges) == 1
    boundary = edges[counts == 1]
    b_verts, b_edges = np.unique(boundary, return_inverse=True)
    b_edges = b_edges.reshape(-1, 2)
    assert (np.bincount(b_edges.ravel()) == 2).all(), "boundary must be a union of simple loops"
    n_loops = _n_components(len(b_verts), b_edges)
    assert n_loops == 2, f"expected two boundary loops (waist and hem), found {n_loops}"
    z = v[0, b_verts, 2]
    top, bottom = z.max(), z.min()
    assert np.allclose(z[z > 0.5 * (top + bottom)], top) and np.allclose(z[z < 0.5 * (top + bottom)], bottom)
    assert v.shape[1] - len(edges) + len(f) == 0, "Euler characteristic of an annulus is 0"
    # outward: face normals point away from the axis on average in every pose
    tri = v[:, f]
    n = np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
    radial = tri.mean(2)[..., :2] - v[:, :, :2].mean(1)[:, None]
    assert (np.einsum("nfi,nfi->n", n[..., :2], radial) > 0).all()


@pytest.mark.parametrize("name", NAMES)
def test_no_degenerate_faces(data, name):
    v, f = data[name]
    a = _areas(v, f)  # (N, F)
    ratio = a.min(axis=1) / a.mean(axis=1)
    assert (ratio > REL_AREA).all(), f"{name}: smallest face area / mean per pose: {ratio}"


@pytest.mark.parametrize("name", NAMES)
def test_dataset_poses_are_collision_free(data, name):
    v, f = data[name]
    flagged = np.array([_flagged(x, f) for x in v])
    assert (flagged == 0).all(), f"{name}: MeshLab flags faces in data-set poses: {flagged.tolist()}"


@pytest.mark.parametrize("name", NAMES)
def test_extrapolated_poses_collide(data, name):
    v, f = data[name]
    rng = np.random.default_rng(123)
    pairs = np.array([rng.choice(len(v), 2, replace=False) for _ in range(N_EXTRAP)])
    t = rng.uniform(*EXTRAP_T, size=N_EXTRAP)
    ext = v[pairs[:, 0]] + t[:, None, None] * (v[pairs[:, 1]] - v[pairs[:, 0]])
    flagged = np.array([_flagged(x, f) for x in ext])
    frac = float((flagged > 0).mean())
    assert frac >= MIN_COLLIDING, f"{name}: only {frac:.0%} of extrapolations intersect; flagged {flagged}"
    # interpolation and the data set itself stay well inside: midpoints intersect less often
    mid = 0.5 * (v[pairs[:, 0]] + v[pairs[:, 1]])
    frac_mid = float((np.array([_flagged(x, f) for x in mid]) > 0).mean())
    assert frac_mid < frac, (frac_mid, frac)


def test_hand_joint_space_extrapolation_collides():
    p = merge_kwargs(hand._HAND_DEFAULTS, {}, "test", hand.__name__)
    rig = hand._build_hand_rig(p)
    angles = hand._sample_hand_angles(p, rig, N_EXTRAP, np.random.default_rng(7))
    assert angles.shape == (N_EXTRAP, 21)
    np.testing.assert_allclose(hand._pose_hand(rig, np.zeros((1, 21)))[0], rig.rest, atol=1e-12)
    f = rig.faces
    assert all(_flagged(x, f) == 0 for x in hand._pose_hand(rig, angles))
    flagged = np.array([_flagged(x, f) for x in hand._pose_hand(rig, 2.0 * angles)])
    assert (flagged > 0).mean() >= MIN_COLLIDING, f"joint angles x 2: flagged faces {flagged}"


def test_cloth_fold_scale_extrapolation_collides():
    p = merge_kwargs(cloth._CLOTH_DEFAULTS, {}, "test", cloth.__name__)
    rest = cloth._cloth_rest(p)
    q = cloth._sample_cloth_params(p, rest, N_EXTRAP, np.random.default_rng(7))
    over = cloth._pose_cloth(p, rest, q._replace(scale=2 * q.scale))
    flagged = np.array([_flagged(x, rest.faces) for x in over])
    assert (flagged > 0).mean() >= MIN_COLLIDING, f"fold scale x 2: flagged faces {flagged}"


def test_hand_pose_distribution_is_rich():
    p = merge_kwargs(hand._HAND_DEFAULTS, {}, "test", hand.__name__)
    rig = hand._build_hand_rig(p)
    angles = hand._sample_hand_angles(p, rig, 200, np.random.default_rng(0))
    std = np.rad2deg(angles.std(axis=0))
    assert (std > 2.0).all(), f"every one of the 21 joint angles must vary; std (deg) {np.round(std, 1)}"
    w = rig.weights
    assert (w >= 0).all() and np.allclose(w.sum(1), 1.0), "skinning weights must be a partition of unity"
    assert ((w > 1e-9).sum(1) <= 3).all()


@pytest.mark.parametrize("name", NAMES)
def test_pose_variety(data, name):
    """The poses span many directions in vertex space (something for an autoencoder to learn)."""
    v, _ = data[name]
    x = (v - v.mean(0)).reshape(len(v), -1)
    s = np.linalg.svd(x, compute_uv=False)
    explained = np.cumsum(s**2) / np.sum(s**2)
    n99 = int(np.searchsorted(explained, 0.99)) + 1
    assert n99 >= 8, f"{name}: {n99} of {len(v) - 1} principal components explain 99 % of the variance"


def test_geometry_kwargs():
    v, f = make_proc_cloth(2, seed=0, n_around=64, n_rings=36)
    assert v.shape == (2, 64 * 36, 3) and f.shape == (2 * 64 * 35, 3)
    v, f = make_proc_hand(2, seed=0, rings_per_finger=8)
    q = 248 + 5 * (8 * 8 + 4)  # control quads: palm minus 5 patches + 5 tubes with caps
    assert v.shape == (2, 4 * q + 2, 3) and f.shape == (8 * q, 3)
    with pytest.raises(UserInputError, match="finger_lenght"):
        make_proc_hand(2, finger_lenght=(1, 1, 1, 1))
    with pytest.raises(UserInputError, match="n_poses"):
        make_proc_cloth(0)
    with pytest.raises(UserInputError, match="spread_range"):
        make_proc_hand(2, spread_range=(-5.0, 10.0))


@pytest.mark.parametrize("name", NAMES)
def test_generation_is_fast(name):
    t0 = time.perf_counter()
    v, _ = GENERATORS[name](n_poses=100, seed=0)
    dt = time.perf_counter() - t0
    assert len(v) == 100
    assert dt < 10.0, f"{name}: 100 poses took {dt:.1f} s"
