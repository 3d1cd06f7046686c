"""The far pass over the rest mesh's triangle clusters (``ExactLabeler(far_clusters=k)``, the default) gives the labels
of the grid over every triangle (``far_clusters=0``, the path before clusters) bit for bit, on SCAPE poses that collide
and that do not (limited and full labels, vertex depths); and its candidate pairs are exactly the grid's pairs with
overlapping boxes, less adjacent and near ones."""

from __future__ import annotations

import numpy as np
import pytest

from neuralcol.collision.kernels.broadphase import grid_pairs, triangle_aabbs
from neuralcol.collision.kernels.clusters import cluster_candidates
from neuralcol.collision.labeler import ExactLabeler


def _poses(scape):
    """SCAPE poses (files 7 and 70 collide), extrapolated poses (most collide) and smoothly perturbed ones."""
    verts = scape.vertices.numpy()
    rest = verts[0]
    poses = [verts[k] for k in (1, 7, 20, 70)]
    poses += [rest + t * (verts[k] - rest) for k, t in ((1, 1.5), (3, 2.0), (4, 2.5), (30, 2.0))]
    rng = np.random.default_rng(0)
    diag = float(np.linalg.norm(rest.max(0) - rest.min(0)))
    for k in (2, 5):
        freq = rng.normal(size=(3, 3)) * 4.0 / diag
        poses.append(verts[k] + 0.01 * diag * np.sin(verts[k] @ freq + rng.uniform(0, 6, 3)))
    return rest, poses


@pytest.mark.parametrize(("far_clusters", "n_parts"), [(6, 16), (1, 1), (3, 4), (8, 16)])
def test_far_clusters_give_the_grid_labels(scape, far_clusters, n_parts):
    rest, poses = _poses(scape)
    faces = scape.faces.numpy()
    part = (np.arange(len(rest)) * n_parts) // len(rest)
    new = ExactLabeler(faces, rest, partition=part, far_clusters=far_clusters)
    old = ExactLabeler(faces, rest, partition=part, far_clusters=0)
    limit = 0.25 * new.cap * (1 + 1e-9)  # the training labels' limit
    n_colliding = 0
    for v in poses:
        for lim in (limit, None):
            a, b = new.label_limited(v, lim), old.label_limited(v, lim)
            assert (a.collides, a.n_pairs) == (b.collides, b.n_pairs)
            assert a.pd == b.pd
            np.testing.assert_array_equal(a.pd_sub, b.pd_sub)
        np.testing.assert_array_equal(new.vertex_depths(v), old.vertex_depths(v))
        n_colliding += a.collides
    assert 3 <= n_colliding <= len(poses) - 3


def test_cluster_candidates_are_the_grid_pairs_less_adjacent_and_near(scape):
    rest, poses = _poses(scape)
    faces = scape.faces.numpy()
    lab = ExactLabeler(faces, rest)
    n_faces = len(faces)
    near_keys = np.repeat(np.arange(n_faces), np.diff(lab._near_ptr)) * n_faces + lab._near_b
    for v in (poses[2], poses[6]):
        for grow in (0.0, 0.25 * lab.cap, lab.cap):
            lo, hi = triangle_aabbs(v, lab.faces, 0.5 * grow)
            cand = cluster_candidates(lo, hi, *lab._clusters)
            keys = cand[:, 0] * n_faces + cand[:, 1]
            assert (cand[:, 0] < cand[:, 1]).all() and len(np.unique(keys)) == len(keys)  # each pair once
            grid = grid_pairs(lo, hi, lab.cell)
            grid_keys = grid[:, 0] * n_faces + grid[:, 1]
            shared = (faces[grid[:, 0], :, None] == faces[grid[:, 1], None, :]).any((1, 2))
            far = ~shared & ~np.isin(grid_keys, near_keys)
            assert np.isin(keys, grid_keys).all()  # only pairs with overlapping boxes
            assert np.isin(grid_keys[far], keys).all()  # every far one of them


def test_far_clusters_out_of_range(scape):
    with pytest.raises(ValueError, match="far_clusters"):
        ExactLabeler(scape.faces.numpy(), scape.vertices[0].numpy(), far_clusters=9)
