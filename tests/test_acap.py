"""ACAP features: references, round trips on SCAPE, gradients, rotation consistency."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import torch
from conftest import make_tube, twist
from scipy.spatial.transform import Rotation

from neuralcol import ACAP
from neuralcol.geometry.acap import IDENTITY_FEATURE, rotvec_to_matrix, sym_from_entries
from neuralcol.metrics.reconstruction import relative_vertex_error


def _assert_close(actual, expected, atol, what):
    actual, expected = np.asarray(actual), np.asarray(expected)
    diff = np.abs(actual - expected)
    idx = np.unravel_index(np.argmax(diff), diff.shape)
    assert diff.max() <= atol, f"{what}: max |diff| {diff.max():.3g} > {atol} at {idx}"


def _smooth_deform(vertices: np.ndarray, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(3, 3)) * 0.3
    return vertices + np.sin(vertices @ a) * 0.1 + 0.05 * vertices**2


def test_deformation_gradient_matches_per_vertex_loop(icosphere):
    """Vectorised T_i and polar decomposition vs a slow loop over vertices (scipy.linalg.polar)."""
    rest, faces = icosphere
    deformed = _smooth_deform(rest)
    acap = ACAP(rest, faces, weights="uniform", normal_weight=0.5)
    t_fast = acap.deformation_gradients(deformed[None])[0]
    feats = acap.encode(torch.from_numpy(deformed[None]))[0].numpy()
    # reference: explicit normal equations per vertex, uniform weights
    n_rest = acap_normals(rest, faces)
    n_def = acap_normals(deformed, faces)
    nbrs = [set() for _ in range(len(rest))]
    for f in faces:
        for a in range(3):
            nbrs[f[a]].update([f[(a + 1) % 3], f[(a + 2) % 3]])
    for i in range(len(rest)):
        js = sorted(nbrs[i])
        e = rest[js] - rest[i]
        ed = deformed[js] - deformed[i]
        h, hd = np.linalg.norm(e, axis=1).mean(), np.linalg.norm(ed, axis=1).mean()
        a_mat = e.T @ e + 0.5 * np.outer(h * n_rest[i], h * n_rest[i])
        b_mat = ed.T @ e + 0.5 * np.outer(hd * n_def[i], h * n_rest[i])
        t_ref = b_mat @ np.linalg.inv(a_mat)
        _assert_close(t_fast[i], t_ref, 1e-10, f"T at vertex {i}")
        r_ref, s_ref = scipy.linalg.polar(t_ref)
        rv = feats[i, :3]
        _assert_close(Rotation.from_rotvec(rv).as_matrix(), r_ref, 1e-8, f"R at vertex {i}")
        _assert_close(sym_from_entries(torch.from_numpy(feats[i, 3:])).numpy(), s_ref, 1e-8, f"S at vertex {i}")


def acap_normals(v, f):
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    vn = np.zeros_like(v)
    for c in range(3):
        np.add.at(vn, f[:, c], fn)
    return vn / np.linalg.norm(vn, axis=1, keepdims=True)


def test_rest_mesh_encodes_to_identity(scape, scape_acap):
    feats = scape_acap.encode(scape.vertices[:1])
    expected = torch.tensor(IDENTITY_FEATURE, dtype=torch.float64).expand_as(feats)
    _assert_close(feats, expected, 1e-10, "rest features")
    _assert_close(scape_acap.decode(feats), scape.vertices[:1], 1e-10, "rest decode")


def test_rigid_motion_gives_rotation_features(icosphere):
    rest, faces = icosphere
    acap = ACAP(rest, faces)
    rot = Rotation.from_rotvec([0.3, -1.2, 0.7])
    moved = rot.apply(rest) * 1.5 + np.array([1.0, 2.0, 3.0])  # rotate, scale, translate
    feats = acap.encode(torch.from_numpy(moved[None]))[0].numpy()
    _assert_close(feats[:, :3], np.broadcast_to(rot.as_rotvec(), (len(rest), 3)), 1e-9, "rotation part")
    _assert_close(feats[:, 3:], np.broadcast_to([1.5, 0, 0, 1.5, 0, 1.5], (len(rest), 6)), 1e-9, "stretch")
    back = acap.decode(torch.from_numpy(feats[None]))[0].numpy()
    _assert_close(back - back.mean(0), moved - moved.mean(0), 1e-9, "decode of a similarity transform")


def test_scape_round_trip_all_meshes(scape, scape_acap):
    """Acceptance: decode(encode(V)) on all 71 SCAPE meshes, errors relative to the bbox diagonal."""
    feats = scape_acap.encode(scape.vertices)
    recon = scape_acap.decode(feats)
    err = relative_vertex_error(recon, scape.vertices)
    assert len(err.mean) == 71
    worst = int(err.mean.argmax())
    assert err.mean.max() <= 2e-3, f"mesh {scape.names[worst]}: mean error {err.mean.max():.2e} > 2e-3"
    worst = int(err.max.argmax())
    assert err.max.max() <= 1e-2, f"mesh {scape.names[worst]}: max error {err.max.max():.2e} > 1e-2"


def test_decode_gradcheck_float64():
    verts, faces = make_tube(n_rings=4, n_around=5, capped=True)
    acap = ACAP(verts, faces)
    rng = np.random.default_rng(0)
    feats = acap.encode(torch.from_numpy(twist(verts, 0.8)[None]))
    feats = feats + torch.from_numpy(rng.normal(scale=0.05, size=feats.shape))
    feats.requires_grad_(True)
    assert torch.autograd.gradcheck(acap.decode, (feats,), eps=1e-6, atol=1e-6)


def test_decode_gradcheck_at_identity():
    """The small-angle branch of Rodrigues' formula has the right derivative at r = 0."""
    verts, faces = make_tube(n_rings=3, n_around=4)
    acap = ACAP(verts, faces)
    feats = acap.identity_features(1, torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(acap.decode, (feats,), eps=1e-6, atol=1e-6)


def test_rotvec_to_matrix_matches_scipy():
    rng = np.random.default_rng(1)
    rv = np.concatenate([rng.normal(size=(50, 3)) * 2, rng.normal(size=(5, 3)) * 1e-4, np.zeros((1, 3)),
                         [[np.pi, 0, 0], [0, 0, 5.5]]])
    _assert_close(rotvec_to_matrix(torch.from_numpy(rv)).numpy(), Rotation.from_rotvec(rv).as_matrix(),
                  1e-12, "Rodrigues")


@pytest.mark.parametrize("root_at_twisted_end", [False, True])
def test_twisted_tube_features_are_continuous(root_at_twisted_end):
    """A tube twisted from 0 to 1.5 pi: rotation features change in small steps, no 2 pi jumps."""
    rest, faces = make_tube(n_rings=40, n_around=12)
    root = len(rest) - 1 if root_at_twisted_end else 0  # top cap centre, or a vertex of ring 0
    acap = ACAP(rest, faces, root=root)
    angles = np.linspace(0.0, 1.5 * np.pi, 16)
    seq = np.stack([twist(rest, a) for a in angles])
    feats = acap.encode(torch.from_numpy(seq)).numpy()
    rv = feats[..., :3]
    steps = np.linalg.norm(np.diff(rv, axis=0), axis=-1)  # (15, V)
    assert steps.max() < 0.5, f"largest change between consecutive meshes {steps.max():.3f} rad"
    # the far end really reaches 1.5 pi about +z, i.e. beyond the principal range [0, pi]
    top_ring = slice(39 * 12, 40 * 12)
    _assert_close(rv[-1, top_ring, 2], np.full(12, 1.5 * np.pi), 0.15, "twist angle at the far end")
    edge_jumps = np.linalg.norm(rv[:, acap.edges[:, 0]] - rv[:, acap.edges[:, 1]], axis=-1)
    assert edge_jumps.max() < 1.0, f"rotation jump {edge_jumps.max():.2f} rad across an edge"
    recon = acap.decode(torch.from_numpy(feats))
    err = relative_vertex_error(recon, torch.from_numpy(seq))
    assert err.mean.max() <= 2e-3 and err.max.max() <= 1e-2, (err.mean.max(), err.max.max())


def test_decode_float32_and_batch_shapes(scape, scape_acap):
    feats = scape_acap.encode(scape.vertices[:3]).float()
    out = scape_acap.decode(feats)
    assert out.dtype == torch.float32 and out.shape == (3, 2161, 3)
    single = scape_acap.decode(feats[1])
    _assert_close(single, out[1], 1e-5, "single vs batched decode")
    with pytest.raises(ValueError, match=r"expected \(B, 2161, 9\)"):
        scape_acap.decode(feats[:, :100])


@pytest.mark.gpu
def test_decode_on_cuda(scape, scape_acap):
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    feats = scape_acap.encode(scape.vertices[:2]).cuda().requires_grad_(True)
    out = scape_acap.decode(feats)
    assert out.device.type == "cuda"
    out.sum().backward()
    assert feats.grad.device.type == "cuda"


def test_no_gradient_decode_equals_the_differentiable_one(scape, scape_acap):
    """The numba right-hand side (``decode(..., fast=True)`` without a graph) against the torch ops
    of the differentiable decode, on real poses (large and small angles) and a near-identity pose (Taylor branch)."""
    feats = scape_acap.encode(scape.vertices[:6].to(torch.float64))
    feats = torch.cat([feats, scape_acap.identity_features(1, torch.float64) + 1e-5])
    graph = scape_acap.decode(feats.clone().requires_grad_(True)).detach()
    with torch.no_grad():
        fast = scape_acap.decode(feats, fast=True)
        assert torch.equal(scape_acap.decode(feats), graph), "the default keeps the torch path"
    assert fast.dtype == torch.float64 and torch.allclose(fast, graph, rtol=0, atol=1e-12)
    with torch.no_grad():
        fast32 = scape_acap.decode(feats.float(), fast=True)
    graph32 = scape_acap.decode(feats.float().requires_grad_(True)).detach()
    assert fast32.dtype == torch.float32 and torch.allclose(fast32, graph32, rtol=0, atol=1e-5)
    assert torch.allclose(scape_acap.decode(feats[0], fast=True), fast[0], rtol=0, atol=1e-12)  # one (V, 9) mesh


def test_decode_vertices_equals_full_decode_and_its_gradient():
    """decode_vertices(f, idx) is decode(f)[:, idx] (to round-off, float64), the pinned root included, and so
    is its gradient with respect to the features."""
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=2)
    rest = np.asarray(mesh.vertices)
    acap = ACAP(rest, np.asarray(mesh.faces))
    rng = np.random.default_rng(0)
    bent = rest * np.array([1.3, 0.8, 1.0]) + 0.05 * rng.normal(size=rest.shape)
    f = acap.encode(torch.as_tensor(np.stack([bent, rest]), dtype=torch.float64))
    f = (f + 0.01 * torch.randn(f.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(1)))
    f.requires_grad_(True)
    idx = np.array([acap.root, 5, 17, 17, 100, len(rest) - 1])
    full = acap.decode(f)
    part = acap.decode_vertices(f, idx)
    assert part.shape == (2, len(idx), 3)
    assert torch.allclose(part, full[:, idx], atol=1e-10, rtol=0)
    w = torch.randn(part.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    g_full = torch.autograd.grad((full[:, idx] * w).sum(), f)[0]
    g_part = torch.autograd.grad((part * w).sum(), f)[0]
    assert torch.allclose(g_part, g_full, atol=1e-9, rtol=0)
    single = acap.decode_vertices(f[0].detach(), idx)
    assert torch.allclose(single, full[0, idx].detach(), atol=1e-10, rtol=0)
    with pytest.raises(ValueError, match="vertex indices"):
        acap.decode_vertices(f.detach(), [len(rest)])


def test_acap_survives_pickling_with_the_same_decode():
    """A pickled ACAP (the label pool's workers decode with one) factorises its Laplacian again and
    decodes bit for bit like the original."""
    import pickle

    import trimesh

    s = trimesh.creation.icosphere(subdivisions=2)
    rest = np.asarray(s.vertices, np.float64)
    acap = ACAP(rest, np.asarray(s.faces))
    posed = rest * np.array([1.2, 0.9, 1.0]) + 0.05 * np.sin(3 * rest)
    feats = acap.encode(torch.as_tensor(posed[None]))
    copy = pickle.loads(pickle.dumps(acap))
    assert torch.equal(copy.decode(feats), acap.decode(feats))
    with torch.no_grad():
        assert torch.equal(copy.decode(feats, fast=True), acap.decode(feats, fast=True))
