"""The pruned full label (default) gives exactly the labels of the reference path that evaluates every pair
within the clearance cap (``ExactLabeler(..., prune=False)``): same verdict and pair count, bit-identical PD,
PD_i and vertex depths, on meshes that collide and that do not, with and without a partition."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from neuralcol.collision.labeler import ExactLabeler


def _assert_same(rest, faces, meshes, partition=None, clearance_cap=0.01):
    pruned = ExactLabeler(faces, rest, partition=partition, clearance_cap=clearance_cap)
    ref = ExactLabeler(faces, rest, partition=partition, clearance_cap=clearance_cap, prune=False)
    n_colliding = 0
    for v in meshes:
        a, b = pruned.label(v), ref.label(v)
        assert (a.collides, a.n_pairs) == (b.collides, b.n_pairs)
        assert a.pd == b.pd
        np.testing.assert_array_equal(a.pd_sub, b.pd_sub)
        np.testing.assert_array_equal(pruned.vertex_depths(v), ref.vertex_depths(v))
        n_colliding += a.collides
    return n_colliding


def _subdivide(verts, faces, levels, rng):
    """Midpoint subdivision plus a 1e-6 diagonal jitter (as the bench's scaling meshes)."""
    for _ in range(levels):
        verts, faces = trimesh.remesh.subdivide(verts, faces)
    diag = float(np.linalg.norm(verts.max(0) - verts.min(0)))
    return verts + rng.normal(scale=1e-6 * diag / np.sqrt(3), size=verts.shape), np.asarray(faces)


def _blocks(n, k):
    return (np.arange(n) * k) // n


@pytest.mark.parametrize("partition", [None, "blocks", "random"])
def test_two_spheres_far_and_near_pairs(partition):
    """Two spheres in one mesh (far pairs across them, near pairs within each), squeezed and moved from apart
    through contact to overlap; a large cap so that far pairs matter."""
    s = trimesh.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(0)
    faces = np.concatenate([s.faces, s.faces + len(s.vertices)])
    rest = np.concatenate([s.vertices, s.vertices + [3.0, 0.0, 0.0]])
    part = {None: None, "blocks": _blocks(len(rest), 3), "random": rng.integers(0, 4, len(rest))}[partition]
    meshes = []
    for gap in (0.6, 0.25, 0.05, 0.0, -0.05, -0.4):
        v = rest.copy()
        v[len(s.vertices):, 0] -= 1.0 - gap
        v[:, 1] *= 1.0 + 0.2 * np.sin(3 * v[:, 0])  # non-rigid: near pairs change their separation
        meshes.append(v)
    cap = 0.3 / float(np.linalg.norm(rest.max(0) - rest.min(0)))
    assert _assert_same(rest, faces, meshes, part, clearance_cap=cap) >= 2


def test_pinched_sphere_near_pairs():
    """One sphere pinched at its waist until the two sides touch and cross: only near pairs and far pairs
    of the same surface."""
    s = trimesh.creation.icosphere(subdivisions=3)
    rest = np.asarray(s.vertices, dtype=np.float64)
    meshes = []
    for depth in (0.5, 0.9, 0.99, 1.05):
        v = rest.copy()
        v[:, 1] *= 1.0 - depth * np.exp(-(v[:, 0] / 0.3) ** 2)
        v[:, 2] *= 1.0 - 0.5 * depth * np.exp(-(v[:, 0] / 0.3) ** 2)
        meshes.append(v)
    _assert_same(rest, np.asarray(s.faces), meshes, _blocks(len(rest), 2), clearance_cap=0.05)


def test_scape_raw_deformed_and_subdivided(scape):
    verts = scape.vertices.numpy().astype(np.float64)
    faces = scape.faces.numpy().astype(np.int64)
    rng = np.random.default_rng(1)
    meshes = [verts[7], verts[70], verts[20], verts[3] + 1.6 * (verts[9] - verts[3]),
              verts[15] + 2.0 * (verts[30] - verts[15])]  # files 8 and 71 collide; the extrapolations too
    assert _assert_same(verts[0], faces, meshes, _blocks(len(verts[0]), 4)) >= 3
    sv, sf = zip(*[_subdivide(v, faces, 1, rng) for v in (verts[0], verts[7], verts[33])])
    assert _assert_same(sv[0], sf[0], sv[1:], _blocks(len(sv[0]), 4)) == 1


def test_labels_do_not_depend_on_triangle_order():
    """The pruned path visits pairs in an order set by the triangle ids; a pair is ruled out only with a margin
    over the round-off of its bound, so relabelling the triangles gives bit-identical labels (the pinched sphere
    has many pairs at equal distance by symmetry: ties where an order effect would show)."""
    s = trimesh.creation.icosphere(subdivisions=3)
    rest = np.asarray(s.vertices, dtype=np.float64)
    faces = np.asarray(s.faces)
    perm = np.random.default_rng(3).permutation(len(faces))
    part = _blocks(len(rest), 2)
    a = ExactLabeler(faces, rest, partition=part, clearance_cap=0.05)
    b = ExactLabeler(faces[perm], rest, partition=part, clearance_cap=0.05)
    for depth in (0.5, 0.9, 0.99, 1.05):
        v = rest.copy()
        v[:, 1] *= 1.0 - depth * np.exp(-(v[:, 0] / 0.3) ** 2)
        v[:, 2] *= 1.0 - 0.5 * depth * np.exp(-(v[:, 0] / 0.3) ** 2)
        la, lb = a.label(v), b.label(v)
        assert (la.collides, la.n_pairs) == (lb.collides, lb.n_pairs)
        np.testing.assert_array_equal(la.pd_sub, lb.pd_sub)
