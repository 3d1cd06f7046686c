"""Compiled (numba) geometric kernels of the exact labeler: broadphase, triangle tests and distances.

Every function here is pure: arrays in, arrays or scalars out. Triangles are given as vertex arrays
``verts (V, 3) float64`` plus ``faces (F, 3) int64``. See :mod:`neuralcol.collision.labeler` for how they
combine into the verdict and the penetration depth.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_EPS_AXIS = 1e-24  # squared length below which a SAT axis is degenerate (relative to scale^4)


# ----------------------------------------------------------------------------------------- vectors
# A computed lower bound of a clearance term (a box gap, a SAT-axis gap, a cone angle) may exceed the computed term
# by a few ulps (different operations); it rules a term out only with this margin, so a skipped term is always
# >= the clearance it was compared with, and the minimum does not depend on the order the pairs are visited in.
BOUND_SHRINK = 1.0 - 1e-9
BOUND_GROW = 1.0 + 1e-9


@njit(cache=True, inline="always")
def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, inline="always")
def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, inline="always")
def _scale(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


@njit(cache=True, inline="always")
def _add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@njit(cache=True, inline="always")
def _pt(verts, i):
    return (verts[i, 0], verts[i, 1], verts[i, 2])


@njit(cache=True, inline="always")
def _tri(verts, faces, f):
    """The three corners of triangle f, each an (x, y, z) tuple."""
    return _pt(verts, faces[f, 0]), _pt(verts, faces[f, 1]), _pt(verts, faces[f, 2])


# ----------------------------------------------------------------------------------------- broadphase
@njit(cache=True)
def triangle_aabbs(verts, faces, inflate):
    """Axis-aligned boxes of all triangles, each grown by ``inflate`` on every side -> (F, 3), (F, 3)."""
    n = faces.shape[0]
    lo = np.empty((n, 3))
    hi = np.empty((n, 3))
    for f in range(n):
        for d in range(3):
            a = verts[faces[f, 0], d]
            b = verts[faces[f, 1], d]
            c = verts[faces[f, 2], d]
            lo[f, d] = min(a, b, c) - inflate
            hi[f, d] = max(a, b, c) + inflate
    return lo, hi


@njit(cache=True)
def grid_pairs(lo, hi, cell):
    """All pairs (a < b) of boxes that overlap, found with a uniform grid of cell size ``cell``.

    Each box is entered in every cell it touches; a pair is reported once, by the cell that holds the
    lower corner of the two boxes' intersection. Cost is linear in the number of boxes for boxes of
    bounded size.

    Returns:
        (P, 2) int64 pairs.
    """
    return grid_pairs_active(lo, hi, cell, np.ones(lo.shape[0], dtype=np.bool_), lo, -1.0)


@njit(cache=True)
def _grid_cells(lo, hi, cell):
    """Boxes ``lo``/``hi`` (F, 3) binned into a uniform grid of ``cell``: one entry per (box, cell) it touches.

    Returns:
        keys (E,) cell keys in ascending order, ids (E,) the box of each entry, ilo (F, 3) each box's lower
        cell, dims (3,) cells per axis (key = (x * dims[1] + y) * dims[2] + z).
    """
    n = lo.shape[0]
    origin = np.empty(3)
    for d in range(3):
        origin[d] = lo[:, d].min()
    inv = 1.0 / cell
    ilo = np.empty((n, 3), dtype=np.int64)
    ihi = np.empty((n, 3), dtype=np.int64)
    total = 0
    for f in range(n):
        cnt = 1
        for d in range(3):
            ilo[f, d] = int((lo[f, d] - origin[d]) * inv)
            ihi[f, d] = int((hi[f, d] - origin[d]) * inv)
            cnt *= ihi[f, d] - ilo[f, d] + 1
        total += cnt
    dims = np.empty(3, dtype=np.int64)
    for d in range(3):
        dims[d] = ihi[:, d].max() + 1
    keys = np.empty(total, dtype=np.int64)
    ids = np.empty(total, dtype=np.int64)
    k = 0
    for f in range(n):
        for x in range(ilo[f, 0], ihi[f, 0] + 1):
            for y in range(ilo[f, 1], ihi[f, 1] + 1):
                for z in range(ilo[f, 2], ihi[f, 2] + 1):
                    keys[k] = (x * dims[1] + y) * dims[2] + z
                    ids[k] = f
                    k += 1
    order = np.argsort(keys, kind="quicksort")
    keys = keys[order]
    ids = ids[order]
    return keys, ids, ilo, dims


@njit(cache=True)
def grid_pairs_active(lo, hi, cell, active, pts, skip2):
    """Like :func:`grid_pairs`, only the pairs with at least one box marked in ``active`` (F,) bool and whose
    points ``pts`` (F, 3) are at least ``sqrt(skip2)`` apart (``skip2 < 0``: no such filter)."""
    n = lo.shape[0]
    keys, ids, ilo, dims = _grid_cells(lo, hi, cell)
    total = keys.shape[0]
    cap = max(16, 8 * n)
    out = np.empty((cap, 2), dtype=np.int64)
    m = 0
    start = 0
    while start < total:
        end = start + 1
        while end < total and keys[end] == keys[start]:
            end += 1
        key = keys[start]
        cz = key % dims[2]
        cy = (key // dims[2]) % dims[1]
        cx = key // (dims[2] * dims[1])
        for i in range(start, end):
            a = ids[i]
            for j in range(i + 1, end):
                b = ids[j]
                if not (active[a] or active[b]):
                    continue
                if skip2 >= 0.0:
                    dd = 0.0
                    for d in range(3):
                        dd += (pts[a, d] - pts[b, d]) ** 2
                    if dd < skip2:
                        continue
                ok = True
                for d in range(3):
                    if lo[a, d] > hi[b, d] or lo[b, d] > hi[a, d]:
                        ok = False
                        break
                if not ok:
                    continue
                # report in the cell of the lower corner of the intersection box only
                if (max(ilo[a, 0], ilo[b, 0]) != cx or max(ilo[a, 1], ilo[b, 1]) != cy
                        or max(ilo[a, 2], ilo[b, 2]) != cz):
                    continue
                if m == cap:
                    cap *= 2
                    grown = np.empty((cap, 2), dtype=np.int64)
                    grown[:m] = out[:m]
                    out = grown
                out[m, 0] = min(a, b)
                out[m, 1] = max(a, b)
                m += 1
        start = end
    return out[:m]


@njit(cache=True)
def shared_vertex_count(faces, a, b):
    """Number of vertices triangles a and b share (0, 1, 2 or 3)."""
    s = 0
    for i in range(3):
        for j in range(3):
            if faces[a, i] == faces[b, j]:
                s += 1
    return s


# ----------------------------------------------------------------------------------------- SAT depth
@njit(cache=True)
def _sat_axis(axis, p0, p1, p2, q0, q1, q2, best):
    ll = _dot(axis, axis)
    if ll <= 0.0:
        return best
    inv = 1.0 / np.sqrt(ll)
    a0 = _dot(axis, p0) * inv
    a1 = _dot(axis, p1) * inv
    a2 = _dot(axis, p2) * inv
    b0 = _dot(axis, q0) * inv
    b1 = _dot(axis, q1) * inv
    b2 = _dot(axis, q2) * inv
    # translation along the axis that makes the two intervals disjoint (shift either way)
    ov = min(max(a0, a1, a2) - min(b0, b1, b2), max(b0, b1, b2) - min(a0, a1, a2))
    return min(best, ov)


@njit(cache=True)
def triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale):
    """Translational penetration depth of two triangles by the separating-axis theorem.

    The candidate axes are the two normals, the 9 edge-edge cross products and the 6 in-plane edge normals
    (normal x edge), i.e. every face normal of the Minkowski difference of the two flat triangles; the
    depth is the smallest overlap of the projections over these axes. It is > 0 iff the triangles' relative
    interiors overlap in 3D, is 0 when they only touch (e.g. at a shared vertex), is continuous in the
    vertex positions, and when negative it is minus the largest separation along a candidate axis. Along
    one axis the depth is the shift that makes the projections disjoint, ``min(maxA - minB, maxB - minA)``
    (not the overlap length, which is 0 along a flat triangle's own normal).
    ``scale`` (a typical edge length) sets what counts as a degenerate axis.
    """
    tiny = _EPS_AXIS * scale**4
    e0 = _sub(p1, p0)
    e1 = _sub(p2, p1)
    e2 = _sub(p0, p2)
    f0 = _sub(q1, q0)
    f1 = _sub(q2, q1)
    f2 = _sub(q0, q2)
    n = _cross(e0, _sub(p2, p0))
    m = _cross(f0, _sub(q2, q0))
    best = np.inf
    best = _sat_axis(n, p0, p1, p2, q0, q1, q2, best)
    best = _sat_axis(m, p0, p1, p2, q0, q1, q2, best)
    for ea in (e0, e1, e2):
        for fb in (f0, f1, f2):
            ax = _cross(ea, fb)
            if _dot(ax, ax) > tiny:
                best = _sat_axis(ax, p0, p1, p2, q0, q1, q2, best)
    for ea in (e0, e1, e2):
        ax = _cross(n, ea)
        if _dot(ax, ax) > tiny:
            best = _sat_axis(ax, p0, p1, p2, q0, q1, q2, best)
    for fb in (f0, f1, f2):
        ax = _cross(m, fb)
        if _dot(ax, ax) > tiny:
            best = _sat_axis(ax, p0, p1, p2, q0, q1, q2, best)
    return best


@njit(cache=True)
def plane_separated(p0, p1, p2, q0, q1, q2, margin):
    """True if one triangle lies strictly beyond ``margin`` on one side of the other's plane (then their
    SAT depth is < -margin, i.e. they are apart)."""
    for side in range(2):
        a0, a1, a2 = (p0, p1, p2) if side == 0 else (q0, q1, q2)
        b0, b1, b2 = (q0, q1, q2) if side == 0 else (p0, p1, p2)
        n = _cross(_sub(a1, a0), _sub(a2, a0))
        ln = np.sqrt(_dot(n, n))
        if ln <= 0.0:
            continue
        off = _dot(n, a0)
        s0 = _dot(n, b0) - off
        s1 = _dot(n, b1) - off
        s2 = _dot(n, b2) - off
        m = margin * ln
        if (s0 > m and s1 > m and s2 > m) or (s0 < -m and s1 < -m and s2 < -m):
            return True
    return False


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
            val = _corner_angle(rest, faces, a, b)
        else:
            if _tri_dist(rest, faces, a, b) >= cap:
                continue
            p0, p1, p2 = _tri(rest, faces, a)
            q0, q1, q2 = _tri(rest, faces, b)
            val = -triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale)
        keys[m] = a * n_faces + b
        vals[m] = val
        m += 1
    order = np.argsort(keys[:m])
    return keys[:m][order], vals[:m][order]


@njit(cache=True)
def pair_depths(verts, faces, pairs, scale):
    """SAT depth of each candidate pair, (P,) float64."""
    out = np.empty(pairs.shape[0])
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        p0, p1, p2 = _tri(verts, faces, a)
        q0, q1, q2 = _tri(verts, faces, b)
        out[k] = triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale)
    return out


@njit(cache=True)
def any_intersection(verts, faces, pairs, scale, tau):
    """True as soon as one candidate pair has depth > tau (early exit; the verdict)."""
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        p0, p1, p2 = _tri(verts, faces, a)
        q0, q1, q2 = _tri(verts, faces, b)
        d = triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale)
        if d > tau:
            return True
    return False


# ----------------------------------------------------------------------------------------- crossings
@njit(cache=True, inline="always")
def _orient(a, b, c, d):
    """Signed volume (times 6) of tetrahedron (a, b, c, d): > 0 if d is on the side of (b-a)x(c-a)."""
    return _dot(_cross(_sub(b, a), _sub(c, a)), _sub(d, a))


@njit(cache=True)
def segment_crosses_triangle(p, q, a, b, c):
    """Signed volume of p w.r.t. triangle (a, b, c) if segment pq properly crosses its interior, else 0.

    The segment crosses when p and q are strictly on opposite sides of the plane and the crossing point lies
    inside the triangle (boundary included). The sign of the returned value tells on which side p is.
    """
    dp = _orient(a, b, c, p)
    dq = _orient(a, b, c, q)
    if dp * dq >= 0.0:
        return 0.0
    s0 = _orient(p, q, a, b)
    s1 = _orient(p, q, b, c)
    s2 = _orient(p, q, c, a)
    if (s0 >= 0.0 and s1 >= 0.0 and s2 >= 0.0) or (s0 <= 0.0 and s1 <= 0.0 and s2 <= 0.0):
        return dp
    return 0.0


# ----------------------------------------------------------------------------------------- distances
@njit(cache=True)
def point_triangle_distance(p, a, b, c):
    """Euclidean distance from point p to triangle (a, b, c) (Ericson, Real-Time Collision Detection 5.1.5)."""
    ab = _sub(b, a)
    ac = _sub(c, a)
    ap = _sub(p, a)
    d1 = _dot(ab, ap)
    d2 = _dot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        x = a
    else:
        bp = _sub(p, b)
        d3 = _dot(ab, bp)
        d4 = _dot(ac, bp)
        if d3 >= 0.0 and d4 <= d3:
            x = b
        else:
            vc = d1 * d4 - d3 * d2
            if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                x = _add(a, _scale(ab, d1 / (d1 - d3)))
            else:
                cp = _sub(p, c)
                d5 = _dot(ab, cp)
                d6 = _dot(ac, cp)
                if d6 >= 0.0 and d5 <= d6:
                    x = c
                else:
                    vb = d5 * d2 - d1 * d6
                    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                        x = _add(a, _scale(ac, d2 / (d2 - d6)))
                    else:
                        va = d3 * d6 - d5 * d4
                        if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
                            x = _add(b, _scale(_sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6))))
                        else:
                            denom = 1.0 / (va + vb + vc)
                            x = _add(a, _add(_scale(ab, vb * denom), _scale(ac, vc * denom)))
    d = _sub(p, x)
    return np.sqrt(_dot(d, d))


@njit(cache=True)
def segment_segment_distance(p1, q1, p2, q2):
    """Distance between segments p1q1 and p2q2 (Ericson 5.1.9)."""
    d1 = _sub(q1, p1)
    d2 = _sub(q2, p2)
    r = _sub(p1, p2)
    a = _dot(d1, d1)
    e = _dot(d2, d2)
    f = _dot(d2, r)
    if a <= 1e-300 and e <= 1e-300:
        return np.sqrt(_dot(r, r))
    if a <= 1e-300:
        s = 0.0
        t = min(max(f / e, 0.0), 1.0)
    else:
        c = _dot(d1, r)
        if e <= 1e-300:
            t = 0.0
            s = min(max(-c / a, 0.0), 1.0)
        else:
            b = _dot(d1, d2)
            denom = a * e - b * b
            s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > 0.0 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t = 1.0
                s = min(max((b - c) / a, 0.0), 1.0)
    diff = _sub(_add(p1, _scale(d1, s)), _add(p2, _scale(d2, t)))
    return np.sqrt(_dot(diff, diff))


@njit(cache=True)
def triangle_distance(p0, p1, p2, q0, q1, q2):
    """Distance between two triangles that do not intersect: min of 6 point-triangle and 9 edge-edge distances.

    (For intersecting triangles the caller uses 0; this function does not test intersection.)
    """
    d = point_triangle_distance(p0, q0, q1, q2)
    d = min(d, point_triangle_distance(p1, q0, q1, q2))
    d = min(d, point_triangle_distance(p2, q0, q1, q2))
    d = min(d, point_triangle_distance(q0, p0, p1, p2))
    d = min(d, point_triangle_distance(q1, p0, p1, p2))
    d = min(d, point_triangle_distance(q2, p0, p1, p2))
    ps = (p0, p1, p2)
    qs = (q0, q1, q2)
    for i in range(3):
        for j in range(3):
            d = min(d, segment_segment_distance(ps[i], ps[(i + 1) % 3], qs[j], qs[(j + 1) % 3]))
    return d


@njit(cache=True, inline="always")
def _unit(a):
    n = np.sqrt(_dot(a, a))
    if n <= 0.0:
        return (0.0, 0.0, 0.0)
    return _scale(a, 1.0 / n)


@njit(cache=True)
def _point_arc_chord(x, v1, v2):
    """Chordal distance from unit vector x to the great-circle arc from unit v1 to unit v2 (shorter arc):
    the Euclidean distance to the nearest unit vector on the arc."""
    n = _unit(_cross(v1, v2))
    xp = _sub(x, _scale(n, _dot(x, n)))
    lxp = np.sqrt(_dot(xp, xp))
    if lxp > 0.0 and _dot(_cross(v1, xp), n) >= 0.0 and _dot(_cross(xp, v2), n) >= 0.0:
        return np.sqrt(max(0.0, 2.0 - 2.0 * lxp))  # |x - xp/|xp||, since x . xp = |xp|^2
    d1 = _sub(x, v1)
    d2 = _sub(x, v2)
    return np.sqrt(min(_dot(d1, d1), _dot(d2, d2)))


@njit(cache=True)
def wedge_gap(p, a, b, c, d):
    """Gap between the corners at shared vertex p of triangles (p, a, b) and (p, c, d).

    The directions of a triangle at p form a great-circle arc on the unit sphere; the gap is 0 when the two
    arcs cross (the triangles then overlap near p, beyond p itself) and otherwise the chordal distance
    between the arcs (2 sin(angle / 2) of the smallest angle between them). Continuous in the vertices.
    """
    u1 = _unit(_sub(a, p))
    u2 = _unit(_sub(b, p))
    v1 = _unit(_sub(c, p))
    v2 = _unit(_sub(d, p))
    nu = _cross(u1, u2)
    nv = _cross(v1, v2)
    s1 = _dot(u1, nv)
    s2 = _dot(u2, nv)
    t1 = _dot(v1, nu)
    t2 = _dot(v2, nu)
    x = _cross(nu, nv)
    coplanar = _dot(x, x) <= 1e-20 * _dot(nu, nu) * _dot(nv, nv)  # then the arc distances below decide
    if not coplanar and s1 * s2 <= 0.0 and t1 * t2 <= 0.0:
        mu = _add(u1, u2)
        mv = _add(v1, v2)
        if (_dot(x, mu) >= 0.0 and _dot(x, mv) >= 0.0) or (_dot(x, mu) <= 0.0 and _dot(x, mv) <= 0.0):
            return 0.0
    g = _point_arc_chord(u1, v1, v2)
    g = min(g, _point_arc_chord(u2, v1, v2))
    g = min(g, _point_arc_chord(v1, u1, u2))
    g = min(g, _point_arc_chord(v2, u1, u2))
    return g


# ----------------------------------------------------------------------------------------- labels
@njit(cache=True)
def drop_adjacent(faces, pairs):
    keep = np.empty(pairs.shape[0], dtype=np.bool_)
    for k in range(pairs.shape[0]):
        keep[k] = shared_vertex_count(faces, pairs[k, 0], pairs[k, 1]) < 2
    return pairs[keep]


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
        p0, p1, p2 = _tri(verts, faces, a)
        q0, q1, q2 = _tri(verts, faces, b)
        if shared == 0 and plane_separated(p0, p1, p2, q0, q1, q2, tau):
            continue
        if triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale) > tau:
            return True
    return False


@njit(cache=True)
def _edge_id(adj_ptr, adj_idx, adj_eid, u, w):
    for k in range(adj_ptr[u], adj_ptr[u + 1]):
        if adj_idx[k] == w:
            return adj_eid[k]
    return -1


@njit(cache=True)
def _tri_dist(verts, faces, a, b):
    p0, p1, p2 = _tri(verts, faces, a)
    q0, q1, q2 = _tri(verts, faces, b)
    return triangle_distance(p0, p1, p2, q0, q1, q2)


@njit(cache=True, inline="always")
def _box_gap(p0, p1, p2, q0, q1, q2):
    """Distance between the axis-aligned boxes of two triangles (a lower bound of their distance)."""
    g2 = 0.0
    for d in range(3):
        gap = max(min(q0[d], q1[d], q2[d]) - max(p0[d], p1[d], p2[d]),
                  min(p0[d], p1[d], p2[d]) - max(q0[d], q1[d], q2[d]), 0.0)
        g2 += gap * gap
    return np.sqrt(g2)


@njit(cache=True, inline="always")
def _part_min(clear, part, faces, a, b, cap):
    """Largest current clearance among the parts of the vertices of triangles a and b, capped."""
    m = 0.0
    for t in (a, b):
        for i in range(3):
            m = max(m, clear[part[faces[t, i]]])
    return min(m, cap)


@njit(cache=True)
def opposite_edges_cross(verts, faces, a, b):
    """For triangles sharing exactly one vertex: does the edge of one opposite the shared vertex cross the
    other? (They overlap beyond the shared vertex only if one of these two edges crosses.)"""
    for i in range(3):
        for j in range(3):
            if faces[a, i] == faces[b, j]:
                pa = _pt(verts, faces[a, (i + 1) % 3])
                pb = _pt(verts, faces[a, (i + 2) % 3])
                qa = _pt(verts, faces[b, (j + 1) % 3])
                qb = _pt(verts, faces[b, (j + 2) % 3])
                p = _pt(verts, faces[a, i])
                if segment_crosses_triangle(pa, pb, p, qa, qb) != 0.0:
                    return True
                return segment_crosses_triangle(qa, qb, p, pa, pb) != 0.0
    return False


@njit(cache=True)
def _corner_angle(verts, faces, a, b):
    """Wedge angle at the single shared vertex of triangles a and b."""
    for i in range(3):
        for j in range(3):
            if faces[a, i] == faces[b, j]:
                p = faces[a, i]
                return wedge_gap(_pt(verts, p), _pt(verts, faces[a, (i + 1) % 3]),
                                   _pt(verts, faces[a, (i + 2) % 3]), _pt(verts, faces[b, (j + 1) % 3]),
                                   _pt(verts, faces[b, (j + 2) % 3]))
    return 0.0


@njit(cache=True, inline="always")
def _near_index(near_ptr, near_b, a, b):
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
def _boxes_overlap(lo, hi, a, b):
    """The test of :func:`grid_pairs` (same comparisons, so the same pairs)."""
    for d in range(3):
        if lo[a, d] > hi[b, d] or lo[b, d] > hi[a, d]:
            return False
    return True


@njit(cache=True)
def _pair_terms(verts, faces, a, b, shared, idx, near_rest, scale, tau, cap, clear, part):
    """Depth and clearance term of one non-adjacent candidate pair: (evaluated, depth, c).

    ``idx`` is the pair's near-table row (-1: far). ``evaluated`` is False for a far pair that provably cannot
    lower any clearance of its parts below the current one (then depth and c are not computed).
    """
    p0, p1, p2 = _tri(verts, faces, a)
    q0, q1, q2 = _tri(verts, faces, b)
    near = idx >= 0
    if shared == 1:
        if opposite_edges_cross(verts, faces, a, b):
            depth = triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale)
        else:
            depth = -1.0  # no overlap beyond the shared vertex
    elif near:
        depth = triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale)
    else:
        lb = _box_gap(p0, p1, p2, q0, q1, q2)
        if lb > 0.0 and lb * BOUND_SHRINK >= _part_min(clear, part, faces, a, b, cap):
            return False, 0.0, 0.0  # apart by more than any clearance this pair could still lower
        if plane_separated(p0, p1, p2, q0, q1, q2, cap * BOUND_GROW):
            return False, 0.0, 0.0  # apart by more than cap: no overlap, clearance term >= cap
        if plane_separated(p0, p1, p2, q0, q1, q2, tau):
            depth = -1.0
        else:
            depth = triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale)
    if depth > tau:
        c = 0.0
    elif near:
        r = near_rest[idx]
        if r <= 0.0:
            c = cap  # the pair touches in the rest mesh: no reference to measure against
        elif shared == 1:
            c = cap * _corner_angle(verts, faces, a, b) / r
        else:
            c = cap * max(-depth, 0.0) / r
    else:
        c = 0.0 if depth > 0.0 else triangle_distance(p0, p1, p2, q0, q1, q2)
    return True, depth, c


@njit(cache=True, inline="always")
def _lower_clearance(clear, part, faces, a, b, c):
    for t in (a, b):
        for i in range(3):
            pi = part[faces[t, i]]
            if c < clear[pi]:
                clear[pi] = c


@njit(cache=True)
def _add_crossings(verts, faces, a, b, adj_ptr, adj_idx, adj_eid, orient, rec_key, rec_int, n_rec):
    """Append the crossing records of a counted pair (edges of a through b and of b through a).

    A record is key = edge id + lambda / 2 and ints = (edge, behind vertex, other end, pierced triangle,
    counted pair). Returns the (possibly grown) arrays and the new count.
    """
    for side in range(2):
        s = a if side == 0 else b
        t = b if side == 0 else a
        ta, tb, tc = _tri(verts, faces, t)
        for i in range(3):
            u = faces[s, i]
            w = faces[s, (i + 1) % 3]
            if u == faces[t, 0] or u == faces[t, 1] or u == faces[t, 2]:
                continue
            if w == faces[t, 0] or w == faces[t, 1] or w == faces[t, 2]:
                continue
            pu = _pt(verts, u)
            pw = _pt(verts, w)
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
            dl = _orient(ta, tb, tc, _pt(verts, lo_v))
            dh = _orient(ta, tb, tc, _pt(verts, hi_v))
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
        idx = _near_index(near_ptr, near_b, a, b)
        evaluated, depth, c = _pair_terms(verts, faces, a, b, shared, idx, near_rest, scale, tau, cap, clear, part)
        if not evaluated:
            continue
        _lower_clearance(clear, part, faces, a, b, c)
        if depth <= tau:
            continue  # apart, or touching within tau: not counted, no crossing edges
        n_pairs += 1
        for t in (a, b):
            for i in range(3):
                pi = part[faces[t, i]]
                floor[pi] = max(floor[pi], depth - tau)
        rec_key, rec_int, n_rec = _add_crossings(verts, faces, a, b, adj_ptr, adj_idx, adj_eid, orient,
                                                 rec_key, rec_int, n_rec)
    return n_pairs, rec_key, rec_int, n_rec


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


# ----------------------------------------------------------------------------------------- pruned clearance
@njit(cache=True)
def triangle_axes(verts, faces, scale):
    """The four SAT axes each triangle contributes to :func:`triangle_pair_depth`: its normal and its three
    in-plane edge normals, formed with exactly the same floating-point operations.

    Returns:
        axes (F, 4, 3) unnormalised axes, inv (F, 4) their inverse length (0 for an axis
        ``triangle_pair_depth`` skips as degenerate), lo and hi (F, 4) the triangle's own projection interval.
    """
    tiny = _EPS_AXIS * scale**4
    n_faces = faces.shape[0]
    axes = np.zeros((n_faces, 4, 3))
    inv = np.zeros((n_faces, 4))
    lo = np.zeros((n_faces, 4))
    hi = np.zeros((n_faces, 4))
    for f in range(n_faces):
        p0, p1, p2 = _tri(verts, faces, f)
        e0 = _sub(p1, p0)
        e1 = _sub(p2, p1)
        e2 = _sub(p0, p2)
        n = _cross(e0, _sub(p2, p0))
        for k in range(4):
            if k == 0:
                ax = n
                ok = _dot(ax, ax) > 0.0
            else:
                ax = _cross(n, e0 if k == 1 else (e1 if k == 2 else e2))
                ok = _dot(ax, ax) > tiny and _dot(ax, ax) > 0.0
            if not ok:
                continue
            iv = 1.0 / np.sqrt(_dot(ax, ax))
            a0 = _dot(ax, p0) * iv
            a1 = _dot(ax, p1) * iv
            a2 = _dot(ax, p2) * iv
            for d in range(3):
                axes[f, k, d] = ax[d]
            inv[f, k] = iv
            lo[f, k] = min(a0, a1, a2)
            hi[f, k] = max(a0, a1, a2)
    return axes, inv, lo, hi


@njit(cache=True, inline="always")
def _axes_gap(axes, inv, lo, hi, f, q0, q1, q2):
    """Largest gap between triangle f and the triangle (q0, q1, q2) along f's own SAT axes (-inf if none).

    Each term is the negated overlap ``_sat_axis`` computes for that axis, bit for bit, and the SAT depth is
    the minimum overlap over a superset of these axes, so ``gap <= -triangle_pair_depth`` exactly."""
    g = -np.inf
    for k in range(4):
        iv = inv[f, k]
        if iv == 0.0:
            continue
        ax = (axes[f, k, 0], axes[f, k, 1], axes[f, k, 2])
        b0 = _dot(ax, q0) * iv
        b1 = _dot(ax, q1) * iv
        b2 = _dot(ax, q2) * iv
        ov = min(hi[f, k] - min(b0, b1, b2), max(b0, b1, b2) - lo[f, k])
        g = max(g, -ov)
    return g


@njit(cache=True)
def _seed_depth(verts, faces, seeds, k):
    """Depth of a crossing edge: distance of its nearer endpoint to the pierced triangle."""
    t = seeds[k, 2]
    ta, tb, tc = _tri(verts, faces, t)
    return min(point_triangle_distance(_pt(verts, seeds[k, 0]), ta, tb, tc),
               point_triangle_distance(_pt(verts, seeds[k, 1]), ta, tb, tc))


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
            p = _pt(verts, v)
            k_best = 0
            for k in range(n_opp):
                e = 0.0
                for d in range(3):
                    e += (p[d] - cen[k, d]) ** 2
                lb[k] = np.sqrt(e) - rad[k]
                if lb[k] < lb[k_best]:
                    k_best = k
            f = opp[k_best]
            t0, t1, t2 = _tri(verts, faces, f)
            best = point_triangle_distance(p, t0, t1, t2)
            for k in range(n_opp):
                if lb[k] >= best:
                    continue
                f = opp[k]
                t0, t1, t2 = _tri(verts, faces, f)
                d = point_triangle_distance(p, t0, t1, t2)
                if d < best:
                    best = d
            depth[v] = best
    return depth


# ----------------------------------------------------------------------------------------- pruned label passes
@njit(cache=True, inline="always")
def _count_pair(verts, faces, a, b, depth, tau, part, floor, adj_ptr, adj_idx, adj_eid, orient, rec_key, rec_int,
                n_rec):
    """A counted pair (depth > tau): raise the floor of its parts and append its crossing records."""
    for t in (a, b):
        for i in range(3):
            pi = part[faces[t, i]]
            floor[pi] = max(floor[pi], depth - tau)
    return _add_crossings(verts, faces, a, b, adj_ptr, adj_idx, adj_eid, orient, rec_key, rec_int, n_rec)


@njit(cache=True)
def corner_cones(verts, faces):
    """The corner of every triangle at each of its vertices as a ball of unit directions: (F, 3, 3) unit axis
    ``m`` (the bisector) and (F, 3) chordal radius ``rho = |u1 - m|`` (``u1``, ``u2``: unit edge directions;
    every direction of the corner lies within ``rho`` of ``m``; 2, i.e. no bound, for a degenerate corner)."""
    n = faces.shape[0]
    axis = np.zeros((n, 3, 3))
    rho = np.full((n, 3), 2.0)
    for f in range(n):
        for i in range(3):
            p = _pt(verts, faces[f, i])
            u1 = _sub(_pt(verts, faces[f, (i + 1) % 3]), p)
            u2 = _sub(_pt(verts, faces[f, (i + 2) % 3]), p)
            l1 = np.sqrt(_dot(u1, u1))
            l2 = np.sqrt(_dot(u2, u2))
            if l1 <= 0.0 or l2 <= 0.0:
                continue
            u1 = _scale(u1, 1.0 / l1)
            u2 = _scale(u2, 1.0 / l2)
            m = _add(u1, u2)
            lm = np.sqrt(_dot(m, m))
            if lm <= 1e-8:
                continue
            m = _scale(m, 1.0 / lm)
            for d in range(3):
                axis[f, i, d] = m[d]
            e = _sub(u1, m)
            rho[f, i] = np.sqrt(_dot(e, e))
    return axis, rho


CONE_MARGIN = 1e-9  # taken off the cone bound (chord units): covers the round-off of the unit vectors


@njit(cache=True, inline="always")
def _cone_gap(faces, a, b, axis, rho):
    """Lower bound of :func:`wedge_gap` for triangles a and b sharing one vertex, from their corner balls: by
    the triangle inequality the chordal distance between any two directions of the corners is at least
    ``|m_a - m_b| - rho_a - rho_b`` (minus :data:`CONE_MARGIN`); -1 if that is <= 0 (no bound: the corners
    may overlap). A positive bound also proves the triangles do not overlap beyond the shared vertex."""
    for i in range(3):
        for j in range(3):
            if faces[a, i] == faces[b, j]:
                d0 = axis[a, i, 0] - axis[b, j, 0]
                d1 = axis[a, i, 1] - axis[b, j, 1]
                d2 = axis[a, i, 2] - axis[b, j, 2]
                lb = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) - rho[a, i] - rho[b, j] - CONE_MARGIN
                return lb if lb > 0.0 else -1.0
    return -1.0


@njit(cache=True)
def near_pass(verts, faces, near_ptr, near_b, near_rest, near_shared, lo0, hi0, lo_cap, hi_cap, axes, inv, ax_lo,
              ax_hi, cone_axis, cone_rho, scale, tau, cap, clear, floor, part, adj_ptr, adj_idx, adj_eid, orient,
              rec_key, rec_int, n_rec, scratch_i, scratch_f):
    """Every near pair (the rest mesh's table) that the reference considers (boxes within cap): counted pairs,
    their crossings, and the clearance terms that can lower a part's clearance. Lowers ``clear`` and raises
    ``floor`` in place.

    A pair whose boxes overlap may be counted (d > tau); a pair whose boxes are disjoint cannot (as in the
    reference, whose counted pairs come from overlapping boxes). The per-triangle SAT axes give
    ``g <= -depth`` exactly (:func:`_axes_gap`), so a pair not sharing a vertex with ``g > tau`` is not
    counted and its term ``c = cap * max(-depth, 0) / r >= cap * g / r``: it is evaluated only if that bound
    is below the largest current clearance of its parts (then it might lower one). To make that threshold
    low early, the pair with the smallest bound of each part is evaluated first. Pairs sharing a vertex and
    pairs touching at rest (no bound) are always evaluated, as in the reference. Skipping a term that is
    >= the current clearance leaves every minimum, maximum and count unchanged, so the labels equal the
    reference's bit for bit.

    ``scratch_i`` (2, N) int64 and ``scratch_f`` (N,) float64 (N = number of near pairs) are work space, reused
    between meshes (allocating them per mesh costs more than the pass on finely subdivided meshes).

    Returns:
        n_pairs (counted), rec_key, rec_int, n_rec (crossing records, possibly grown).
    """
    n_faces = faces.shape[0]
    n_parts = clear.shape[0]
    todo_a = scratch_i[0]  # preallocated (2, N) int64 and (N,) float64 for N = len(near_b)
    todo_i = scratch_i[1]
    todo_bound = scratch_f
    n_todo = 0
    best_bound = np.full(n_parts, np.inf)
    best_k = np.full(n_parts, -1, dtype=np.int64)
    n_pairs = 0
    for a in range(n_faces):
        p0, p1, p2 = _tri(verts, faces, a)
        t_all = min(clear.max(), cap)  # no term >= this can lower any clearance (they only fall)
        for idx in range(near_ptr[a], near_ptr[a + 1]):
            b = near_b[idx]
            if not _boxes_overlap(lo_cap, hi_cap, a, b):
                continue  # not a candidate of the reference
            overlap = _boxes_overlap(lo0, hi0, a, b)
            r = near_rest[idx]
            bound = -np.inf
            if near_shared[idx]:
                # c = cap * wedge_gap / r; a positive cone bound also rules out an overlap beyond the vertex
                g = _cone_gap(faces, a, b, cone_axis, cone_rho)
                if g > 0.0:
                    bound = cap if r <= 0.0 else cap * (g * BOUND_SHRINK) / r
            else:
                q0, q1, q2 = _tri(verts, faces, b)
                g = _axes_gap(axes, inv, ax_lo, ax_hi, a, q0, q1, q2)
                if (not overlap or g > tau) and (r <= 0.0 or cap * (g * BOUND_SHRINK) / r >= t_all):
                    continue  # not counted, and its term cannot lower any clearance
                g = max(g, _axes_gap(axes, inv, ax_lo, ax_hi, b, p0, p1, p2))
                if not overlap or g > tau:  # not counted; c >= bound (c = cap when the pair touches at rest)
                    bound = cap if r <= 0.0 else cap * (g * BOUND_SHRINK) / r
            if overlap and bound == -np.inf:  # may be counted: evaluate now
                shared = 1 if near_shared[idx] else 0
                evaluated, depth, c = _pair_terms(verts, faces, a, b, shared, idx, near_rest, scale, tau, cap,
                                                  clear, part)
                if evaluated:
                    _lower_clearance(clear, part, faces, a, b, c)
                    if depth > tau:
                        n_pairs += 1
                        rec_key, rec_int, n_rec = _count_pair(verts, faces, a, b, depth, tau, part, floor, adj_ptr,
                                                              adj_idx, adj_eid, orient, rec_key, rec_int, n_rec)
                continue
            if bound >= t_all:
                continue  # not counted (bound > -inf), and its term cannot lower any clearance
            todo_a[n_todo] = a
            todo_i[n_todo] = idx
            todo_bound[n_todo] = bound
            for t in (a, b):
                for i in range(3):
                    pi = part[faces[t, i]]
                    if bound < best_bound[pi]:
                        best_bound[pi] = bound
                        best_k[pi] = n_todo
            n_todo += 1
    # the most promising pair of each part first, then the rest against the lowered thresholds
    for step in range(n_parts + n_todo):
        k = best_k[step] if step < n_parts else step - n_parts
        if k < 0:
            continue
        if step >= n_parts and todo_bound[k] == np.inf:
            continue  # done in the first round
        a = todo_a[k]
        idx = todo_i[k]
        b = near_b[idx]
        thr = _part_min(clear, part, faces, a, b, cap)
        if thr <= 0.0 or todo_bound[k] >= thr:
            continue
        todo_bound[k] = np.inf  # mark done
        shared = 1 if near_shared[idx] else 0
        evaluated, depth, c = _pair_terms(verts, faces, a, b, shared, idx, near_rest, scale, tau, cap, clear, part)
        if evaluated:
            _lower_clearance(clear, part, faces, a, b, c)
    return n_pairs, rec_key, rec_int, n_rec


@njit(cache=True, inline="always")
def _far_gap(verts, faces, a, b, axes, inv, ax_lo, ax_hi):
    """Largest gap between triangles a and b along their own SAT axes: ``<= -depth`` and ``<= distance``."""
    p0, p1, p2 = _tri(verts, faces, a)
    q0, q1, q2 = _tri(verts, faces, b)
    return max(_axes_gap(axes, inv, ax_lo, ax_hi, a, q0, q1, q2), _axes_gap(axes, inv, ax_lo, ax_hi, b, p0, p1, p2))


@njit(cache=True)
def far_pass(verts, faces, lo, hi, cell, lo0, hi0, lo_cap, hi_cap, active, pts, skip2, near_ptr, near_b, near_rest,
             axes, inv, ax_lo, ax_hi, scale, tau, cap, clear, floor, part, adj_ptr, adj_idx, adj_eid, orient, rec_key,
             rec_int, n_rec):
    """Every far pair (not adjacent, sharing no vertex, not in the near table) that matters, found with one
    uniform grid over the boxes ``lo``/``hi`` (grown by at least half the largest clearance still to beat):
    far pairs with overlapping boxes are evaluated in full (they may be counted), far pairs with disjoint
    boxes within cap lower the clearance (their term is the distance; only when a triangle is ``active``,
    i.e. some part of its vertices still has a clearance > 0, and the rest centroids ``pts`` are at least
    ``sqrt(skip2)`` apart: closer pairs are near). Each pair is visited once (the cell of the lower corner
    of the two grown boxes' intersection) and evaluated as it is found.

    Returns:
        n_pairs (counted), rec_key, rec_int, n_rec.
    """
    n = lo.shape[0]
    keys, ids, ilo, dims = _grid_cells(lo, hi, cell)
    total = keys.shape[0]
    # entries in cell order, each cell's entries sorted by their box's lower x (insertion sort: cells are
    # small), copied contiguously; a sweep along x stops at the first entry that starts beyond the box's end
    s_lo = np.empty((total, 3))
    s_hi = np.empty((total, 3))
    for e in range(total):
        f = ids[e]
        for d in range(3):
            s_lo[e, d] = lo[f, d]
            s_hi[e, d] = hi[f, d]
    start = 0
    while start < total:
        end = start + 1
        while end < total and keys[end] == keys[start]:
            end += 1
        for e in range(start + 1, end):
            x = s_lo[e, 0]
            f = ids[e]
            y0 = s_lo[e, 1]
            z0 = s_lo[e, 2]
            x1 = s_hi[e, 0]
            y1 = s_hi[e, 1]
            z1 = s_hi[e, 2]
            m = e - 1
            while m >= start and s_lo[m, 0] > x:
                ids[m + 1] = ids[m]
                for d in range(3):
                    s_lo[m + 1, d] = s_lo[m, d]
                    s_hi[m + 1, d] = s_hi[m, d]
                m -= 1
            ids[m + 1] = f
            s_lo[m + 1, 0] = x
            s_lo[m + 1, 1] = y0
            s_lo[m + 1, 2] = z0
            s_hi[m + 1, 0] = x1
            s_hi[m + 1, 1] = y1
            s_hi[m + 1, 2] = z1
        start = end
    # per triangle, the largest clearance (capped) among its vertices' parts when the pass starts
    tri_thr = np.zeros(n)
    for f in range(n):
        if active[f]:
            for i in range(3):
                tri_thr[f] = max(tri_thr[f], min(clear[part[faces[f, i]]], cap))
    n_pairs = 0
    start = 0
    while start < total:
        end = start + 1
        while end < total and keys[end] == keys[start]:
            end += 1
        key = keys[start]
        cz = key % dims[2]
        cy = (key // dims[2]) % dims[1]
        cx = key // (dims[2] * dims[1])
        for i in range(start, end):
            a0 = ids[i]
            ax1 = s_hi[i, 0]
            for j in range(i + 1, end):
                if s_lo[j, 0] > ax1:
                    break  # this and every later entry of the cell start beyond a0's box in x
                if (s_lo[j, 1] > s_hi[i, 1] or s_lo[i, 1] > s_hi[j, 1] or s_lo[j, 2] > s_hi[i, 2]
                        or s_lo[i, 2] > s_hi[j, 2]):
                    continue  # (x overlaps: s_lo[i, 0] <= s_lo[j, 0] <= s_hi[i, 0])
                b0 = ids[j]
                if (max(ilo[a0, 0], ilo[b0, 0]) != cx or max(ilo[a0, 1], ilo[b0, 1]) != cy
                        or max(ilo[a0, 2], ilo[b0, 2]) != cz):
                    continue
                a = min(a0, b0)
                b = max(a0, b0)
                if _boxes_overlap(lo0, hi0, a, b):
                    if _near_index(near_ptr, near_b, a, b) >= 0 or shared_vertex_count(faces, a, b) > 0:
                        continue  # near or adjacent: not a far pair
                    g = _far_gap(verts, faces, a, b, axes, inv, ax_lo, ax_hi)
                    if g > tau and g * BOUND_SHRINK >= _part_min(clear, part, faces, a, b, cap):
                        continue  # not counted (depth <= -g), and its distance >= g cannot lower a clearance
                    evaluated, depth, c = _pair_terms(verts, faces, a, b, 0, -1, near_rest, scale, tau, cap, clear,
                                                      part)
                    if evaluated:
                        _lower_clearance(clear, part, faces, a, b, c)
                        if depth > tau:
                            n_pairs += 1
                            rec_key, rec_int, n_rec = _count_pair(verts, faces, a, b, depth, tau, part, floor,
                                                                  adj_ptr, adj_idx, adj_eid, orient, rec_key, rec_int,
                                                                  n_rec)
                    continue
                t = max(tri_thr[a], tri_thr[b])  # >= the pair's current threshold (clearances only fall)
                if t <= 0.0 or not _boxes_overlap(lo_cap, hi_cap, a, b):
                    continue
                g2 = 0.0  # Euclidean gap of the boxes, as _pair_terms computes it: a lower bound of the distance
                for d in range(3):
                    gap = max(lo0[b, d] - hi0[a, d], lo0[a, d] - hi0[b, d], 0.0)
                    g2 += gap * gap
                lb = np.sqrt(g2)
                if lb > 0.0 and lb * BOUND_SHRINK >= t:
                    continue
                dd = 0.0
                for d in range(3):
                    dd += (pts[a, d] - pts[b, d]) ** 2
                if dd < skip2:
                    continue  # closer than cap at rest: near
                if _near_index(near_ptr, near_b, a, b) >= 0 or shared_vertex_count(faces, a, b) > 0:
                    continue
                thr = _part_min(clear, part, faces, a, b, cap)
                if thr <= 0.0 or _far_gap(verts, faces, a, b, axes, inv, ax_lo, ax_hi) * BOUND_SHRINK >= thr:
                    continue  # its distance >= the gap cannot lower a clearance
                evaluated, depth, c = _pair_terms(verts, faces, a, b, 0, -1, near_rest, scale, tau, cap, clear, part)
                if evaluated:
                    _lower_clearance(clear, part, faces, a, b, c)
        start = end
    return n_pairs, rec_key, rec_int, n_rec
