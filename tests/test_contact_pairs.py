"""Contact-pair features (what the detector over code and mesh reads): analytic cases, hop neighbourhoods,
gradients. The pair choice per sub-domain: tests/test_part_geometry.py."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from neuralcol.geometry.contact_pairs import ContactFeatures, hop_neighbourhood, vertex_normals


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
