"""Whole-mesh label passes of the reference path: the verdict, the pass over every candidate pair
(``ExactLabeler(prune=False)``), and the per-part PD_i and vertex depths from the crossing records
(``finish_label``, shared with the pruned path and the Warp labeler)."""

from __future__ import annotations

import numpy as np
from numba import njit

from neuralcol.collision.kernels.broadphase import grid_pairs, shared_vertex_count
from neuralcol.collision.kernels.depth import opposite_edges_cross, plane_separated, triangle_pair_depth
from neuralcol.collision.kernels.distance import point_triangle_distance
from neuralcol.collision.kernels.pair_terms import add_crossings, lower_clearance, near_index, pair_terms
from neuralcol.collision.kernels.vec import corners, point


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
def _seed_depth(verts, faces, seeds, k):
    """Depth of a crossing edge: distance of its nearer endpoint to the pierced triangle."""
    t = seeds[k, 2]
    ta, tb, tc = corners(verts, faces, t)
    return min(point_triangle_distance(point(verts, seeds[k, 0]), ta, tb, tc),
               point_triangle_distance(point(verts, seeds[k, 1]), ta, tb, tc))


@njit(cache=True)
def _penetration_depths(verts, faces, seeds, adj_ptr, adj_idx, adj_eid, blocked, closed):
    """Depth of every penetrating vertex (0 elsewhere), (V,). See the labeler's module docstring."""
    n_vert = verts.shape[0]
    depth = np.zeros(n_vert)
    n_seeds = seeds.shape[0]
    region = np.full(n_vert, -1, dtype=np.int64)
    n_regions = 0
    if closed:  # flood fill the penetrating regions, bounded by crossing edges
        queue = np.empty(n_vert, dtype=np.int64)
        for k in range(n_seeds):
            s = seeds[k, 0]
            if region[s] >= 0:
                continue
            head = 0
            tail = 0
            queue[tail] = s
            tail += 1
            region[s] = n_regions
            while head < tail:
                v = queue[head]
                head += 1
                for j in range(adj_ptr[v], adj_ptr[v + 1]):
                    w = adj_idx[j]
                    if region[w] >= 0 or blocked[adj_eid[j]]:
                        continue
                    region[w] = n_regions
                    queue[tail] = w
                    tail += 1
            n_regions += 1
    # a region that holds both ends of one of its crossing edges is not enclosed by the intersection
    # curves (a local fold): it keeps its seeds only
    valid = np.ones(n_regions, dtype=np.bool_)
    for k in range(n_seeds):
        r = region[seeds[k, 0]]
        if r >= 0 and region[seeds[k, 1]] == r:
            valid[r] = False
    for k in range(n_seeds):
        r = region[seeds[k, 0]]
        if r < 0 or not valid[r]:
            v = seeds[k, 0]
            depth[v] = max(depth[v], _seed_depth(verts, faces, seeds, k))
    if n_regions == 0:
        return depth
    # opposing triangles of each valid region: the triangles it pierces + triangles of all other regions
    pierced = np.zeros((n_regions, faces.shape[0]), dtype=np.bool_)
    for k in range(n_seeds):
        pierced[region[seeds[k, 0]], seeds[k, 2]] = True
    opp = np.empty(faces.shape[0], dtype=np.int64)
    for r in range(n_regions):
        if not valid[r]:
            continue
        n_opp = 0
        for f in range(faces.shape[0]):
            own = False
            other = False
            for i in range(3):
                rf = region[faces[f, i]]
                if rf == r:
                    own = True
                elif rf >= 0:
                    other = True
            if not own and (pierced[r, f] or other):
                opp[n_opp] = f
                n_opp += 1
        if n_opp == 0:
            continue
        # centroid and radius of each opposing triangle: |p - c| - r is a lower bound of the distance
        cen = np.empty((n_opp, 3))
        rad = np.empty(n_opp)
        for k in range(n_opp):
            f = opp[k]
            for d in range(3):
                cen[k, d] = (verts[faces[f, 0], d] + verts[faces[f, 1], d] + verts[faces[f, 2], d]) / 3.0
            r2 = 0.0
            for i in range(3):
                e = 0.0
                for d in range(3):
                    e += (verts[faces[f, i], d] - cen[k, d]) ** 2
                r2 = max(r2, e)
            rad[k] = np.sqrt(r2)
        lb = np.empty(n_opp)
        for v in range(n_vert):
            if region[v] != r:
                continue
            p = point(verts, v)
            k_best = 0
            for k in range(n_opp):
                e = 0.0
                for d in range(3):
                    e += (p[d] - cen[k, d]) ** 2
                lb[k] = np.sqrt(e) - rad[k]
                if lb[k] < lb[k_best]:
                    k_best = k
            f = opp[k_best]
            t0, t1, t2 = corners(verts, faces, f)
            best = point_triangle_distance(p, t0, t1, t2)
            for k in range(n_opp):
                if lb[k] >= best:
                    continue
                f = opp[k]
                t0, t1, t2 = corners(verts, faces, f)
                d = point_triangle_distance(p, t0, t1, t2)
                if d < best:
                    best = d
            depth[v] = best
    return depth


@njit(cache=True)
def finish_label(verts, faces, rec_key, rec_int, n_rec, n_edges, floor, clear, part, n_parts, cap,
                 adj_ptr, adj_idx, adj_eid, closed):
    """Per-part PD_i (K,) and per-vertex penetration depth (V,) from the crossing records and the per-part
    clearance / pair-depth floor of :func:`pair_pass`."""
    n_vert = verts.shape[0]
    blocked = np.zeros(n_edges, dtype=np.bool_)
    # An edge separates inside from outside only if it crosses the surface an odd number of times (an edge
    # through a corner enters and leaves). Crossings at the same point (through a shared edge or vertex of the
    # other surface) count once if they agree on the side, and not at all if they disagree (a graze).
    order = np.argsort(rec_key[:n_rec])
    seeds = np.empty((max(n_rec, 1), 3), dtype=np.int64)
    n_seeds = 0
    keep = np.zeros(n_rec, dtype=np.bool_)
    k = 0
    while k < n_rec:
        e = rec_int[order[k], 0]
        end = k
        while end < n_rec and rec_int[order[end], 0] == e:
            end += 1
        n_cross = 0
        c0 = k
        while c0 < end:  # clusters of equal crossing parameter
            c1 = c0 + 1
            agree = True
            while c1 < end and rec_key[order[c1]] - rec_key[order[c0]] <= 1e-12:
                if rec_int[order[c1], 1] != rec_int[order[c0], 1]:
                    agree = False
                c1 += 1
            if agree:
                n_cross += 1
                for j in range(c0, c1):
                    keep[order[j]] = True
            c0 = c1
        if n_cross % 2 == 1:
            blocked[e] = True
            for j in range(k, end):
                r = order[j]
                if keep[r] and rec_int[r, 4] == 1:
                    seeds[n_seeds, 0] = rec_int[r, 1]
                    seeds[n_seeds, 1] = rec_int[r, 2]
                    seeds[n_seeds, 2] = rec_int[r, 3]
                    n_seeds += 1
        k = end
    pos = floor.copy()
    depth_v = np.zeros(n_vert)
    if n_seeds > 0:
        depth_v = _penetration_depths(verts, faces, seeds[:n_seeds], adj_ptr, adj_idx, adj_eid, blocked, closed)
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
