"""bench.repair: the figures of a set from resolve's results, and ipctk's barrier path kept free from a free start."""

from __future__ import annotations

import numpy as np
import pytest
from fault_labelers import two_spheres

from bench.repair import barrier_path, resolve_set


def test_resolve_set_frees_overlapping_spheres_and_reports_moves():
    meshes, faces = [], []
    for offset in (1.7, 1.8):
        v, f = two_spheres(offset, subdivisions=2)
        meshes.append(v)
        faces.append(f)
    fig, rows = resolve_set(meshes, faces)
    assert fig["freed"]["median"] == 1.0 and fig["meshes"]["median"] == 2
    depth = [2.0 - 1.7, 2.0 - 1.8]  # the spheres' overlap; a move frees them only if it covers about half of it
    for r, d, v in zip(rows, depth, meshes):
        diag = np.linalg.norm(np.ptp(v, axis=0))
        assert r["freed"] and 0.4 * d / diag < r["largest"] < 3 * d / diag
        assert r["to_depth"] == pytest.approx(r["largest"] * diag / d, rel=0.1)  # the exact PD is about d
    assert fig["largest_move_p95"]["median"] >= fig["largest_move_median"]["median"] > 0


def test_barrier_path_stays_free_and_moves_back_towards_the_input():
    pytest.importorskip("ipctk")
    from neuralcol.collision.labeler import ExactLabeler

    target, faces = two_spheres(1.8, subdivisions=1)
    start, _ = two_spheres(2.3, subdivisions=1)
    lab = ExactLabeler(faces, start)
    x, its = barrier_path(start, target, faces, lab.ell, max_iter=30)
    assert not lab.verdict(x) and its >= 1
    assert np.linalg.norm(x - target, axis=1).max() < np.linalg.norm(start - target, axis=1).max()
