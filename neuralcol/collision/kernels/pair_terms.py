"""The terms of one non-adjacent triangle pair: the rest mesh's near table, the pair's depth and clearance term,
their effect on a part's clearance and floor, and the crossing records of a counted pair."""

from __future__ import annotations

import numpy as np
from numba import njit

from neuralcol.collision.kernels.broadphase import shared_vertex_count
from neuralcol.collision.kernels.depth import (
    coplanar_depth,
    plane_separated,
    segment_crosses_triangle,
    signed_volume,
    triangle_pair_depth,
)
from neuralcol.collision.kernels.distance import box_gap, corner_angle, pair_distance, triangle_distance
from neuralcol.collision.kernels.predicates import COPLANAR_OVERLAP, NO_CONTACT, triangles_intersect
from neuralcol.collision.kernels.vec import BOUND_GROW, BOUND_SHRINK, MIN_PENETRATION, corners, point


@njit(cache=True)
def near_table(rest, faces, pairs, cap, scale):
    """Pairs that are within ``cap`` in the rest mesh, with their rest measure.

    Args:
        rest: (V, 3) rest vertices.
        faces: (F, 3).
        pairs: (P, 2) non-adjacent candidate pairs of the rest mesh (boxes grown by cap / 2).
        cap: clearance cap.
        scale: mean edge length.

    Returns:
        keys (N,) int64 sorted (``a * F + b``), rest (N,) float64: the corner angle for pairs sharing a
        vertex, the SAT separation for the others (<= 0 when the pair touches at rest).
    """
    n_faces = faces.shape[0]
    keys = np.empty(pairs.shape[0], dtype=np.int64)
    vals = np.empty(pairs.shape[0])
    m = 0
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        shared = shared_vertex_count(faces, a, b)
        if shared == 1:
            val = corner_angle(rest, faces, a, b)
        else:
            if pair_distance(rest, faces, a, b) >= cap:
                continue
            p0, p1, p2 = corners(rest, faces, a)
            q0, q1, q2 = corners(rest, faces, b)
            val = -triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale)
        keys[m] = a * n_faces + b
        vals[m] = val
        m += 1
    order = np.argsort(keys[:m])
    return keys[:m][order], vals[:m][order]


@njit(cache=True, inline="always")
def near_index(near_ptr, near_b, a, b):
    """Row of pair (a, b), a < b, in the near table (CSR by a, partners b sorted), or -1 if it is not near."""
    lo = near_ptr[a]
    end = near_ptr[a + 1]
    hi = end
    while lo < hi:
        mid = (lo + hi) >> 1
        if near_b[mid] < b:
            lo = mid + 1
        else:
            hi = mid
    if lo < end and near_b[lo] == b:
        return lo
    return -1


@njit(cache=True, inline="always")
def part_min(clear, part, faces, a, b, cap):
    """Largest current clearance among the parts of the vertices of triangles a and b, capped."""
    m = 0.0
    for t in (a, b):
        for i in range(3):
            m = max(m, clear[part[faces[t, i]]])
    return min(m, cap)


@njit(cache=True)
def contact_depth(hit, p0, p1, p2, q0, q1, q2, scale):
    """Depth of two triangles whose interiors intersect (``hit`` from
    :func:`~neuralcol.collision.kernels.predicates.triangles_intersect`): the SAT depth of a crossing, the in-plane
    depth of a coplanar overlap (whose SAT depth is 0)."""
    if hit == COPLANAR_OVERLAP:
        return coplanar_depth(p0, p1, p2, q0, q1, q2, scale)
    return triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale)


@njit(cache=True, inline="always")
def is_counted(hit, depth, tau):
    """A pair counts when its interiors intersect (exact) and, with a touching tolerance tau > 0, deeper than tau."""
    return hit != NO_CONTACT and (tau <= 0.0 or depth > tau)


@njit(cache=True, inline="always")
def penetration_of(depth, tau):
    """A counted pair's penetration ``depth - tau``, at least :data:`MIN_PENETRATION` (so PD > 0 iff counted)."""
    return max(depth - tau, MIN_PENETRATION)


@njit(cache=True)
def pair_counted(verts, faces, a, b, scale, tau):
    """Is the non-adjacent pair (a, b) counted (module docstring of :mod:`neuralcol.collision.labeler`)? Exact."""
    p0, p1, p2 = corners(verts, faces, a)
    q0, q1, q2 = corners(verts, faces, b)
    hit = triangles_intersect(p0, p1, p2, q0, q1, q2)
    if hit == NO_CONTACT:
        return False
    return tau <= 0.0 or contact_depth(hit, p0, p1, p2, q0, q1, q2, scale) > tau


@njit(cache=True)
def counted_mask(verts, faces, pairs, scale, tau):
    """(P,) bool: which of the non-adjacent pairs (P, 2) are counted (:func:`pair_counted`)."""
    out = np.empty(pairs.shape[0], dtype=np.bool_)
    for k in range(pairs.shape[0]):
        out[k] = pair_counted(verts, faces, pairs[k, 0], pairs[k, 1], scale, tau)
    return out


@njit(cache=True)
def pair_terms(verts, faces, a, b, shared, idx, near_rest, scale, tau, gerr, cap, clear, part):
    """Verdict, penetration and clearance term of one non-adjacent candidate pair: (evaluated, counted, pen, c).

    ``idx`` is the pair's near-table row (-1: far). ``evaluated`` is False for a far pair that provably cannot
    lower any clearance of its parts below the current one (then the rest is not computed). ``counted``: the
    exact verdict (:func:`is_counted`); ``pen`` > 0 its penetration when counted (:func:`penetration_of`), else 0.
    ``gerr``: the round-off bound of a computed gap (``GAP_ROUNDOFF`` x the largest coordinate); a pair whose SAT
    depth is below ``-gerr`` is apart without the exact test.
    """
    p0, p1, p2 = corners(verts, faces, a)
    q0, q1, q2 = corners(verts, faces, b)
    near = idx >= 0
    hit = NO_CONTACT
    if shared == 1:
        hit = triangles_intersect(p0, p1, p2, q0, q1, q2)
        depth = contact_depth(hit, p0, p1, p2, q0, q1, q2, scale) if hit != NO_CONTACT else -1.0
    elif near:
        depth = triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale)
        if depth >= -gerr:
            hit = triangles_intersect(p0, p1, p2, q0, q1, q2)
            if hit == COPLANAR_OVERLAP:
                depth = coplanar_depth(p0, p1, p2, q0, q1, q2, scale)
    else:
        lb = box_gap(p0, p1, p2, q0, q1, q2)
        if lb > 0.0 and lb * BOUND_SHRINK >= part_min(clear, part, faces, a, b, cap):
            return False, False, 0.0, 0.0  # apart by more than any clearance this pair could still lower
        if plane_separated(p0, p1, p2, q0, q1, q2, cap * BOUND_GROW):
            return False, False, 0.0, 0.0  # apart by more than cap: no overlap, clearance term >= cap
        hit = triangles_intersect(p0, p1, p2, q0, q1, q2)
        depth = contact_depth(hit, p0, p1, p2, q0, q1, q2, scale) if hit != NO_CONTACT else -1.0
    counted = is_counted(hit, depth, tau)
    pen = penetration_of(depth, tau) if counted else 0.0
    if hit != NO_CONTACT:
        c = 0.0  # interiors intersect (touching within tau when not counted)
    elif near:
        r = near_rest[idx]
        if r <= 0.0:
            c = cap  # the pair touches in the rest mesh: no reference to measure against
        elif shared == 1:
            c = cap * corner_angle(verts, faces, a, b) / r
        else:
            c = cap * max(-depth, 0.0) / r
    else:
        c = triangle_distance(p0, p1, p2, q0, q1, q2)
    return True, counted, pen, c


@njit(cache=True, inline="always")
def lower_clearance(clear, part, faces, a, b, c):
    for t in (a, b):
        for i in range(3):
            pi = part[faces[t, i]]
            if c < clear[pi]:
                clear[pi] = c


@njit(cache=True)
def _edge_id(adj_ptr, adj_idx, adj_eid, u, w):
    for k in range(adj_ptr[u], adj_ptr[u + 1]):
        if adj_idx[k] == w:
            return adj_eid[k]
    return -1


@njit(cache=True)
def add_crossings(verts, faces, a, b, adj_ptr, adj_idx, adj_eid, orient, rec_key, rec_int, n_rec):
    """Append the crossing records of a counted pair (edges of a through b and of b through a).

    A record is key = edge id + lambda / 2 and ints = (edge, behind vertex, other end, pierced triangle,
    counted pair). Returns the (possibly grown) arrays and the new count.
    """
    for side in range(2):
        s = a if side == 0 else b
        t = b if side == 0 else a
        ta, tb, tc = corners(verts, faces, t)
        for i in range(3):
            u = faces[s, i]
            w = faces[s, (i + 1) % 3]
            if u == faces[t, 0] or u == faces[t, 1] or u == faces[t, 2]:
                continue
            if w == faces[t, 0] or w == faces[t, 1] or w == faces[t, 2]:
                continue
            pu = point(verts, u)
            pw = point(verts, w)
            sd = segment_crosses_triangle(pu, pw, ta, tb, tc)
            if sd == 0.0:
                continue
            eid = _edge_id(adj_ptr, adj_idx, adj_eid, u, w)
            if eid < 0:
                continue
            if n_rec == rec_key.shape[0]:
                g_key = np.empty(2 * n_rec)
                g_int = np.empty((2 * n_rec, 5), dtype=np.int64)
                g_key[:n_rec] = rec_key[:n_rec]
                g_int[:n_rec] = rec_int[:n_rec]
                rec_key = g_key
                rec_int = g_int
            lo_v = min(u, w)  # crossing parameter measured from the lower vertex id, so both
            hi_v = max(u, w)  # triangles of the edge give the same value
            dl = signed_volume(ta, tb, tc, point(verts, lo_v))
            dh = signed_volume(ta, tb, tc, point(verts, hi_v))
            lam = dl / (dl - dh)
            behind = u if sd * orient < 0.0 else w
            rec_key[n_rec] = eid + 0.5 * min(max(lam, 0.0), 1.0)
            rec_int[n_rec, 0] = eid
            rec_int[n_rec, 1] = behind
            rec_int[n_rec, 2] = w if behind == u else u
            rec_int[n_rec, 3] = t
            rec_int[n_rec, 4] = 1
            n_rec += 1
    return rec_key, rec_int, n_rec


@njit(cache=True, inline="always")
def count_pair(verts, faces, a, b, pen, part, floor, adj_ptr, adj_idx, adj_eid, orient, rec_key, rec_int, n_rec):
    """A counted pair of penetration ``pen`` > 0: raise the floor of its parts and append its crossing records."""
    for t in (a, b):
        for i in range(3):
            pi = part[faces[t, i]]
            floor[pi] = max(floor[pi], pen)
    return add_crossings(verts, faces, a, b, adj_ptr, adj_idx, adj_eid, orient, rec_key, rec_int, n_rec)
