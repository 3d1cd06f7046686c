"""``labeler_body``: the labeler at Swing/Jump size, side by side with MeshLab.

Two sets of meshes with the same number of triangles (26 692, anny's main shell):

- ``body_*``: poses of ``dataset=anny_body`` (realistic bodies; half of the timed poses collide, as the crouching
  and reaching poses do), needs the ``body`` extra (anny);
- ``scape_at_body_size_*``: collision-free SCAPE poses subdivided once (17 272 triangles), then the longest edges of
  the rest mesh split at their midpoints until the count matches (:func:`split_edges`: the surface and its
  collision state do not change, only the triangulation), jittered by 1e-6 of the diagonal as in
  ``bench/labeler.py``.

Keys: ``*_full_label_ms``, ``*_verdict_ms``, ``*_meshlab_ms`` (MeshLab's self-intersection filter, mesh upload
excluded) and the ratios ``*_full_label_vs_meshlab`` (target <= 1) and ``*_verdict_vs_meshlab``.
"""

from __future__ import annotations

import numpy as np

from bench.context import BenchContext
from bench.labeler import _jittered_subdivision, meshlab_times
from bench.timing import per_mesh_times, ratio, summarize

BODY_TRIANGLES = 26_692  # anny's main shell (neuralcol/data/procedural/body.py)


def split_edges(faces: np.ndarray, rest: np.ndarray, n_splits: int) -> tuple[np.ndarray, np.ndarray]:
    """Split ``n_splits`` edges of a closed manifold mesh at their midpoints, longest first (in ``rest``), no two
    in one triangle, so each split turns its two triangles into four (+2 triangles, +1 vertex).

    Args:
        faces: (F, 3) int triangles, consistently oriented.
        rest: (V, 3) positions that rank the edges by length.
        n_splits: edges to split; at most one per triangle, so at most F / 2.

    Returns:
        (new faces (F + 2 n, 3) with the same orientation, (n, 2) the end points of each new vertex, which is
        vertex ``V + i``: place it at the midpoint of ``ends[i]`` in every pose).
    """
    faces = np.asarray(faces, dtype=np.int64)
    n_v = len(rest)
    e = np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], 1).reshape(-1, 2)  # directed, 3 per face
    key = np.minimum(e[:, 0], e[:, 1]) * n_v + np.maximum(e[:, 0], e[:, 1])
    uniq, inv = np.unique(key, return_inverse=True)
    a, b = uniq // n_v, uniq % n_v
    length = np.linalg.norm(rest[a] - rest[b], axis=1)
    owners = [[] for _ in range(len(uniq))]
    for row, k in enumerate(inv):
        owners[k].append(row)
    used = np.zeros(len(faces), dtype=bool)
    chosen: list[tuple[int, list[int]]] = []
    for k in np.argsort(-length, kind="stable"):
        rows = owners[k]
        tris = [r // 3 for r in rows]
        if len(rows) != 2 or used[tris].any():
            continue
        used[tris] = True
        chosen.append((int(k), rows))
        if len(chosen) == n_splits:
            break
    if len(chosen) < n_splits:
        raise ValueError(f"only {len(chosen)} edges can be split one per triangle; asked {n_splits}")
    out = [faces[~used]]
    ends = np.empty((n_splits, 2), dtype=np.int64)
    for i, (k, rows) in enumerate(chosen):
        m = n_v + i
        ends[i] = (a[k], b[k])
        for r in rows:
            f, j = faces[r // 3], r % 3  # the split edge runs from corner j to corner j + 1
            x, y, z = f[j], f[(j + 1) % 3], f[(j + 2) % 3]
            out.append(np.array([[x, m, z], [m, y, z]]))
    return np.concatenate(out), ends


def scape_at_size(verts: np.ndarray, faces: np.ndarray, triangles: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """SCAPE meshes ``verts`` (N, V, 3) (the first is the rest mesh that ranks the edges) refined to exactly
    ``triangles`` triangles: subdivided while that stays at or below it, then edges split."""
    levels = 0
    while len(faces) * 4 ** (levels + 1) <= triangles:
        levels += 1
    sub, sf = _jittered_subdivision(verts, faces, levels, rng) if levels else (verts, faces)
    extra = triangles - len(sf)
    if extra % 2:
        raise ValueError(f"{triangles} triangles cannot be reached from {len(sf)} by edge splits (+2 each)")
    nf, ends = split_edges(sf, sub[0], extra // 2)
    mids = 0.5 * (sub[:, ends[:, 0]] + sub[:, ends[:, 1]])
    return np.concatenate([sub, mids], 1), nf


def _timed(lab, meshes, faces, reps) -> dict:
    out = {
        "verdict_ms": summarize(per_mesh_times(lab.verdict, meshes, reps), 1e3),
        "meshlab_ms": summarize(meshlab_times(meshes, faces, reps), 1e3),
        "full_label_ms": summarize(per_mesh_times(lab.label, meshes, reps), 1e3),
    }
    out["verdict_vs_meshlab"] = ratio(out["verdict_ms"], out["meshlab_ms"])
    out["full_label_vs_meshlab"] = ratio(out["full_label_ms"], out["meshlab_ms"])
    return out


def body_poses(cache_dir, n_each: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """(rest (V, 3), timed poses (2 n_each, V, 3): the first ``n_each`` collision-free and the first ``n_each``
    colliding poses of ``dataset=anny_body``, faces, their indices)."""
    from neuralcol.collision.labeler import ExactLabeler
    from neuralcol.data.datasets import load_procedural_dataset

    ds = load_procedural_dataset("anny_body", 150, 0, cache_dir=cache_dir)
    v = ds.vertices.numpy().astype(np.float64)
    f = ds.faces.numpy()
    lab = ExactLabeler(f, v[0])
    hit = np.array([lab.verdict(x) for x in v])
    free = [i for i in np.nonzero(~hit)[0][1:n_each + 1]]
    coll = [i for i in np.nonzero(hit)[0][:n_each]]
    idx = [int(i) for i in free + coll]
    return v[0], v[idx], f, idx


def measure(ctx: BenchContext) -> dict:
    """The full label, verdict and MeshLab at anny's 26 692 triangles: anny_body poses and SCAPE refined to it."""
    from neuralcol.collision.labeler import ExactLabeler

    reps = max(2, ctx.reps // 2)
    n_each = 2 if ctx.quick else 4
    out: dict = {}
    try:
        rest, poses, faces, idx = body_poses(f"{ctx.cfg.paths.cache_dir}/datasets", n_each)
    except ImportError as err:  # the body extra is not installed
        ctx.notes["labeler_body"] = f"anny_body poses skipped: {err}"
    else:
        lab = ExactLabeler(faces, rest)
        lab.label(poses[0])  # numba cache / compile outside the timing
        body = _timed(lab, poses, faces, reps)
        free = _timed(lab, poses[:n_each], faces, reps)["full_label_ms"]
        coll = _timed(lab, poses[n_each:], faces, reps)["full_label_ms"]
        out.update({f"body_{k}": v for k, v in body.items()})
        out["body_full_label_free_ms"], out["body_full_label_colliding_ms"] = free, coll
        ctx.notes["labeler_body"] = (f"anny_body poses {idx} ({len(faces)} triangles; the last {n_each} collide)")
    ds = ctx.scape
    verts = ds.vertices.numpy().astype(np.float64)
    lab0 = ExactLabeler(ds.faces.numpy(), verts[0])
    free = [i for i in range(1, len(verts)) if not lab0.verdict(verts[i])][: 2 * n_each]
    sv, sf = scape_at_size(verts[[0, *free]], ds.faces.numpy(), BODY_TRIANGLES, np.random.default_rng(0))
    slab = ExactLabeler(sf, sv[0])
    flagged = sum(slab.verdict(v) for v in sv[1:])
    if flagged:
        raise RuntimeError(f"{flagged} collision-free SCAPE meshes flagged after refinement to {len(sf)} triangles")
    slab.label(sv[1])
    out.update({f"scape_at_body_size_{k}": v for k, v in _timed(slab, sv[1:], sf, reps).items()})
    ctx.notes["labeler_body"] = (ctx.notes.get("labeler_body", "") + f"; SCAPE poses {[ds.names[i] for i in free]} "
                                 f"refined to {len(sf)} triangles, {sv.shape[1]} vertices")
    return out
