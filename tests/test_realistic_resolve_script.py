"""``research/anymesh/realistic_resolve.py`` on a tiny synthetic case (two icospheres, no data set): its core
measurement and its motion metrics still run and report what they claim."""

from __future__ import annotations

import numpy as np
import trimesh

from research.anymesh.realistic_resolve import evaluate_resolve, motion_metrics, pick_colliding, sweep


def two_spheres(offsets) -> tuple[np.ndarray, np.ndarray]:
    """Meshes (B, V, 3) of two unit icospheres (42 vertices each), the second shifted by each offset along x (< 2:
    they overlap), and their faces (F, 3)."""
    s = trimesh.creation.icosphere(subdivisions=1)
    v, f = np.asarray(s.vertices, np.float64), np.asarray(s.faces, np.int64)
    meshes = np.stack([np.concatenate([v, v + [o, 0.0, 0.0]]) for o in offsets])
    return meshes, np.concatenate([f, f + len(v)])


def test_pick_colliding_caps_and_keeps_near_boundary_first():
    pd = np.array([-1.0, 0.5, 2.0, 3.0, 0.1, 4.0, np.nan, 5.0])
    clear = np.abs(pd) >= 1.0
    assert pick_colliding(pd, clear, 10, 0).tolist() == [1, 2, 3, 4, 5, 7]
    few = pick_colliding(pd, clear, 4, 0)
    assert len(few) == 4 and np.all(pd[few] > 0)
    assert len({1, 4} & set(few.tolist())) == 1  # near-boundary ones (PD 0.5, 0.1): a quarter of the 4
    assert np.array_equal(few, pick_colliding(pd, clear, 4, 0))  # deterministic


def test_sweep_goes_there_and_back():
    t = sweep(1.0, 1.5, 24)
    assert t[0] == 1.0 and abs(t[-1] - 1.0) < 1e-12 and 1.49 < t.max() <= 1.5 and np.argmax(t) in (11, 12)


def test_evaluate_resolve_on_two_spheres():
    import neuralcol

    offsets = [2.6, 1.7, 1.85, 2.4, 1.98, 3.0]
    meshes, f = two_spheres(offsets)
    rest = meshes[0]
    pd = neuralcol.check(meshes, f, rest=rest).pd
    assert (pd > 0).sum() == 3
    diag = float(np.linalg.norm(np.ptp(rest, axis=0)))
    out = evaluate_resolve(meshes, pd, f, rest, eps=1e-3 * diag, clear_eps=10, max_meshes=10, n_free=2, seed=0)
    assert out["used"]["colliding"] == 3 and out["all"]["n"] == 3
    assert out["used"]["clear"] + out["used"]["near_boundary"] == 3
    assert out["all"]["freed"] == 1.0 and out["all"]["freed_by_check"] == 1.0 and not out["not_freed"]
    assert 0 < out["all"]["median_largest_move"] < 0.5 and out["all"]["seconds_max"] > 0
    assert out["same_as_resolve"] is True
    assert out["free_identity"] == {**out["free_identity"], "n": 2, "bit_identical": 2}
    assert len(out["per_mesh"]) == 3 and all(m["freed"] for m in out["per_mesh"])


def test_motion_metrics_on_spheres_meeting_and_parting():
    offsets = 3.0 - 1.3 * np.sin(np.pi * np.arange(8) / 7)  # apart, overlapping in the middle, apart again
    frames, f = two_spheres(offsets)
    m = motion_metrics(frames, f, frames[0])
    assert m["colliding_in"] > 0 and m["every_frame_free"] and m["colliding_after"] == 0
    assert np.isfinite(m["jump_ratio"]) and m["seconds_per_frame"] > 0 and m["frames"] == 8
