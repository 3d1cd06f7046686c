"""Exact geometric predicates for the verdict: the signs of orient3d and orient2d on the float coordinates given,
and whether two triangles' relative interiors intersect.

Each predicate first evaluates its determinant in floating point and accepts the sign when it exceeds Shewchuk's
static error bound ("Adaptive Precision Floating-Point Arithmetic and Fast Robust Geometric Predicates", 1997,
stage A); only when it does not (the points are coplanar or collinear within round-off) it evaluates the
determinant exactly with floating-point expansions (the same paper's two-sum, two-product and expansion sums, no
rounding anywhere), so the sign is exact for the coordinates given at every scale, as long as no product
overflows or underflows (coordinates between about 1e-140 and 1e140 in magnitude).

The triangle-triangle test uses only these signs on the six input points (the approach of Guigue and Devillers,
"Fast and robust triangle-triangle overlap test using orientation predicates", 2003, made strict so that touching
does not count), so it is exact too. Conventions: ``orient3d(a, b, c, d) > 0`` when d lies on the side of the plane
(a, b, c) that ``(b - a) x (c - a)`` points to; ``orient2d(a, b, c) > 0`` when (a, b, c) turn counterclockwise.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_EPS = 2.0**-53  # half an ulp of 1.0: the unit round-off of float64
_SPLITTER = 2.0**27 + 1.0
_O3D_BOUND = (7.0 + 56.0 * _EPS) * _EPS  # Shewchuk's o3derrboundA
_O2D_BOUND = (3.0 + 16.0 * _EPS) * _EPS  # Shewchuk's ccwerrboundA

NO_CONTACT, CROSSING, COPLANAR_OVERLAP = 0, 1, 2  # what :func:`triangles_intersect` returns


# ---------------------------------------------------------------------------------------------- expansion arithmetic
@njit(cache=True, inline="always")
def _two_sum(a, b):
    x = a + b
    bv = x - a
    av = x - bv
    return x, (a - av) + (b - bv)


@njit(cache=True, inline="always")
def _split(a):
    c = _SPLITTER * a
    hi = c - (c - a)
    return hi, a - hi


@njit(cache=True, inline="always")
def _two_product(a, b):
    x = a * b
    ahi, alo = _split(a)
    bhi, blo = _split(b)
    err = x - ahi * bhi
    err -= alo * bhi
    err -= ahi * blo
    return x, alo * blo - err


@njit(cache=True)
def _grow(e, n, b, out):
    """out[:m] = e[:n] + b (Shewchuk's grow_expansion_zeroelim): m. ``e`` nonoverlapping, increasing magnitude."""
    q = b
    m = 0
    for i in range(n):
        q, h = _two_sum(q, e[i])
        if h != 0.0:
            out[m] = h
            m += 1
    if q != 0.0 or m == 0:
        out[m] = q
        m += 1
    return m


@njit(cache=True)
def _add(e, f):
    """The exact sum of expansions e and f, as a new expansion."""
    buf = np.empty(e.shape[0] + f.shape[0] + 1)
    tmp = np.empty(e.shape[0] + f.shape[0] + 1)
    buf[:e.shape[0]] = e
    n = e.shape[0]
    for j in range(f.shape[0]):
        n = _grow(buf, n, f[j], tmp)
        buf, tmp = tmp, buf
    return buf[:n].copy()


@njit(cache=True)
def _scale(e, b):
    """The exact product of expansion e and the float b (Shewchuk's scale_expansion_zeroelim)."""
    out = np.empty(2 * e.shape[0] + 1)
    q, h = _two_product(e[0], b)
    m = 0
    if h != 0.0:
        out[m] = h
        m += 1
    for i in range(1, e.shape[0]):
        p1, p0 = _two_product(e[i], b)
        s, h = _two_sum(q, p0)
        if h != 0.0:
            out[m] = h
            m += 1
        q = p1 + s  # fast two-sum: |p1| >= |s|
        h = s - (q - p1)
        if h != 0.0:
            out[m] = h
            m += 1
    if q != 0.0 or m == 0:
        out[m] = q
        m += 1
    return out[:m].copy()


@njit(cache=True)
def _mul(e, f):
    """The exact product of expansions e and f."""
    out = _scale(e, f[0])
    for j in range(1, f.shape[0]):
        out = _add(out, _scale(e, f[j]))
    return out


@njit(cache=True)
def _diff(a, b):
    """a - b as an exact expansion of two floats."""
    x, y = _two_sum(a, -b)
    out = np.empty(2)
    out[0] = y
    out[1] = x
    return out


@njit(cache=True)
def _sign(e):
    """Sign of a nonoverlapping expansion (its largest component is its last nonzero one)."""
    for i in range(e.shape[0] - 1, -1, -1):
        if e[i] > 0.0:
            return 1
        if e[i] < 0.0:
            return -1
    return 0


@njit(cache=True)
def _orient3d_exact(a, b, c, d):
    """Exact sign of det[b - a, c - a, d - a]."""
    bx, by, bz = _diff(b[0], a[0]), _diff(b[1], a[1]), _diff(b[2], a[2])
    cx, cy, cz = _diff(c[0], a[0]), _diff(c[1], a[1]), _diff(c[2], a[2])
    dx, dy, dz = _diff(d[0], a[0]), _diff(d[1], a[1]), _diff(d[2], a[2])
    m1 = _add(_mul(cy, dz), -_mul(cz, dy))
    m2 = _add(_mul(cz, dx), -_mul(cx, dz))
    m3 = _add(_mul(cx, dy), -_mul(cy, dx))
    return _sign(_add(_add(_mul(bx, m1), _mul(by, m2)), _mul(bz, m3)))


@njit(cache=True)
def _orient2d_exact(ax, ay, bx, by, cx, cy):
    """Exact sign of det[b - a, c - a] in the plane."""
    ux, uy = _diff(bx, ax), _diff(by, ay)
    vx, vy = _diff(cx, ax), _diff(cy, ay)
    return _sign(_add(_mul(ux, vy), -_mul(uy, vx)))


# ----------------------------------------------------------------------------------------------- filtered signs
@njit(cache=True)
def orient3d(a, b, c, d):
    """Exact sign (-1, 0, 1) of ``det[b - a, c - a, d - a]`` for 3-tuples a, b, c, d: > 0 when d lies on the side
    ``(b - a) x (c - a)`` points to. A float evaluation with Shewchuk's error bound, exact expansions when it is
    not conclusive."""
    # Shewchuk's orient3d(a, b, c, d) is det[a - d, b - d, c - d] = -det[b - a, c - a, d - a]: evaluate that one
    # (its error bound is stated for this form) and negate.
    adx = a[0] - d[0]
    bdx = b[0] - d[0]
    cdx = c[0] - d[0]
    ady = a[1] - d[1]
    bdy = b[1] - d[1]
    cdy = c[1] - d[1]
    adz = a[2] - d[2]
    bdz = b[2] - d[2]
    cdz = c[2] - d[2]
    bdxcdy = bdx * cdy
    cdxbdy = cdx * bdy
    cdxady = cdx * ady
    adxcdy = adx * cdy
    adxbdy = adx * bdy
    bdxady = bdx * ady
    det = adz * (bdxcdy - cdxbdy) + bdz * (cdxady - adxcdy) + cdz * (adxbdy - bdxady)
    perm = ((abs(bdxcdy) + abs(cdxbdy)) * abs(adz) + (abs(cdxady) + abs(adxcdy)) * abs(bdz)
            + (abs(adxbdy) + abs(bdxady)) * abs(cdz))
    bound = _O3D_BOUND * perm
    if det > bound:
        return -1
    if -det > bound:
        return 1
    if perm == 0.0:
        # every product is 0, so every term has an exactly zero factor (a float difference is 0 only for equal
        # floats): the determinant is exactly 0. The common case of a corner shared by the two triangles.
        return 0
    return _orient3d_exact(a, b, c, d)


@njit(cache=True)
def orient2d(ax, ay, bx, by, cx, cy):
    """Exact sign (-1, 0, 1) of ``det[b - a, c - a]``: > 0 when (a, b, c) turn counterclockwise."""
    left = (ax - cx) * (by - cy)
    right = (ay - cy) * (bx - cx)
    det = left - right
    if left > 0.0:
        if right <= 0.0:
            return 1 if det > 0.0 else (-1 if det < 0.0 else 0)
        total = left + right
    elif left < 0.0:
        if right >= 0.0:
            return 1 if det > 0.0 else (-1 if det < 0.0 else 0)
        total = -left - right
    else:
        return 1 if det > 0.0 else (-1 if det < 0.0 else 0)
    bound = _O2D_BOUND * total
    if det > bound:
        return 1
    if -det > bound:
        return -1
    return _orient2d_exact(ax, ay, bx, by, cx, cy)


# ------------------------------------------------------------------------------------------ triangle-triangle test
@njit(cache=True, inline="always")
def _apex(s0, s1, s2):
    """Index of a corner with a nonzero sign whose two other corners lie on the opposite closed side (-1: none;
    there is one whenever the signs hold both a +1 and a -1)."""
    if s0 != 0 and s1 * s0 <= 0 and s2 * s0 <= 0:
        return 0
    if s1 != 0 and s0 * s1 <= 0 and s2 * s1 <= 0:
        return 1
    if s2 != 0 and s0 * s2 <= 0 and s1 * s2 <= 0:
        return 2
    return -1


@njit(cache=True, inline="always")
def _rotate(p0, p1, p2, k):
    """Corners (p0, p1, p2) cyclically rotated to start at corner k (orientation kept)."""
    if k == 1:
        return p1, p2, p0
    if k == 2:
        return p2, p0, p1
    return p0, p1, p2


@njit(cache=True, inline="always")
def _has_both(s0, s1, s2):
    return (s0 > 0 or s1 > 0 or s2 > 0) and (s0 < 0 or s1 < 0 or s2 < 0)


@njit(cache=True)
def _drop_axis(p0, p1, p2):
    """A coordinate axis (0, 1, 2) whose dropping keeps triangle (p0, p1, p2) non-degenerate in the plane and the
    triangle's orientation there (+1 / -1); (-1, 0) if the triangle is degenerate (collinear corners)."""
    nx = abs((p1[1] - p0[1]) * (p2[2] - p0[2]) - (p1[2] - p0[2]) * (p2[1] - p0[1]))
    ny = abs((p1[2] - p0[2]) * (p2[0] - p0[0]) - (p1[0] - p0[0]) * (p2[2] - p0[2]))
    nz = abs((p1[0] - p0[0]) * (p2[1] - p0[1]) - (p1[1] - p0[1]) * (p2[0] - p0[0]))
    first = 0 if (nx >= ny and nx >= nz) else (1 if ny >= nz else 2)  # the normal's largest component (float)
    for t in range(3):
        k = (first + t) % 3
        i = 1 if k == 0 else 0
        j = 1 if k == 2 else 2
        o = orient2d(p0[i], p0[j], p1[i], p1[j], p2[i], p2[j])
        if o != 0:
            return k, o
    return -1, 0


@njit(cache=True)
def _separates_2d(a, b, i, j, o, q0, q1, q2):
    """Does the edge line a -> b of a triangle of orientation o (in the plane of axes i, j) leave all of q0, q1, q2
    on its closed outer side?"""
    return (o * orient2d(a[i], a[j], b[i], b[j], q0[i], q0[j]) <= 0
            and o * orient2d(a[i], a[j], b[i], b[j], q1[i], q1[j]) <= 0
            and o * orient2d(a[i], a[j], b[i], b[j], q2[i], q2[j]) <= 0)


@njit(cache=True)
def coplanar_interiors_overlap(p0, p1, p2, q0, q1, q2):
    """For two triangles in one plane: do their interiors overlap (an overlap of positive area)? Exact.

    The interiors of two convex polygons are disjoint iff a line along an edge of one leaves the other on its
    closed outer side (the separating-axis theorem for the polygons' Minkowski difference); projected on a
    coordinate plane where both stay non-degenerate (dropping a coordinate is exact). A degenerate triangle has
    no interior: False."""
    k, op = _drop_axis(p0, p1, p2)
    if k < 0:
        return False
    i = 1 if k == 0 else 0
    j = 1 if k == 2 else 2
    oq = orient2d(q0[i], q0[j], q1[i], q1[j], q2[i], q2[j])
    if oq == 0:
        return False
    if (_separates_2d(p0, p1, i, j, op, q0, q1, q2) or _separates_2d(p1, p2, i, j, op, q0, q1, q2)
            or _separates_2d(p2, p0, i, j, op, q0, q1, q2)):
        return False
    return not (_separates_2d(q0, q1, i, j, oq, p0, p1, p2) or _separates_2d(q1, q2, i, j, oq, p0, p1, p2)
                or _separates_2d(q2, q0, i, j, oq, p0, p1, p2))


@njit(cache=True)
def triangles_intersect(p0, p1, p2, q0, q1, q2):
    """Do the relative interiors of triangles P = (p0, p1, p2) and Q = (q0, q1, q2) intersect? Exact.

    Returns :data:`NO_CONTACT` (0) when they do not: apart, or touching only (a corner on the other triangle, an
    edge along it, coplanar triangles meeting along an edge); :data:`CROSSING` (1) when they cross (a segment of
    each triangle's interior in the other's); :data:`COPLANAR_OVERLAP` (2) for triangles in one plane whose
    interiors overlap with positive area. Triangles may share corners (a shared corner is not in either
    interior, so two triangles sharing one vertex intersect only when they meet away from it). A triangle with
    collinear corners has no interior and never intersects.

    Non-coplanar case (Guigue and Devillers 2003, strict form): each triangle must have corners strictly on both
    sides of the other's plane (else its interior misses that plane); then both interiors meet the planes' common
    line L in open segments, and, after rotating each triangle to start at its lone corner and orienting both so
    that the lone corners lie on the positive sides, the open segments overlap iff
    ``orient3d(p0, p1, q0, q1) < 0 < orient3d(p0, p2, q0, q2)`` (the order of the segments' ends along L).
    """
    s0 = orient3d(p0, p1, p2, q0)
    s1 = orient3d(p0, p1, p2, q1)
    s2 = orient3d(p0, p1, p2, q2)
    if (s0 > 0 and s1 > 0 and s2 > 0) or (s0 < 0 and s1 < 0 and s2 < 0):
        return NO_CONTACT
    if s0 == 0 and s1 == 0 and s2 == 0:  # Q in P's plane, or P degenerate
        return COPLANAR_OVERLAP if coplanar_interiors_overlap(p0, p1, p2, q0, q1, q2) else NO_CONTACT
    if not _has_both(s0, s1, s2):
        return NO_CONTACT  # Q touches P's plane with a corner or an edge only
    t0 = orient3d(q0, q1, q2, p0)
    t1 = orient3d(q0, q1, q2, p1)
    t2 = orient3d(q0, q1, q2, p2)
    if not _has_both(t0, t1, t2):
        return NO_CONTACT  # includes a degenerate Q (all zero)
    ip = _apex(t0, t1, t2)
    iq = _apex(s0, s1, s2)
    tp = t0 if ip == 0 else (t1 if ip == 1 else t2)
    sq = s0 if iq == 0 else (s1 if iq == 1 else s2)
    a0, a1, a2 = _rotate(p0, p1, p2, ip)
    b0, b1, b2 = _rotate(q0, q1, q2, iq)
    if tp < 0:  # flip Q's orientation: P's lone corner on Q's positive side
        b1, b2 = b2, b1
    if sq < 0:  # flip P's orientation: Q's lone corner on P's positive side
        a1, a2 = a2, a1
    if orient3d(a0, a1, b0, b1) < 0 and orient3d(a0, a2, b0, b2) > 0:
        return CROSSING
    return NO_CONTACT
