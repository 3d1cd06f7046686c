"""Contact-pair features and the mesh-reading detector (issue 27): analytic cases, the pair choice, gradients,
and the saved detector loading without pickles."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from neuralcol.geometry.contact_pairs import ContactFeatures, hop_neighbourhood, select_contact_pairs, vertex_normals


def two_cubes(gap: float) -> tuple[np.ndarray, np.ndarray]:
    """Two unit cubes side by side along x, the second shifted by 1 + gap (gap < 0: they overlap)."""
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    v, f = np.asarray(box.vertices, np.float64) + 0.5, np.asarray(box.faces, np.int64)  # corners in {0, 1}^3
    w = v + np.array([1.0 + gap, 0.0, 0.0])
    return np.concatenate([v, w]), np.concatenate([f, f + len(v)])


def facing_pair(v: np.ndarray) -> tuple[int, int]:
    """Cube A's corner (1, 0, 0) and cube B's corner at A's (1, 0, 0) + (gap, 0, 0)."""
    n = len(v) // 2
    i = int(np.flatnonzero(np.all(np.isclose(v[:n], [1, 0, 0]), 1))[0])
    j = n + int(np.flatnonzero(np.all(np.isclose(v[n:] - v[n:].min(0), [0, 0, 0]), 1))[0])
    return i, j


def test_vertex_normals_of_a_cube_point_out_along_the_diagonals():
    v, f = two_cubes(0.5)
    n = vertex_normals(torch.as_tensor(v)[None], torch.as_tensor(f))[0].numpy()
    centre = np.where(np.arange(len(v))[:, None] < 8, 0.5, 0.5 + 1.5 * np.array([1, 0, 0]))
    out = v - centre
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    assert (np.sum(n * out, 1) > 0.5).all()  # outward, roughly along the corner's diagonal


@pytest.mark.parametrize("gap", [0.3, 0.05, -0.05, -0.3])
def test_signed_offsets_tell_touching_from_penetrating(gap):
    """Facing corners: the distance is |gap| (in radii) on both sides of contact, the signed offsets have the
    sign of the gap: apart both > 0, passed through each other both < 0."""
    v, f = two_cubes(gap)
    i, j = facing_pair(v)
    radius = 0.1
    feats = ContactFeatures(np.array([[i, j]]), f, radius=radius, clip=10.0)(torch.as_tensor(v))[0].numpy()
    dist, s_min, s_max = feats
    assert dist == pytest.approx(abs(gap) / radius)
    # the offsets are gap * n_x at each corner (n: the corner's outward vertex normal, n_x > 0 on A's corner at
    # x = 1 and n_x < 0 on B's corner at its x minimum): both have the sign of the gap
    n = vertex_normals(torch.as_tensor(v)[None], torch.as_tensor(f))[0].numpy()
    assert n[i, 0] > 0.1 and n[j, 0] < -0.1
    expect = sorted([gap * n[i, 0] / radius, -gap * n[j, 0] / radius])
    assert [s_min, s_max] == pytest.approx(expect, rel=1e-9)
    assert np.sign(s_min) == np.sign(s_max) == np.sign(gap)
    clipped = ContactFeatures(np.array([[i, j]]), f, radius=radius, clip=1.0)(torch.as_tensor(v))[0].numpy()
    assert (np.abs(clipped) <= 1.0).all()


def test_features_are_differentiable():
    v, f = two_cubes(0.1)
    i, j = facing_pair(v)
    feats = ContactFeatures(np.array([[i, j], [0, 9]]), f, radius=1.0, clip=10.0).double()
    x = torch.as_tensor(v + 0.01 * np.random.default_rng(0).standard_normal(v.shape), dtype=torch.float64)
    x.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda y: feats(y[None]), (x,), eps=1e-6, atol=1e-5)


def test_hop_neighbourhood_on_a_strip():
    # a strip of triangles: vertex k is adjacent to k +- 1 and k +- 2
    f = np.array([[k, k + 1, k + 2] for k in range(8)])
    near = hop_neighbourhood(f, 10, 1).toarray() > 0
    assert near[0, 2] and not near[0, 3]
    near2 = hop_neighbourhood(f, 10, 2).toarray() > 0
    assert near2[0, 4] and not near2[0, 5]


def test_select_pairs_far_on_the_mesh_close_in_the_examples():
    v, f = two_cubes(0.02)
    far, _ = two_cubes(2.0)
    i, j = facing_pair(v)
    pairs = select_contact_pairs(np.stack([v, far, v]), np.array([True, False, False]), f, radius=0.1, min_hops=1,
                                 n_pairs=10, colliding_weight=3.0)
    # the 4 facing corner pairs (the cubes' faces x = 1 and x = 1.02) are the only ones within 0.1
    assert len(pairs) == 4 and (pairs[:, 0] < 8).all() and (pairs[:, 1] >= 8).all()
    assert [i, j] in pairs.tolist()
    d = np.linalg.norm(v[pairs[:, 0]] - v[pairs[:, 1]], axis=1)
    np.testing.assert_allclose(d, 0.02)
    none = select_contact_pairs(far[None], np.array([False]), f, radius=0.1, min_hops=1, n_pairs=10)
    assert none.shape == (0, 2)


def test_select_pairs_max_per_vertex_spreads_the_pairs():
    """Cubes 0.05 apart, radius 1.02: each facing corner of A is within reach of three of B's (0.05 and two at
    ~1.001): 12 pairs, every facing corner in 3; the cap keeps at most k per vertex, most frequent first."""
    v, f = two_cubes(0.05)
    free = select_contact_pairs(v[None], np.array([True]), f, radius=1.02, min_hops=1, n_pairs=100)
    capped = select_contact_pairs(v[None], np.array([True]), f, radius=1.02, min_hops=1, n_pairs=100,
                                  max_per_vertex=1)
    counts = np.bincount(free.ravel(), minlength=len(v))
    assert counts.max() == 3 and len(free) == 12
    assert np.bincount(capped.ravel(), minlength=len(v)).max() == 1 and len(capped) == 4
    assert {tuple(p) for p in capped} <= {tuple(p) for p in free}
    two = select_contact_pairs(v[None], np.array([True]), f, radius=1.02, min_hops=1, n_pairs=5, max_per_vertex=2)
    assert len(two) == 5 and np.bincount(two.ravel()).max() <= 2
    with pytest.raises(ValueError, match="max_per_vertex"):
        select_contact_pairs(v[None], np.array([True]), f, radius=1.02, min_hops=1, n_pairs=5, max_per_vertex=0)


def test_select_pairs_folding_bounds_memory_and_changes_nothing():
    """Issue 31: the close pairs are folded into running scores every ``fold_at`` pairs (a body mesh has ~10^6 close
    pairs per example; held all at once they took 20 GB). Any fold size gives the pairs of one fold."""
    v, f = two_cubes(0.05)
    rng = np.random.default_rng(0)
    meshes = v[None] + rng.normal(scale=0.05, size=(12, *v.shape))
    collides = rng.random(12) < 0.4
    kw = dict(radius=1.02, min_hops=1, n_pairs=30, colliding_weight=3.0)
    once = select_contact_pairs(meshes, collides, f, **kw, fold_at=10**9)
    for fold_at in (1, 7, 50):
        np.testing.assert_array_equal(select_contact_pairs(meshes, collides, f, **kw, fold_at=fold_at), once)
    assert 10 < len(once) <= 30


def test_mesh_detector_saves_and_loads_without_pickles(tmp_path):
    from neuralcol.nn.mesh_detector import MeshDetector, load_mesh_detector, mesh_logits, save_mesh_detector

    v, f = two_cubes(0.1)
    i, j = facing_pair(v)
    net = MeshDetector(ContactFeatures(np.array([[i, j], [1, 12]]), f, radius=0.1), hidden=8)
    save_mesh_detector(tmp_path / "m.pt", net)
    back = load_mesh_detector(tmp_path / "m.pt")
    meshes = np.stack([two_cubes(g)[0] for g in (0.2, -0.2)])
    np.testing.assert_allclose(mesh_logits(back, meshes), mesh_logits(net, meshes), atol=1e-6)
