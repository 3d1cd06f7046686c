"""Triangle-pair penetration by the separating-axis theorem: the SAT depth, cheap separation tests, the
per-triangle SAT axes that bound it, and the segment/triangle crossings of a counted pair."""

from __future__ import annotations

import numpy as np
from numba import njit

from neuralcol.collision.kernels.vec import corners, point, vcross, vdot, vsub

_EPS_AXIS = 1e-24  # squared length below which a SAT axis is degenerate (relative to scale^4)


@njit(cache=True)
def _sat_axis(axis, p0, p1, p2, q0, q1, q2, best):
    ll = vdot(axis, axis)
    if ll <= 0.0:
        return best
    inv = 1.0 / np.sqrt(ll)
    a0 = vdot(axis, p0) * inv
    a1 = vdot(axis, p1) * inv
    a2 = vdot(axis, p2) * inv
    b0 = vdot(axis, q0) * inv
    b1 = vdot(axis, q1) * inv
    b2 = vdot(axis, q2) * inv
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
    e0 = vsub(p1, p0)
    e1 = vsub(p2, p1)
    e2 = vsub(p0, p2)
    f0 = vsub(q1, q0)
    f1 = vsub(q2, q1)
    f2 = vsub(q0, q2)
    n = vcross(e0, vsub(p2, p0))
    m = vcross(f0, vsub(q2, q0))
    best = np.inf
    best = _sat_axis(n, p0, p1, p2, q0, q1, q2, best)
    best = _sat_axis(m, p0, p1, p2, q0, q1, q2, best)
    for ea in (e0, e1, e2):
        for fb in (f0, f1, f2):
            ax = vcross(ea, fb)
            if vdot(ax, ax) > tiny:
                best = _sat_axis(ax, p0, p1, p2, q0, q1, q2, best)
    for ea in (e0, e1, e2):
        ax = vcross(n, ea)
        if vdot(ax, ax) > tiny:
            best = _sat_axis(ax, p0, p1, p2, q0, q1, q2, best)
    for fb in (f0, f1, f2):
        ax = vcross(m, fb)
        if vdot(ax, ax) > tiny:
            best = _sat_axis(ax, p0, p1, p2, q0, q1, q2, best)
    return best


@njit(cache=True)
def coplanar_depth(p0, p1, p2, q0, q1, q2, scale):
    """In-plane penetration depth of two triangles that lie in one plane: the separating-axis depth over the six
    in-plane edge normals (normal x edge) alone, i.e. the shortest translation within the plane that makes their
    interiors disjoint. > 0 when the interiors overlap. (:func:`triangle_pair_depth` is 0 for such a pair: a
    shift along the common normal separates it, however large the overlap.)"""
    tiny = _EPS_AXIS * scale**4
    n = vcross(vsub(p1, p0), vsub(p2, p0))
    m = vcross(vsub(q1, q0), vsub(q2, q0))
    best = np.inf
    for ea in (vsub(p1, p0), vsub(p2, p1), vsub(p0, p2)):
        ax = vcross(n, ea)
        if vdot(ax, ax) > tiny:
            best = _sat_axis(ax, p0, p1, p2, q0, q1, q2, best)
    for fb in (vsub(q1, q0), vsub(q2, q1), vsub(q0, q2)):
        ax = vcross(m, fb)
        if vdot(ax, ax) > tiny:
            best = _sat_axis(ax, p0, p1, p2, q0, q1, q2, best)
    return best


@njit(cache=True)
def plane_separated(p0, p1, p2, q0, q1, q2, margin):
    """True if one triangle lies strictly beyond ``margin`` on one side of the other's plane (then their
    SAT depth is < -margin, i.e. they are apart)."""
    for side in range(2):
        a0, a1, a2 = (p0, p1, p2) if side == 0 else (q0, q1, q2)
        b0, b1, b2 = (q0, q1, q2) if side == 0 else (p0, p1, p2)
        n = vcross(vsub(a1, a0), vsub(a2, a0))
        ln = np.sqrt(vdot(n, n))
        if ln <= 0.0:
            continue
        off = vdot(n, a0)
        s0 = vdot(n, b0) - off
        s1 = vdot(n, b1) - off
        s2 = vdot(n, b2) - off
        m = margin * ln
        if (s0 > m and s1 > m and s2 > m) or (s0 < -m and s1 < -m and s2 < -m):
            return True
    return False


@njit(cache=True)
def pair_depths(verts, faces, pairs, scale):
    """SAT depth of each candidate pair, (P,) float64."""
    out = np.empty(pairs.shape[0])
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        p0, p1, p2 = corners(verts, faces, a)
        q0, q1, q2 = corners(verts, faces, b)
        out[k] = triangle_pair_depth(p0, p1, p2, q0, q1, q2, scale)
    return out


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
        p0, p1, p2 = corners(verts, faces, f)
        e0 = vsub(p1, p0)
        e1 = vsub(p2, p1)
        e2 = vsub(p0, p2)
        n = vcross(e0, vsub(p2, p0))
        for k in range(4):
            if k == 0:
                ax = n
                ok = vdot(ax, ax) > 0.0
            else:
                ax = vcross(n, e0 if k == 1 else (e1 if k == 2 else e2))
                ok = vdot(ax, ax) > tiny and vdot(ax, ax) > 0.0
            if not ok:
                continue
            iv = 1.0 / np.sqrt(vdot(ax, ax))
            a0 = vdot(ax, p0) * iv
            a1 = vdot(ax, p1) * iv
            a2 = vdot(ax, p2) * iv
            for d in range(3):
                axes[f, k, d] = ax[d]
            inv[f, k] = iv
            lo[f, k] = min(a0, a1, a2)
            hi[f, k] = max(a0, a1, a2)
    return axes, inv, lo, hi


@njit(cache=True, inline="always")
def axes_gap(axes, inv, lo, hi, f, q0, q1, q2):
    """Largest gap between triangle f and the triangle (q0, q1, q2) along f's own SAT axes (-inf if none).

    Each term is the negated overlap ``_sat_axis`` computes for that axis, bit for bit, and the SAT depth is
    the minimum overlap over a superset of these axes, so ``gap <= -triangle_pair_depth`` exactly."""
    g = -np.inf
    for k in range(4):
        iv = inv[f, k]
        if iv == 0.0:
            continue
        ax = (axes[f, k, 0], axes[f, k, 1], axes[f, k, 2])
        b0 = vdot(ax, q0) * iv
        b1 = vdot(ax, q1) * iv
        b2 = vdot(ax, q2) * iv
        ov = min(hi[f, k] - min(b0, b1, b2), max(b0, b1, b2) - lo[f, k])
        g = max(g, -ov)
    return g


@njit(cache=True, inline="always")
def signed_volume(a, b, c, d):
    """Signed volume (times 6) of tetrahedron (a, b, c, d): > 0 if d is on the side of (b-a)x(c-a)."""
    return vdot(vcross(vsub(b, a), vsub(c, a)), vsub(d, a))


@njit(cache=True)
def segment_crosses_triangle(p, q, a, b, c):
    """Signed volume of p w.r.t. triangle (a, b, c) if segment pq properly crosses its interior, else 0.

    The segment crosses when p and q are strictly on opposite sides of the plane and the crossing point lies
    inside the triangle (boundary included). The sign of the returned value tells on which side p is.
    """
    dp = signed_volume(a, b, c, p)
    dq = signed_volume(a, b, c, q)
    if dp * dq >= 0.0:
        return 0.0
    s0 = signed_volume(p, q, a, b)
    s1 = signed_volume(p, q, b, c)
    s2 = signed_volume(p, q, c, a)
    if (s0 >= 0.0 and s1 >= 0.0 and s2 >= 0.0) or (s0 <= 0.0 and s1 <= 0.0 and s2 <= 0.0):
        return dp
    return 0.0


@njit(cache=True)
def opposite_edges_cross(verts, faces, a, b):
    """For triangles sharing exactly one vertex: does the edge of one opposite the shared vertex cross the
    other? (They overlap beyond the shared vertex only if one of these two edges crosses.)"""
    for i in range(3):
        for j in range(3):
            if faces[a, i] == faces[b, j]:
                pa = point(verts, faces[a, (i + 1) % 3])
                pb = point(verts, faces[a, (i + 2) % 3])
                qa = point(verts, faces[b, (j + 1) % 3])
                qb = point(verts, faces[b, (j + 2) % 3])
                p = point(verts, faces[a, i])
                if segment_crosses_triangle(pa, pb, p, qa, qb) != 0.0:
                    return True
                return segment_crosses_triangle(qa, qb, p, pa, pb) != 0.0
    return False
