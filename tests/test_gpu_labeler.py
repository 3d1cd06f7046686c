"""Batched Warp labeler (``labeling=gpu``) against the exact CPU labeler, on Warp's CPU device: same
verdicts and pair counts, PD and PD_i within 1e-6 of the bounding-box diagonal, on the fixtures of
tests/test_labeler.py and tests/test_labeler_scaling.py, batch order, LabelPool and build_labeler."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation
from test_labeler import _one_vertex_fan, _two_spheres
from test_labeler_scaling import _blocks, _subdivide

from neuralcol.collision.labeler import ExactLabeler, Labels
from neuralcol.collision.pool import LabelPool

wp = pytest.importorskip("warp")

from neuralcol.collision.warp_labeler import WarpLabeler  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEVICE = "cpu"  # Warp's CPU backend: what CI runs; the CUDA test below runs where a GPU is


def _pair(faces, rest, device=DEVICE, **kw):
    return WarpLabeler(faces, rest, device=device, **kw), ExactLabeler(faces, rest, **kw)


def assert_agree(gl, ref, meshes, labels: Labels | None = None) -> Labels:
    """Batched labels of ``meshes`` equal the exact labeler's: verdict, n_pairs; PD, PD_i within 1e-6 diag."""
    meshes = np.stack(meshes)
    got = gl.label_batch(meshes) if labels is None else labels
    want = Labels.stack([ref.label(v) for v in meshes], ref.n_parts)
    np.testing.assert_array_equal(got.collides, want.collides)
    np.testing.assert_array_equal(got.n_pairs, want.n_pairs)
    tol = 1e-6 * ref.diag
    assert np.abs(got.pd - want.pd).max() <= tol, np.abs(got.pd - want.pd).max() / ref.diag
    assert np.abs(got.pd_sub - want.pd_sub).max() <= tol
    assert got.pd_sub.shape == (len(meshes), ref.n_parts) and got.collides.dtype == bool
    np.testing.assert_array_equal(got.pd, got.pd_sub.max(1))
    return got


# ------------------------------------------------------------------------------------------ test_labeler.py
def test_small_meshes_adjacency_and_one_vertex_folds():
    verts = np.array([[0, 0, 0], [1, 0, 0], [0.3, 1, 0], [0.4, 0.8, 0.0]], float)
    faces = np.array([[0, 1, 2], [1, 0, 3]])
    rest = np.array([[0, 0, 0], [1, 0, 0], [0.3, 1, 0], [0.4, -0.8, 0.0]], float)
    gl, ref = _pair(faces, rest)
    folded = verts.copy()
    folded[3, 2] = 0.3
    got = assert_agree(gl, ref, [verts, folded, rest])
    assert not got.collides.any()  # edge neighbours never count

    lab, tip = _one_vertex_fan(0.3)
    gl = WarpLabeler(lab.faces, lab.rest, device=DEVICE)
    touching = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0.2, 0.5], [-0.8, -0.9, 0.4]], float)
    got = assert_agree(gl, lab, [tip, touching, lab.rest])
    assert got.collides.tolist() == [True, False, False] and got.n_pairs[0] == 1
    assert gl.verdict(tip) and not gl.verdict(touching)
    lb = gl.label(tip)
    assert lb.collides and lb.pd > 0 and lb.pd == lb.pd_sub.max()
    with pytest.raises(ValueError, match=r"expected \(B, 5, 3\)"):
        gl.label_batch(tip[:4][None])
    bad = tip.copy()
    bad[1, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        gl.label(bad)


def test_spheres_and_boxes_analytic():
    at, faces, part = _two_spheres(subdiv=3)
    rest = at(6.0)
    diag = np.linalg.norm(rest.max(0) - rest.min(0))
    gl, ref = _pair(faces, rest, partition=part, clearance_cap=0.2 / diag)
    got = assert_agree(gl, ref, [at(d) for d in (2.15, 2.03, 1.99, 1.9, 1.5, 1.05)])
    assert got.collides.tolist() == [False, False, True, True, True, True]

    box = trimesh.creation.box(extents=(1, 1, 1))
    v, f = trimesh.remesh.subdivide_to_size(box.vertices + 0.5, box.faces, max_edge=0.25)
    faces = np.concatenate([f, f + len(v)])
    v2 = Rotation.from_rotvec([2e-3, -1e-3, 1.5e-3]).apply(v - 0.5) + 0.5

    def at_box(s):
        return np.concatenate([v, v2 + [s, 0.3, 0.2]])

    gl, ref = _pair(faces, at_box(3.0), clearance_cap=0.1)
    got = assert_agree(gl, ref, [at_box(s) for s in (1.3, 1.1, 1.02, 0.98, 0.95, 0.9, 0.85)])
    assert got.collides.sum() == 4


@pytest.mark.slow
def test_spheres_dense_large_cap():
    """test_labeler's 2 x 2562-vertex spheres with cap 0.2: many pairs within cap."""
    at, faces, part = _two_spheres(subdiv=4)
    rest = at(6.0)
    diag = np.linalg.norm(rest.max(0) - rest.min(0))
    gl, ref = _pair(faces, rest, partition=part, clearance_cap=0.2 / diag)
    assert_agree(gl, ref, [at(d) for d in np.linspace(2.15, 1.05, 23)])


def test_partition_uninvolved_part_and_far_clearance():
    at, faces, part = _two_spheres(subdiv=3)
    third = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    tv = np.asarray(third.vertices)
    faces3 = np.concatenate([faces, np.asarray(third.faces) + 2 * len(tv)])
    part3 = np.concatenate([part, np.full(len(tv), 2)])

    def at3(d, y=2.3):
        return np.concatenate([at(d), tv + [0.0, y, 0.0]])

    rest = at3(6.0, y=6.0)
    gl, ref = _pair(faces3, rest, partition=part3, clearance_cap=0.5 / np.linalg.norm(rest.max(0) - rest.min(0)))
    got = assert_agree(gl, ref, [at3(1.8), at3(2.1), at3(2.45, y=2.1)])
    assert got.collides.tolist() == [True, False, False]
    assert got.pd_sub[0, 2] == pytest.approx(-0.3, rel=0.05)


def test_scape_variants(scape):
    verts = scape.vertices.numpy().astype(np.float64)
    faces = scape.faces.numpy()
    rng = np.random.default_rng(1)
    meshes = [verts[7], verts[70], verts[0]]  # files 8 and 71 collide
    for _ in range(21):
        i, j = rng.choice(69, 2, replace=False)
        meshes.append(verts[i] + rng.uniform(-0.8, 1.8) * (verts[j] - verts[i]))
    gl, ref = _pair(faces, verts[0], partition=_blocks(len(verts[0]), 4))
    got = assert_agree(gl, ref, meshes)
    assert got.collides[:3].tolist() == [True, True, False] and 3 <= got.collides.sum() < len(meshes)


# ------------------------------------------------------------------------------------------ scaling fixtures
@pytest.mark.parametrize("partition", [None, "blocks", "random"])
def test_two_spheres_far_and_near_pairs(partition):
    s = trimesh.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(0)
    faces = np.concatenate([s.faces, s.faces + len(s.vertices)])
    rest = np.concatenate([s.vertices, s.vertices + [3.0, 0.0, 0.0]])
    part = {None: None, "blocks": _blocks(len(rest), 3), "random": rng.integers(0, 4, len(rest))}[partition]
    meshes = []
    for gap in (0.6, 0.25, 0.05, 0.0, -0.05, -0.4):
        v = rest.copy()
        v[len(s.vertices):, 0] -= 1.0 - gap
        v[:, 1] *= 1.0 + 0.2 * np.sin(3 * v[:, 0])
        meshes.append(v)
    cap = 0.3 / float(np.linalg.norm(rest.max(0) - rest.min(0)))
    gl, ref = _pair(faces, rest, partition=part, clearance_cap=cap)
    assert assert_agree(gl, ref, meshes).collides.sum() >= 2


def test_pinched_sphere_near_pairs():
    s = trimesh.creation.icosphere(subdivisions=3)
    rest = np.asarray(s.vertices, dtype=np.float64)
    meshes = []
    for depth in (0.5, 0.9, 0.99, 1.05):
        v = rest.copy()
        v[:, 1] *= 1.0 - depth * np.exp(-(v[:, 0] / 0.3) ** 2)
        v[:, 2] *= 1.0 - 0.5 * depth * np.exp(-(v[:, 0] / 0.3) ** 2)
        meshes.append(v)
    gl, ref = _pair(np.asarray(s.faces), rest, partition=_blocks(len(rest), 2), clearance_cap=0.05)
    assert_agree(gl, ref, meshes)


def test_scape_deformed_and_subdivided(scape):
    verts = scape.vertices.numpy().astype(np.float64)
    faces = scape.faces.numpy().astype(np.int64)
    rng = np.random.default_rng(1)
    meshes = [verts[7], verts[70], verts[20], verts[3] + 1.6 * (verts[9] - verts[3]),
              verts[15] + 2.0 * (verts[30] - verts[15])]
    gl, ref = _pair(faces, verts[0], partition=_blocks(len(verts[0]), 4))
    assert assert_agree(gl, ref, meshes).collides.sum() >= 3
    # midpoint subdivision (+ 1e-6 jitter): exactly coplanar one-vertex neighbours must not count
    sv, sf = zip(*[_subdivide(v, faces, 1, rng) for v in (verts[0], verts[7], verts[33])])
    gl, ref = _pair(sf[0], sv[0], partition=_blocks(len(sv[0]), 4))
    assert assert_agree(gl, ref, sv).collides.tolist() == [False, True, False]
    v1, f1 = trimesh.remesh.subdivide(verts[0], faces)  # no jitter
    flat = trimesh.creation.box(extents=(1, 1, 1))
    fv, ff = trimesh.remesh.subdivide_to_size(flat.vertices, flat.faces, max_edge=0.1)
    for v, f in ((v1, f1), (fv, ff)):
        gl = WarpLabeler(f, v, device=DEVICE)
        lb = gl.label(v)
        assert not lb.collides and lb.n_pairs == 0 and lb.pd < 0


# ------------------------------------------------------------------------------------------ batching, plumbing
def _mixed_batch():
    at, faces, part = _two_spheres(subdiv=2)
    rest = at(6.0)
    offsets = [1.5, 2.6, 1.9, 3.0, 1.2, 2.05, 1.99, 4.0, 2.2]
    rng = np.random.default_rng(0)
    batch = np.stack([at(o) for o in offsets]) + 1e-3 * rng.standard_normal((len(offsets), len(rest), 3))
    return faces, rest, part, batch


def test_mixed_batch_keeps_order_and_slices():
    faces, rest, part, batch = _mixed_batch()
    gl, ref = _pair(faces, rest, partition=part)
    got = assert_agree(gl, ref, list(batch))
    assert got.collides.any() and not got.collides.all()
    perm = np.random.default_rng(1).permutation(len(batch))
    shuffled = gl.label_batch(batch[perm])
    for name in Labels._fields:
        np.testing.assert_array_equal(getattr(shuffled, name), getattr(got, name)[perm])
    small = WarpLabeler(faces, rest, partition=part, device=DEVICE, max_batch=4)  # 3 launches: 4 + 4 + 1
    for name in Labels._fields:
        np.testing.assert_array_equal(getattr(small.label_batch(batch), name), getattr(got, name))
    # one pose alone, and the same pose inside the batch: identical
    one = gl.label(batch[2])
    assert one.collides == got.collides[2] and one.pd == got.pd[2]
    tight = WarpLabeler(faces, rest, partition=part, device=DEVICE)
    tight._min_pair_list = 1  # the counted-pair list overflows: the launch is repeated with room for all
    assert got.n_pairs.sum() > 16 * len(batch)
    for name in Labels._fields:
        np.testing.assert_array_equal(getattr(tight.label_batch(batch), name), getattr(got, name))
    empty = gl.label_batch(batch[:0])
    assert empty.pd.shape == (0,) and empty.pd_sub.shape == (0, 2)
    # torch input (CPU tensor, float32 upcast like the CPU labeler's float64 conversion)
    torch = pytest.importorskip("torch")
    from_torch = gl.label_batch(torch.as_tensor(batch))
    np.testing.assert_array_equal(from_torch.pd, got.pd)
    # set_partition after the device arrays exist
    gl.set_partition(None)
    ref.set_partition(None)
    assert gl.n_parts == 1
    assert_agree(gl, ref, list(batch[:3]))


def _labeling(overrides):
    """The ``labeling`` group of ``conf/config.yaml`` composed with ``overrides``."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=overrides).labeling


def test_build_labeler_pool_and_pickle():
    from neuralcol.collision.backends import build_labeler

    faces, rest, part, batch = _mixed_batch()
    gpu = _labeling(["labeling=gpu", "labeling.labeler.device=cpu"])  # conf/labeling/gpu.yaml on Warp's CPU device
    gl = build_labeler(gpu, faces, rest, partition=part)
    assert isinstance(gl, WarpLabeler) and gl.batched and gl.label_kind == "exact" and gl.device == "cpu"
    ref = build_labeler(_labeling([]), faces, rest, partition=part)
    assert (gl.n_vertices, gl.n_parts, gl.ell, gl.diag, gl.tau, gl.cap, gl.eps) == (
        ref.n_vertices, ref.n_parts, ref.ell, ref.diag, ref.tau, ref.cap, ref.eps)
    want = assert_agree(gl, ref, list(batch))
    with LabelPool(gl, workers=0, chunk_size=4) as pool:
        got = pool.label(batch)
    for name in Labels._fields:
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    # asked for worker processes, the pool labels a batched backend in this process, in chunks of its batch
    with LabelPool(gl, workers=2, chunk_size=4) as pool:
        assert pool.workers == 0 and pool.chunk_size == gl.max_batch
        np.testing.assert_array_equal(pool.label(batch).pd, want.pd)
    np.testing.assert_array_equal(gl.subsets(want.pd), ref.subsets(want.pd))
    gl.label_batch(batch[:2])  # device arrays and a BVH exist: they are not pickled, but rebuilt
    clone = pickle.loads(pickle.dumps(gl))
    assert clone._dev is None and clone._bvh == {}
    np.testing.assert_array_equal(clone.label_batch(batch).pd, want.pd)


@pytest.mark.gpu
def test_cuda_device_and_torch_cuda_input():
    torch = pytest.importorskip("torch")
    if not (wp.is_cuda_available() and torch.cuda.is_available()):
        pytest.skip("needs a CUDA device")
    faces, rest, part, batch = _mixed_batch()
    gl, ref = _pair(faces, rest, partition=part, device=None)
    assert gl.device.startswith("cuda")
    want = assert_agree(gl, ref, list(batch))
    got = gl.label_batch(torch.as_tensor(batch, device="cuda"))
    np.testing.assert_array_equal(got.collides, want.collides)
    np.testing.assert_allclose(got.pd_sub, want.pd_sub, rtol=0, atol=1e-6 * ref.diag)
