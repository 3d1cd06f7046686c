"""Distances and gaps between triangles: point/segment/triangle distances (Ericson), box gaps, and the gap
between the corners of two triangles sharing one vertex (wedge gap) with its cone bound."""

from __future__ import annotations

import numpy as np
from numba import njit

from neuralcol.collision.kernels.vec import corners, point, vadd, vcross, vdot, vscale, vsub


@njit(cache=True, inline="always")
def closest_point_triangle(p, a, b, c):
    """The point of triangle (a, b, c) closest to point p (Ericson, Real-Time Collision Detection 5.1.5). For a
    degenerate triangle (zero area) where Ericson's formulas divide by zero, some point of the triangle."""
    ab = vsub(b, a)
    ac = vsub(c, a)
    ap = vsub(p, a)
    d1 = vdot(ab, ap)
    d2 = vdot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        x = a
    else:
        bp = vsub(p, b)
        d3 = vdot(ab, bp)
        d4 = vdot(ac, bp)
        if d3 >= 0.0 and d4 <= d3:
            x = b
        else:
            vc = d1 * d4 - d3 * d2
            if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                x = vadd(a, vscale(ab, d1 / (d1 - d3))) if d1 != d3 else a
            else:
                cp = vsub(p, c)
                d5 = vdot(ab, cp)
                d6 = vdot(ac, cp)
                if d6 >= 0.0 and d5 <= d6:
                    x = c
                else:
                    vb = d5 * d2 - d1 * d6
                    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                        x = vadd(a, vscale(ac, d2 / (d2 - d6))) if d2 != d6 else a
                    else:
                        va = d3 * d6 - d5 * d4
                        if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
                            w = (d4 - d3) + (d5 - d6)
                            x = vadd(b, vscale(vsub(c, b), (d4 - d3) / w)) if w != 0.0 else b
                        elif va + vb + vc != 0.0:
                            denom = 1.0 / (va + vb + vc)
                            x = vadd(a, vadd(vscale(ab, vb * denom), vscale(ac, vc * denom)))
                        else:
                            x = a  # a degenerate triangle: a point of it (the caller's edge distances cover it)
    return x


@njit(cache=True)
def point_triangle_distance(p, a, b, c):
    """Euclidean distance from point p to triangle (a, b, c) (:func:`closest_point_triangle`)."""
    d = vsub(p, closest_point_triangle(p, a, b, c))
    return np.sqrt(vdot(d, d))


@njit(cache=True)
def segment_segment_distance(p1, q1, p2, q2):
    """Distance between segments p1q1 and p2q2 (Ericson 5.1.9)."""
    d1 = vsub(q1, p1)
    d2 = vsub(q2, p2)
    r = vsub(p1, p2)
    a = vdot(d1, d1)
    e = vdot(d2, d2)
    f = vdot(d2, r)
    if a <= 1e-300 and e <= 1e-300:
        return np.sqrt(vdot(r, r))
    if a <= 1e-300:
        s = 0.0
        t = min(max(f / e, 0.0), 1.0)
    else:
        c = vdot(d1, r)
        if e <= 1e-300:
            t = 0.0
            s = min(max(-c / a, 0.0), 1.0)
        else:
            b = vdot(d1, d2)
            denom = a * e - b * b
            s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > 0.0 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t = 1.0
                s = min(max((b - c) / a, 0.0), 1.0)
    diff = vsub(vadd(p1, vscale(d1, s)), vadd(p2, vscale(d2, t)))
    return np.sqrt(vdot(diff, diff))


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


@njit(cache=True)
def pair_distance(verts, faces, a, b):
    p0, p1, p2 = corners(verts, faces, a)
    q0, q1, q2 = corners(verts, faces, b)
    return triangle_distance(p0, p1, p2, q0, q1, q2)


@njit(cache=True, inline="always")
def box_gap(p0, p1, p2, q0, q1, q2):
    """Distance between the axis-aligned boxes of two triangles (a lower bound of their distance)."""
    g2 = 0.0
    for d in range(3):
        gap = max(min(q0[d], q1[d], q2[d]) - max(p0[d], p1[d], p2[d]),
                  min(p0[d], p1[d], p2[d]) - max(q0[d], q1[d], q2[d]), 0.0)
        g2 += gap * gap
    return np.sqrt(g2)


@njit(cache=True, inline="always")
def _unit(a):
    n = np.sqrt(vdot(a, a))
    if n <= 0.0:
        return (0.0, 0.0, 0.0)
    return vscale(a, 1.0 / n)


@njit(cache=True)
def _point_arc_chord(x, v1, v2):
    """Chordal distance from unit vector x to the great-circle arc from unit v1 to unit v2 (shorter arc):
    the Euclidean distance to the nearest unit vector on the arc."""
    n = _unit(vcross(v1, v2))
    xp = vsub(x, vscale(n, vdot(x, n)))
    lxp = np.sqrt(vdot(xp, xp))
    if lxp > 0.0 and vdot(vcross(v1, xp), n) >= 0.0 and vdot(vcross(xp, v2), n) >= 0.0:
        return np.sqrt(max(0.0, 2.0 - 2.0 * lxp))  # |x - xp/|xp||, since x . xp = |xp|^2
    d1 = vsub(x, v1)
    d2 = vsub(x, v2)
    return np.sqrt(min(vdot(d1, d1), vdot(d2, d2)))


@njit(cache=True)
def wedge_gap(p, a, b, c, d):
    """Gap between the corners at shared vertex p of triangles (p, a, b) and (p, c, d).

    The directions of a triangle at p form a great-circle arc on the unit sphere; the gap is 0 when the two
    arcs cross (the triangles then overlap near p, beyond p itself) and otherwise the chordal distance
    between the arcs (2 sin(angle / 2) of the smallest angle between them). Continuous in the vertices.
    """
    u1 = _unit(vsub(a, p))
    u2 = _unit(vsub(b, p))
    v1 = _unit(vsub(c, p))
    v2 = _unit(vsub(d, p))
    nu = vcross(u1, u2)
    nv = vcross(v1, v2)
    s1 = vdot(u1, nv)
    s2 = vdot(u2, nv)
    t1 = vdot(v1, nu)
    t2 = vdot(v2, nu)
    x = vcross(nu, nv)
    coplanar = vdot(x, x) <= 1e-20 * vdot(nu, nu) * vdot(nv, nv)  # then the arc distances below decide
    if not coplanar and s1 * s2 <= 0.0 and t1 * t2 <= 0.0:
        mu = vadd(u1, u2)
        mv = vadd(v1, v2)
        if (vdot(x, mu) >= 0.0 and vdot(x, mv) >= 0.0) or (vdot(x, mu) <= 0.0 and vdot(x, mv) <= 0.0):
            return 0.0
    g = _point_arc_chord(u1, v1, v2)
    g = min(g, _point_arc_chord(u2, v1, v2))
    g = min(g, _point_arc_chord(v1, u1, u2))
    g = min(g, _point_arc_chord(v2, u1, u2))
    return g


@njit(cache=True)
def corner_angle(verts, faces, a, b):
    """Wedge angle at the single shared vertex of triangles a and b."""
    for i in range(3):
        for j in range(3):
            if faces[a, i] == faces[b, j]:
                p = faces[a, i]
                return wedge_gap(point(verts, p), point(verts, faces[a, (i + 1) % 3]),
                                 point(verts, faces[a, (i + 2) % 3]), point(verts, faces[b, (j + 1) % 3]),
                                 point(verts, faces[b, (j + 2) % 3]))
    return 0.0


@njit(cache=True)
def corner_cones(verts, faces, units=None, normals=None):
    """The corner of every triangle at each of its vertices as a ball of unit directions: (F, 3, 3) unit axis
    ``m`` (the bisector) and (F, 3) chordal radius ``rho = |u1 - m|`` (``u1``, ``u2``: unit edge directions;
    every direction of the corner lies within ``rho`` of ``m``; 2, i.e. no bound, for a degenerate corner).

    If given, ``units`` (F, 3, 2, 3) receives each corner's ``u1`` and ``u2`` and ``normals`` (F, 3, 3) the unit
    normal of its arc, ``_unit(u1 x u2)``, formed with the same operations as :func:`wedge_gap` forms them, so
    :func:`corner_gap` reads them instead of recomputing them (zero vectors where :func:`_unit` gives them)."""
    n = faces.shape[0]
    axis = np.zeros((n, 3, 3))
    rho = np.full((n, 3), 2.0)
    keep = units is not None and normals is not None
    for f in range(n):
        for i in range(3):
            p = point(verts, faces[f, i])
            u1 = vsub(point(verts, faces[f, (i + 1) % 3]), p)
            u2 = vsub(point(verts, faces[f, (i + 2) % 3]), p)
            l1 = np.sqrt(vdot(u1, u1))
            l2 = np.sqrt(vdot(u2, u2))
            if keep:
                w1 = _unit(u1)
                w2 = _unit(u2)
                nn = _unit(vcross(w1, w2))
                for d in range(3):
                    units[f, i, 0, d] = w1[d]
                    units[f, i, 1, d] = w2[d]
                    normals[f, i, d] = nn[d]
            if l1 <= 0.0 or l2 <= 0.0:
                continue
            u1 = vscale(u1, 1.0 / l1)
            u2 = vscale(u2, 1.0 / l2)
            m = vadd(u1, u2)
            lm = np.sqrt(vdot(m, m))
            if lm <= 1e-8:
                continue
            m = vscale(m, 1.0 / lm)
            for d in range(3):
                axis[f, i, d] = m[d]
            e = vsub(u1, m)
            rho[f, i] = np.sqrt(vdot(e, e))
    return axis, rho


@njit(cache=True, inline="always")
def _arc_chord_with_normal(x, v1, v2, n):
    """:func:`_point_arc_chord` with the arc's unit normal ``n = _unit(v1 x v2)`` given (same operations)."""
    xp = vsub(x, vscale(n, vdot(x, n)))
    lxp = np.sqrt(vdot(xp, xp))
    if lxp > 0.0 and vdot(vcross(v1, xp), n) >= 0.0 and vdot(vcross(xp, v2), n) >= 0.0:
        return np.sqrt(max(0.0, 2.0 - 2.0 * lxp))
    d1 = vsub(x, v1)
    d2 = vsub(x, v2)
    return np.sqrt(min(vdot(d1, d1), vdot(d2, d2)))


@njit(cache=True, inline="always")
def corner_gap(faces, a, b, units, normals):
    """:func:`corner_angle` of triangles a and b (sharing one vertex) from the corner frames of
    :func:`corner_cones` (``units``, ``normals``): the same operations on the same numbers, so bit for bit the
    same value, without recomputing the unit edge directions and arc normals."""
    for i in range(3):
        for j in range(3):
            if faces[a, i] == faces[b, j]:
                u1 = (units[a, i, 0, 0], units[a, i, 0, 1], units[a, i, 0, 2])
                u2 = (units[a, i, 1, 0], units[a, i, 1, 1], units[a, i, 1, 2])
                v1 = (units[b, j, 0, 0], units[b, j, 0, 1], units[b, j, 0, 2])
                v2 = (units[b, j, 1, 0], units[b, j, 1, 1], units[b, j, 1, 2])
                na = (normals[a, i, 0], normals[a, i, 1], normals[a, i, 2])
                nb = (normals[b, j, 0], normals[b, j, 1], normals[b, j, 2])
                nu = vcross(u1, u2)
                nv = vcross(v1, v2)
                s1 = vdot(u1, nv)
                s2 = vdot(u2, nv)
                t1 = vdot(v1, nu)
                t2 = vdot(v2, nu)
                x = vcross(nu, nv)
                coplanar = vdot(x, x) <= 1e-20 * vdot(nu, nu) * vdot(nv, nv)
                if not coplanar and s1 * s2 <= 0.0 and t1 * t2 <= 0.0:
                    mu = vadd(u1, u2)
                    mv = vadd(v1, v2)
                    if (vdot(x, mu) >= 0.0 and vdot(x, mv) >= 0.0) or (vdot(x, mu) <= 0.0 and vdot(x, mv) <= 0.0):
                        return 0.0
                g = _arc_chord_with_normal(u1, v1, v2, nb)
                g = min(g, _arc_chord_with_normal(u2, v1, v2, nb))
                g = min(g, _arc_chord_with_normal(v1, u1, u2, na))
                g = min(g, _arc_chord_with_normal(v2, u1, u2, na))
                return g
    return 0.0


CONE_MARGIN = 1e-9  # taken off the cone bound (chord units): covers the round-off of the unit vectors


@njit(cache=True, inline="always")
def cone_gap(faces, a, b, axis, rho):
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
