"""Warp device functions of :class:`~neuralcol.collision.warp_labeler.WarpLabeler`: float64 ports of the numba
kernels (:mod:`neuralcol.collision.kernels`) with the same operations in the same order, so on the same device
kind the values agree to round-off. No FMA contraction (``fuse_fp`` off), here and in
:mod:`neuralcol.collision.warp_kernels`, which compiles these functions into its kernels."""

from __future__ import annotations

import warp as wp

wp.set_module_options({"fuse_fp": False, "enable_backward": False})


# ----------------------------------------------------------------------------------------- vectors
@wp.func
def _sub(a: wp.vec3d, b: wp.vec3d) -> wp.vec3d:
    return wp.vec3d(a[0] - b[0], a[1] - b[1], a[2] - b[2])


@wp.func
def _add(a: wp.vec3d, b: wp.vec3d) -> wp.vec3d:
    return wp.vec3d(a[0] + b[0], a[1] + b[1], a[2] + b[2])


@wp.func
def _scale(a: wp.vec3d, s: wp.float64) -> wp.vec3d:
    return wp.vec3d(a[0] * s, a[1] * s, a[2] * s)


@wp.func
def _dot(a: wp.vec3d, b: wp.vec3d) -> wp.float64:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@wp.func
def _cross(a: wp.vec3d, b: wp.vec3d) -> wp.vec3d:
    return wp.vec3d(a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@wp.func
def min3(a: wp.float64, b: wp.float64, c: wp.float64) -> wp.float64:
    return wp.min(wp.min(a, b), c)


@wp.func
def max3(a: wp.float64, b: wp.float64, c: wp.float64) -> wp.float64:
    return wp.max(wp.max(a, b), c)


# ----------------------------------------------------------------------------------------- SAT depth
@wp.func
def _sat_axis(axis: wp.vec3d, p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, q0: wp.vec3d, q1: wp.vec3d,
              q2: wp.vec3d, best: wp.float64) -> wp.float64:
    ll = _dot(axis, axis)
    if ll <= wp.float64(0.0):
        return best
    inv = wp.float64(1.0) / wp.sqrt(ll)
    a0 = _dot(axis, p0) * inv
    a1 = _dot(axis, p1) * inv
    a2 = _dot(axis, p2) * inv
    b0 = _dot(axis, q0) * inv
    b1 = _dot(axis, q1) * inv
    b2 = _dot(axis, q2) * inv
    ov = wp.min(max3(a0, a1, a2) - min3(b0, b1, b2), max3(b0, b1, b2) - min3(a0, a1, a2))
    return wp.min(best, ov)


@wp.func
def _sat_cross(u: wp.vec3d, w: wp.vec3d, tiny: wp.float64, p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d,
               q0: wp.vec3d, q1: wp.vec3d, q2: wp.vec3d, best: wp.float64) -> wp.float64:
    ax = _cross(u, w)
    if _dot(ax, ax) > tiny:
        return _sat_axis(ax, p0, p1, p2, q0, q1, q2, best)
    return best


@wp.func
def pair_depth(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, q0: wp.vec3d, q1: wp.vec3d, q2: wp.vec3d,
               tiny: wp.float64) -> wp.float64:
    """kernels.depth.triangle_pair_depth (``tiny = 1e-24 * scale**4``)."""
    e0 = _sub(p1, p0)
    e1 = _sub(p2, p1)
    e2 = _sub(p0, p2)
    f0 = _sub(q1, q0)
    f1 = _sub(q2, q1)
    f2 = _sub(q0, q2)
    n = _cross(e0, _sub(p2, p0))
    m = _cross(f0, _sub(q2, q0))
    best = wp.float64(wp.inf)
    best = _sat_axis(n, p0, p1, p2, q0, q1, q2, best)
    best = _sat_axis(m, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(e0, f0, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(e0, f1, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(e0, f2, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(e1, f0, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(e1, f1, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(e1, f2, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(e2, f0, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(e2, f1, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(e2, f2, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(n, e0, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(n, e1, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(n, e2, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(m, f0, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(m, f1, tiny, p0, p1, p2, q0, q1, q2, best)
    best = _sat_cross(m, f2, tiny, p0, p1, p2, q0, q1, q2, best)
    return best


@wp.func
def _beyond_plane(a0: wp.vec3d, a1: wp.vec3d, a2: wp.vec3d, b0: wp.vec3d, b1: wp.vec3d, b2: wp.vec3d,
                  margin: wp.float64) -> bool:
    n = _cross(_sub(a1, a0), _sub(a2, a0))
    ln = wp.sqrt(_dot(n, n))
    if ln <= wp.float64(0.0):
        return False
    off = _dot(n, a0)
    s0 = _dot(n, b0) - off
    s1 = _dot(n, b1) - off
    s2 = _dot(n, b2) - off
    m = margin * ln
    if s0 > m and s1 > m and s2 > m:
        return True
    if s0 < -m and s1 < -m and s2 < -m:
        return True
    return False


@wp.func
def plane_separated(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, q0: wp.vec3d, q1: wp.vec3d, q2: wp.vec3d,
                    margin: wp.float64) -> bool:
    """kernels.depth.plane_separated."""
    if _beyond_plane(p0, p1, p2, q0, q1, q2, margin):
        return True
    return _beyond_plane(q0, q1, q2, p0, p1, p2, margin)


@wp.func
def _orient(a: wp.vec3d, b: wp.vec3d, c: wp.vec3d, d: wp.vec3d) -> wp.float64:
    return _dot(_cross(_sub(b, a), _sub(c, a)), _sub(d, a))


@wp.func
def _segment_crosses(p: wp.vec3d, q: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d) -> wp.float64:
    """kernels.depth.segment_crosses_triangle."""
    zero = wp.float64(0.0)
    dp = _orient(a, b, c, p)
    dq = _orient(a, b, c, q)
    if dp * dq >= zero:
        return zero
    s0 = _orient(p, q, a, b)
    s1 = _orient(p, q, b, c)
    s2 = _orient(p, q, c, a)
    if s0 >= zero and s1 >= zero and s2 >= zero:
        return dp
    if s0 <= zero and s1 <= zero and s2 <= zero:
        return dp
    return zero


# ----------------------------------------------------------------------------------------- distances
@wp.func
def _dist(p: wp.vec3d, x: wp.vec3d) -> wp.float64:
    d = _sub(p, x)
    return wp.sqrt(_dot(d, d))


@wp.func
def _point_triangle_distance(p: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d) -> wp.float64:
    """kernels.distance.point_triangle_distance (Ericson 5.1.5)."""
    zero = wp.float64(0.0)
    ab = _sub(b, a)
    ac = _sub(c, a)
    ap = _sub(p, a)
    d1 = _dot(ab, ap)
    d2 = _dot(ac, ap)
    if d1 <= zero and d2 <= zero:
        return _dist(p, a)
    bp = _sub(p, b)
    d3 = _dot(ab, bp)
    d4 = _dot(ac, bp)
    if d3 >= zero and d4 <= d3:
        return _dist(p, b)
    vc = d1 * d4 - d3 * d2
    if vc <= zero and d1 >= zero and d3 <= zero:
        return _dist(p, _add(a, _scale(ab, d1 / (d1 - d3))))
    cp = _sub(p, c)
    d5 = _dot(ab, cp)
    d6 = _dot(ac, cp)
    if d6 >= zero and d5 <= d6:
        return _dist(p, c)
    vb = d5 * d2 - d1 * d6
    if vb <= zero and d2 >= zero and d6 <= zero:
        return _dist(p, _add(a, _scale(ac, d2 / (d2 - d6))))
    va = d3 * d6 - d5 * d4
    if va <= zero and (d4 - d3) >= zero and (d5 - d6) >= zero:
        return _dist(p, _add(b, _scale(_sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6)))))
    denom = wp.float64(1.0) / (va + vb + vc)
    return _dist(p, _add(a, _add(_scale(ab, vb * denom), _scale(ac, vc * denom))))


@wp.func
def _clamp01(x: wp.float64) -> wp.float64:
    return wp.min(wp.max(x, wp.float64(0.0)), wp.float64(1.0))


@wp.func
def _seg_points_dist(p1: wp.vec3d, d1: wp.vec3d, s: wp.float64, p2: wp.vec3d, d2: wp.vec3d,
                     t: wp.float64) -> wp.float64:
    diff = _sub(_add(p1, _scale(d1, s)), _add(p2, _scale(d2, t)))
    return wp.sqrt(_dot(diff, diff))


@wp.func
def _segment_segment_distance(p1: wp.vec3d, q1: wp.vec3d, p2: wp.vec3d, q2: wp.vec3d) -> wp.float64:
    """kernels.distance.segment_segment_distance (Ericson 5.1.9)."""
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    small = wp.float64(1e-300)
    d1 = _sub(q1, p1)
    d2 = _sub(q2, p2)
    r = _sub(p1, p2)
    a = _dot(d1, d1)
    e = _dot(d2, d2)
    f = _dot(d2, r)
    if a <= small and e <= small:
        return wp.sqrt(_dot(r, r))
    if a <= small:
        return _seg_points_dist(p1, d1, zero, p2, d2, _clamp01(f / e))
    c = _dot(d1, r)
    if e <= small:
        return _seg_points_dist(p1, d1, _clamp01(-c / a), p2, d2, zero)
    b = _dot(d1, d2)
    denom = a * e - b * b
    s = zero
    if denom > zero:
        s = _clamp01((b * f - c * e) / denom)
    t = (b * s + f) / e
    if t < zero:
        t = zero
        s = _clamp01(-c / a)
    elif t > one:
        t = one
        s = _clamp01((b - c) / a)
    return _seg_points_dist(p1, d1, s, p2, d2, t)


@wp.func
def triangle_distance(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, q0: wp.vec3d, q1: wp.vec3d,
                      q2: wp.vec3d) -> wp.float64:
    """kernels.distance.triangle_distance (triangles that do not intersect)."""
    d = _point_triangle_distance(p0, q0, q1, q2)
    d = wp.min(d, _point_triangle_distance(p1, q0, q1, q2))
    d = wp.min(d, _point_triangle_distance(p2, q0, q1, q2))
    d = wp.min(d, _point_triangle_distance(q0, p0, p1, p2))
    d = wp.min(d, _point_triangle_distance(q1, p0, p1, p2))
    d = wp.min(d, _point_triangle_distance(q2, p0, p1, p2))
    d = wp.min(d, _segment_segment_distance(p0, p1, q0, q1))
    d = wp.min(d, _segment_segment_distance(p0, p1, q1, q2))
    d = wp.min(d, _segment_segment_distance(p0, p1, q2, q0))
    d = wp.min(d, _segment_segment_distance(p1, p2, q0, q1))
    d = wp.min(d, _segment_segment_distance(p1, p2, q1, q2))
    d = wp.min(d, _segment_segment_distance(p1, p2, q2, q0))
    d = wp.min(d, _segment_segment_distance(p2, p0, q0, q1))
    d = wp.min(d, _segment_segment_distance(p2, p0, q1, q2))
    d = wp.min(d, _segment_segment_distance(p2, p0, q2, q0))
    return d


@wp.func
def _unit(a: wp.vec3d) -> wp.vec3d:
    n = wp.sqrt(_dot(a, a))
    if n <= wp.float64(0.0):
        return wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    return _scale(a, wp.float64(1.0) / n)


@wp.func
def _point_arc_chord(x: wp.vec3d, v1: wp.vec3d, v2: wp.vec3d) -> wp.float64:
    """kernels.distance._point_arc_chord."""
    zero = wp.float64(0.0)
    n = _unit(_cross(v1, v2))
    xp = _sub(x, _scale(n, _dot(x, n)))
    lxp = wp.sqrt(_dot(xp, xp))
    if lxp > zero and _dot(_cross(v1, xp), n) >= zero and _dot(_cross(xp, v2), n) >= zero:
        return wp.sqrt(wp.max(zero, wp.float64(2.0) - wp.float64(2.0) * lxp))
    e1 = _sub(x, v1)
    e2 = _sub(x, v2)
    return wp.sqrt(wp.min(_dot(e1, e1), _dot(e2, e2)))


@wp.func
def _wedge_gap(p: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d, d: wp.vec3d) -> wp.float64:
    """kernels.distance.wedge_gap."""
    zero = wp.float64(0.0)
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
    coplanar = _dot(x, x) <= wp.float64(1e-20) * _dot(nu, nu) * _dot(nv, nv)
    if (not coplanar) and s1 * s2 <= zero and t1 * t2 <= zero:
        mu = _add(u1, u2)
        mv = _add(v1, v2)
        xm = _dot(x, mu)
        xv = _dot(x, mv)
        if (xm >= zero and xv >= zero) or (xm <= zero and xv <= zero):
            return zero
    g = _point_arc_chord(u1, v1, v2)
    g = wp.min(g, _point_arc_chord(u2, v1, v2))
    g = wp.min(g, _point_arc_chord(v1, u1, u2))
    g = wp.min(g, _point_arc_chord(v2, u1, u2))
    return g


# ----------------------------------------------------------------------------------------- pair terms
@wp.func
def shared_count(fa: wp.vec3i, fb: wp.vec3i) -> int:
    s = wp.int32(0)
    for i in range(3):
        for j in range(3):
            if fa[i] == fb[j]:
                s += 1
    return s


@wp.func
def _shared_corner(fa: wp.vec3i, fb: wp.vec3i) -> wp.vec2i:
    """(i, j) of the first shared vertex ``fa[i] == fb[j]`` in the order of the kernels' double loop."""
    for i in range(3):
        for j in range(3):
            if fa[i] == fb[j]:
                return wp.vec2i(i, j)
    return wp.vec2i(-1, -1)


@wp.func
def opposite_edges_cross(verts: wp.array2d(dtype=wp.vec3d), pose: int, fa: wp.vec3i, fb: wp.vec3i) -> bool:
    """kernels.depth.opposite_edges_cross (triangles sharing exactly one vertex)."""
    ij = _shared_corner(fa, fb)
    i = ij[0]
    j = ij[1]
    if i < 0:
        return False
    pa = verts[pose, fa[(i + 1) % 3]]
    pb = verts[pose, fa[(i + 2) % 3]]
    qa = verts[pose, fb[(j + 1) % 3]]
    qb = verts[pose, fb[(j + 2) % 3]]
    p = verts[pose, fa[i]]
    if _segment_crosses(pa, pb, p, qa, qb) != wp.float64(0.0):
        return True
    return _segment_crosses(qa, qb, p, pa, pb) != wp.float64(0.0)


@wp.func
def corner_angle(verts: wp.array2d(dtype=wp.vec3d), pose: int, fa: wp.vec3i, fb: wp.vec3i) -> wp.float64:
    """kernels.distance.corner_angle."""
    ij = _shared_corner(fa, fb)
    i = ij[0]
    j = ij[1]
    if i < 0:
        return wp.float64(0.0)
    return _wedge_gap(verts[pose, fa[i]], verts[pose, fa[(i + 1) % 3]], verts[pose, fa[(i + 2) % 3]],
                      verts[pose, fb[(j + 1) % 3]], verts[pose, fb[(j + 2) % 3]])


@wp.func
def box_gap(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, q0: wp.vec3d, q1: wp.vec3d, q2: wp.vec3d) -> wp.float64:
    g2 = wp.float64(0.0)
    for d in range(3):
        gap = wp.max(wp.max(min3(q0[d], q1[d], q2[d]) - max3(p0[d], p1[d], p2[d]),
                            min3(p0[d], p1[d], p2[d]) - max3(q0[d], q1[d], q2[d])), wp.float64(0.0))
        g2 += gap * gap
    return wp.sqrt(g2)


@wp.func
def boxes_overlap(lo: wp.array2d(dtype=wp.vec3d), hi: wp.array2d(dtype=wp.vec3d), pose: int, a: int,
                  b: int) -> bool:
    """kernels.broadphase.boxes_overlap (the same comparisons)."""
    la = lo[pose, a]
    ha = hi[pose, a]
    lb = lo[pose, b]
    hb = hi[pose, b]
    for d in range(3):
        if la[d] > hb[d] or lb[d] > ha[d]:
            return False
    return True


@wp.func
def near_index(near_ptr: wp.array(dtype=wp.int32), near_b: wp.array(dtype=wp.int32), a: int, b: int) -> int:
    lo = near_ptr[a]
    end = near_ptr[a + 1]
    hi = end
    while lo < hi:
        mid = (lo + hi) >> 1
        if near_b[mid] < b:
            lo = mid + 1
        else:
            hi = mid
    if lo < end:
        if near_b[lo] == b:
            return lo
    return -1


@wp.func
def record(pose: int, a: int, b: int, depth: wp.float64, c: wp.float64, counted: bool, fa: wp.vec3i,
           fb: wp.vec3i, part: wp.array(dtype=wp.int32), tau: wp.float64, cap: wp.float64,
           clear: wp.array2d(dtype=wp.float64), floor: wp.array2d(dtype=wp.float64),
           n_pairs: wp.array(dtype=wp.int32), out_pairs: wp.array2d(dtype=wp.int32),
           out_count: wp.array(dtype=wp.int32)):
    """Lower the clearance of the pair's parts by c; for a counted pair raise their floor and list it."""
    if c < cap:  # a term >= cap cannot change -min(cap, clearance)
        for i in range(3):
            wp.atomic_min(clear, pose, part[fa[i]], c)
            wp.atomic_min(clear, pose, part[fb[i]], c)
    if counted:
        wp.atomic_add(n_pairs, pose, 1)
        for i in range(3):
            wp.atomic_max(floor, pose, part[fa[i]], depth - tau)
            wp.atomic_max(floor, pose, part[fb[i]], depth - tau)
        slot = wp.atomic_add(out_count, 0, 1)
        if slot < out_pairs.shape[0]:
            out_pairs[slot, 0] = pose
            out_pairs[slot, 1] = a
            out_pairs[slot, 2] = b
