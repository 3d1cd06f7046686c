"""Whole-mesh label passes of the reference path: the verdict, the pass over every candidate pair
(``ExactLabeler(prune=False)``), and the per-part PD_i and vertex depths from the crossing records
(``finish_label``, shared with the pruned path and the Warp labeler)."""

from __future__ import annotations

import numpy as np
from numba import njit

from neuralcol.collision.kernels.broadphase import shared_vertex_count, sorted_cells
from neuralcol.collision.kernels.pair_terms import (
    contact_depth,
    count_pair,
    is_counted,
    lower_clearance,
    near_index,
    pair_counted,
    pair_terms,
    penetration_of,
)
from neuralcol.collision.kernels.penetration import crossing_seeds, penetration
from neuralcol.collision.kernels.predicates import NO_CONTACT, triangles_intersect
from neuralcol.collision.kernels.vec import corners


@njit(cache=True)
def verdict_kernel(verts, faces, lo, hi, cell, scale, tau):
    """Does some counted pair exist? Stops at the first one it confirms: the grid of
    :func:`~neuralcol.collision.kernels.broadphase.sorted_cells` is swept cell by cell and each pair with
    overlapping boxes is tested as it is found (exact), so a colliding mesh costs the grid plus the sweep up to
    its first counted pair, not every candidate pair."""
    cell_keys, cell_start, ids, ilo, dims = sorted_cells(lo, hi, cell)
    for ci in range(cell_keys.shape[0]):
        start = cell_start[ci]
        end = cell_start[ci + 1]
        if end - start < 2:
            continue
        key = cell_keys[ci]
        cz = key % dims[2]
        cy = (key // dims[2]) % dims[1]
        cx = key // (dims[2] * dims[1])
        for i in range(start, end):
            a0 = ids[i]
            for j in range(i + 1, end):
                b0 = ids[j]
                if lo[b0, 0] > hi[a0, 0]:
                    break  # entries of a cell ascend in lower x: this and every later one start beyond a0's box
                if (lo[b0, 1] > hi[a0, 1] or lo[a0, 1] > hi[b0, 1] or lo[b0, 2] > hi[a0, 2]
                        or lo[a0, 2] > hi[b0, 2]):
                    continue
                if (max(ilo[a0, 0], ilo[b0, 0]) != cx or max(ilo[a0, 1], ilo[b0, 1]) != cy
                        or max(ilo[a0, 2], ilo[b0, 2]) != cz):
                    continue  # reported by the cell of the lower corner of the boxes' intersection
                if shared_vertex_count(faces, a0, b0) >= 2:
                    continue
                if pair_counted(verts, faces, a0, b0, scale, tau):
                    return True
    return False


@njit(cache=True)
def counted_pass(verts, faces, pairs, scale, tau, part, floor, adj_ptr, adj_idx, adj_eid, orient):
    """The counted pairs among ``pairs`` (the non-adjacent pairs whose boxes overlap) and their crossing records,
    without any clearance term: what a label needs of a colliding mesh (``ExactLabeler(clearance=False)``). Raises
    ``floor`` (per part) in place.

    Returns:
        n_pairs, rec_key, rec_int, n_rec.
    """
    rec_key = np.empty(64)
    rec_int = np.empty((64, 5), dtype=np.int64)
    n_rec = 0
    n_pairs = 0
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        p0, p1, p2 = corners(verts, faces, a)
        q0, q1, q2 = corners(verts, faces, b)
        hit = triangles_intersect(p0, p1, p2, q0, q1, q2)
        if hit == NO_CONTACT:
            continue
        depth = contact_depth(hit, p0, p1, p2, q0, q1, q2, scale)
        if not is_counted(hit, depth, tau):
            continue
        n_pairs += 1
        rec_key, rec_int, n_rec = count_pair(verts, faces, a, b, penetration_of(depth, tau), part, floor, adj_ptr,
                                             adj_idx, adj_eid, orient, rec_key, rec_int, n_rec)
    return n_pairs, rec_key, rec_int, n_rec


@njit(cache=True)
def pair_pass(verts, faces, pairs, scale, tau, gerr, cap, part, clear, floor, adj_ptr, adj_idx, adj_eid, orient,
              near_ptr, near_b, near_rest):
    """Verdict, penetration and clearance of every candidate pair: lowers ``clear`` and raises ``floor`` (per
    part) in place.

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
        evaluated, counted, pen, c = pair_terms(verts, faces, a, b, shared, idx, near_rest, scale, tau, gerr, cap,
                                                clear, part)
        if not evaluated:
            continue
        lower_clearance(clear, part, faces, a, b, c)
        if not counted:
            continue  # apart, touching, or touching within tau: no crossing edges
        n_pairs += 1
        rec_key, rec_int, n_rec = count_pair(verts, faces, a, b, pen, part, floor, adj_ptr, adj_idx, adj_eid, orient,
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
def label_mesh(verts, faces, pairs, scale, tau, gerr, cap, part, n_parts, adj_ptr, adj_idx, adj_eid,
               n_edges, closed, orient, near_ptr, near_b, near_rest):
    """Counted pairs, per-part PD_i (K,) and per-vertex penetration depth (V,) of one mesh, evaluating every
    pair of ``pairs`` (the non-adjacent pairs whose boxes are within ``cap``): the reference path, quadratic
    in the mesh density (see :func:`near_pass` for the pruned one)."""
    clear = np.full(n_parts, np.inf)
    floor = np.zeros(n_parts)
    n_pairs, rec_key, rec_int, n_rec = pair_pass(verts, faces, pairs, scale, tau, gerr, cap, part, clear, floor,
                                                 adj_ptr, adj_idx, adj_eid, orient, near_ptr, near_b, near_rest)
    out, depth_v = finish_label(verts, faces, rec_key, rec_int, n_rec, n_edges, floor, clear, part, n_parts, cap,
                                adj_ptr, adj_idx, adj_eid, closed)
    return n_pairs, out, depth_v
