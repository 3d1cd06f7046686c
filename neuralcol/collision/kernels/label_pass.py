"""Whole-mesh label passes of the reference path: the verdict, the pass over every candidate pair
(``ExactLabeler(prune=False)``), and the per-part PD_i and vertex depths from the crossing records
(``finish_label``, shared with the pruned path and the Warp labeler)."""

from __future__ import annotations

import numpy as np
from numba import njit

from neuralcol.collision.kernels.broadphase import grid_pairs, shared_vertex_count
from neuralcol.collision.kernels.depth import opposite_edges_cross, plane_separated, triangle_pair_depth
from neuralcol.collision.kernels.pair_terms import add_crossings, lower_clearance, near_index, pair_terms
from neuralcol.collision.kernels.penetration import crossing_seeds, penetration
from neuralcol.collision.kernels.vec import corners


@njit(cache=True)
def verdict_kernel(verts, faces, lo, hi, cell, scale, tau):
    pairs = grid_pairs(lo, hi, cell)
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        shared = shared_vertex_count(faces, a, b)
        if shared >= 2:
            continue
        if shared == 1 and not opposite_edges_cross(verts, faces, a, b):
            continue
        p0, p1, p2 = corners(verts, faces, a)
        q0, q1, q2 = corners(verts, faces, b)
        if shared == 0 and plane_separated(p0, p1, p2, q0, q1, q2, tau):
            continue
        if triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale) > tau:
            return True
    return False


@njit(cache=True)
def pair_pass(verts, faces, pairs, scale, tau, cap, part, clear, floor, adj_ptr, adj_idx, adj_eid, orient,
              near_ptr, near_b, near_rest):
    """Depth and clearance of every candidate pair: lowers ``clear`` and raises ``floor`` (per part) in place.

    Returns:
        n_pairs (counted pairs), and the crossing records (rec_key, rec_int, n_rec) of the counted pairs.
    """
    rec_key = np.empty(64)
    rec_int = np.empty((64, 5), dtype=np.int64)
    n_rec = 0
    n_pairs = 0
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        shared = shared_vertex_count(faces, a, b)
        idx = near_index(near_ptr, near_b, a, b)
        evaluated, depth, c = pair_terms(verts, faces, a, b, shared, idx, near_rest, scale, tau, cap, clear, part)
        if not evaluated:
            continue
        lower_clearance(clear, part, faces, a, b, c)
        if depth <= tau:
            continue  # apart, or touching within tau: not counted, no crossing edges
        n_pairs += 1
        for t in (a, b):
            for i in range(3):
                pi = part[faces[t, i]]
                floor[pi] = max(floor[pi], depth - tau)
        rec_key, rec_int, n_rec = add_crossings(verts, faces, a, b, adj_ptr, adj_idx, adj_eid, orient,
                                                rec_key, rec_int, n_rec)
    return n_pairs, rec_key, rec_int, n_rec


@njit(cache=True)
def finish_label(verts, faces, rec_key, rec_int, n_rec, n_edges, floor, clear, part, n_parts, cap,
                 adj_ptr, adj_idx, adj_eid, closed):
    """Per-part PD_i (K,) and per-vertex penetration depth (V,) from the crossing records and the per-part
    clearance / pair-depth floor of :func:`pair_pass`."""
    n_vert = verts.shape[0]
    seeds, blocked = crossing_seeds(rec_key, rec_int, n_rec, n_edges)
    pos = floor.copy()
    depth_v = np.zeros(n_vert)
    if seeds.shape[0] > 0:
        depth_v, _ = penetration(verts, faces, seeds, adj_ptr, adj_idx, adj_eid, blocked, closed, 0, n_vert)
        for v in range(n_vert):
            if depth_v[v] > pos[part[v]]:
                pos[part[v]] = depth_v[v]
    out = np.empty(n_parts)
    for i in range(n_parts):
        out[i] = pos[i] if pos[i] > 0.0 else -min(cap, clear[i])
    return out, depth_v


@njit(cache=True)
def label_mesh(verts, faces, pairs, scale, tau, cap, part, n_parts, adj_ptr, adj_idx, adj_eid,
               n_edges, closed, orient, near_ptr, near_b, near_rest):
    """Counted pairs, per-part PD_i (K,) and per-vertex penetration depth (V,) of one mesh, evaluating every
    pair of ``pairs`` (the non-adjacent pairs whose boxes are within ``cap``): the reference path, quadratic
    in the mesh density (see :func:`near_pass` for the pruned one)."""
    clear = np.full(n_parts, np.inf)
    floor = np.zeros(n_parts)
    n_pairs, rec_key, rec_int, n_rec = pair_pass(verts, faces, pairs, scale, tau, cap, part, clear, floor,
                                                 adj_ptr, adj_idx, adj_eid, orient, near_ptr, near_b, near_rest)
    out, depth_v = finish_label(verts, faces, rec_key, rec_int, n_rec, n_edges, floor, clear, part, n_parts, cap,
                                adj_ptr, adj_idx, adj_eid, closed)
    return n_pairs, out, depth_v
