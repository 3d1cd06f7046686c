"""bench/labeler_body.py's mesh refinement: edge splits keep the surface, its orientation and its collision state."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from bench.labeler_body import scape_at_size, split_edges


def test_split_edges_keeps_the_closed_surface():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    rest, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    new_faces, ends = split_edges(faces, rest, 50)
    verts = np.concatenate([rest, 0.5 * (rest[ends[:, 0]] + rest[ends[:, 1]])])
    out = trimesh.Trimesh(verts, new_faces, process=False)
    assert len(new_faces) == len(faces) + 100 and len(verts) == len(rest) + 50
    assert out.is_watertight and out.is_winding_consistent
    assert out.volume == pytest.approx(sphere.volume, rel=1e-12)  # midpoints on flat triangles: same surface
    # the longest edges went first, and no triangle lost two edges
    length = np.linalg.norm(rest[ends[:, 0]] - rest[ends[:, 1]], axis=1)
    assert length.min() >= np.percentile(np.linalg.norm(rest[sphere.edges_unique[:, 0]]
                                                         - rest[sphere.edges_unique[:, 1]], axis=1), 50)
    with pytest.raises(ValueError, match="one per triangle"):
        split_edges(faces, rest, len(faces))


def test_scape_at_size_hits_the_count_and_stays_free():
    from neuralcol.collision.labeler import ExactLabeler

    sphere = trimesh.creation.icosphere(subdivisions=1)  # 80 triangles -> 320 -> 500 by splits
    poses = np.stack([sphere.vertices, sphere.vertices * 1.5 + 0.1])
    sv, sf = scape_at_size(poses, np.asarray(sphere.faces), 500, np.random.default_rng(0))
    assert len(sf) == 500 and sv.shape[0] == 2
    assert trimesh.Trimesh(sv[1], sf, process=False).is_watertight
    assert not ExactLabeler(sf, sv[0]).verdict(sv[1])
    with pytest.raises(ValueError, match="edge splits"):
        scape_at_size(poses, np.asarray(sphere.faces), 501, np.random.default_rng(0))
