"""Batched exact labeler in NVIDIA Warp: the labels of :class:`~neuralcol.collision.labeler.ExactLabeler` for a
batch of B poses of one topology (``labeling.backend = gpu``).

The definitions are those of :mod:`neuralcol.collision.labeler` (same verdict, pair count, PD and PD_i); the
pair formulas are ports of :mod:`neuralcol.collision.kernels` with the same float64 operations in the same
order (and no FMA contraction: ``fuse_fp`` is off for this module), so on the same device kind the values agree
to round-off (tests: ``tests/test_gpu_labeler.py``).

Where each stage runs (B poses, F triangles, N = rows of the rest near table):

1. **Device** (Warp kernels, dim B x F): every triangle's box, exact and grown by ``cap / 2`` (float64), plus a
   float32 copy rounded outwards for the broadphase.
2. **Device**, near pairs (dim B x N): the pairs of the fixed rest near table (``ExactLabeler._near_*``, built
   once) whose grown boxes overlap: SAT depth, one-vertex fold test, clearance term ``cap * m / m_rest`` or
   the corner gap (``_pair_terms``).
3. **Device**, far pairs (dim B x F): a grouped ``wp.Bvh`` (one group per pose slot, its tree built once per
   batch size from the rest boxes and refitted to every batch) finds every non-adjacent pair whose grown
   boxes overlap; pairs sharing a vertex or in the near table are left out; SAT depth and Euclidean
   triangle distance (``far_clearances``).
4. **Device**: per pose, counted pairs (``d > tau`` with overlapping exact boxes: ``n_pairs``), the per-part
   floor ``max(d - tau)`` and the per-part clearance ``min c`` (atomics), and the list of counted pairs.
5. **Host** (numba, only for the poses that collide): the penetration depth of the penetrating vertices:
   crossing edges of the counted pairs (``pair_pass`` on the device's pair list), parity of the crossings,
   flood fill of the penetrating regions and vertex depths (``finish_label``). Free poses take
   ``PD_i = -min(cap, clearance_i)`` straight from the device; colliding poses copy only their vertices to
   the host.

The device evaluates every non-adjacent pair within the cap (the reference path of ``ExactLabeler(prune=False)``,
which gives the same labels as the pruned one), apart from far pairs whose box gap alone is already >= cap
(their term is >= cap, so they cannot change ``-min(cap, clearance)``).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from neuralcol.collision.kernels import finish_label, pair_pass
from neuralcol.collision.labeler import ExactLabeler, Label, Labels, split_subsets

wp.set_module_options({"fuse_fp": False, "enable_backward": False})

_EPS_AXIS = 1e-24  # as kernels._EPS_AXIS
_MAX_TRI_POSES = 1 << 22  # triangle x pose slots per launch (about 200 bytes each on the device)
_F32_REL = wp.constant(1e-6)  # outward rounding of the float32 broadphase boxes (float32 rounds within 6e-8 relative)


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
def _min3(a: wp.float64, b: wp.float64, c: wp.float64) -> wp.float64:
    return wp.min(wp.min(a, b), c)


@wp.func
def _max3(a: wp.float64, b: wp.float64, c: wp.float64) -> wp.float64:
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
    ov = wp.min(_max3(a0, a1, a2) - _min3(b0, b1, b2), _max3(b0, b1, b2) - _min3(a0, a1, a2))
    return wp.min(best, ov)


@wp.func
def _sat_cross(u: wp.vec3d, w: wp.vec3d, tiny: wp.float64, p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d,
               q0: wp.vec3d, q1: wp.vec3d, q2: wp.vec3d, best: wp.float64) -> wp.float64:
    ax = _cross(u, w)
    if _dot(ax, ax) > tiny:
        return _sat_axis(ax, p0, p1, p2, q0, q1, q2, best)
    return best


@wp.func
def _pair_depth(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, q0: wp.vec3d, q1: wp.vec3d, q2: wp.vec3d,
                tiny: wp.float64) -> wp.float64:
    """kernels.triangle_pair_depth (``tiny = 1e-24 * scale**4``)."""
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
def _plane_separated(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, q0: wp.vec3d, q1: wp.vec3d, q2: wp.vec3d,
                     margin: wp.float64) -> bool:
    """kernels.plane_separated."""
    if _beyond_plane(p0, p1, p2, q0, q1, q2, margin):
        return True
    return _beyond_plane(q0, q1, q2, p0, p1, p2, margin)


@wp.func
def _orient(a: wp.vec3d, b: wp.vec3d, c: wp.vec3d, d: wp.vec3d) -> wp.float64:
    return _dot(_cross(_sub(b, a), _sub(c, a)), _sub(d, a))


@wp.func
def _segment_crosses(p: wp.vec3d, q: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d) -> wp.float64:
    """kernels.segment_crosses_triangle."""
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
    """kernels.point_triangle_distance (Ericson 5.1.5)."""
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
    """kernels.segment_segment_distance (Ericson 5.1.9)."""
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
def _triangle_distance(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, q0: wp.vec3d, q1: wp.vec3d,
                       q2: wp.vec3d) -> wp.float64:
    """kernels.triangle_distance (triangles that do not intersect)."""
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
    """kernels._point_arc_chord."""
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
    """kernels.wedge_gap."""
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
def _shared_count(fa: wp.vec3i, fb: wp.vec3i) -> int:
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
def _opposite_edges_cross(verts: wp.array2d(dtype=wp.vec3d), pose: int, fa: wp.vec3i, fb: wp.vec3i) -> bool:
    """kernels.opposite_edges_cross (triangles sharing exactly one vertex)."""
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
def _corner_angle(verts: wp.array2d(dtype=wp.vec3d), pose: int, fa: wp.vec3i, fb: wp.vec3i) -> wp.float64:
    """kernels._corner_angle."""
    ij = _shared_corner(fa, fb)
    i = ij[0]
    j = ij[1]
    if i < 0:
        return wp.float64(0.0)
    return _wedge_gap(verts[pose, fa[i]], verts[pose, fa[(i + 1) % 3]], verts[pose, fa[(i + 2) % 3]],
                      verts[pose, fb[(j + 1) % 3]], verts[pose, fb[(j + 2) % 3]])


@wp.func
def _box_gap(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, q0: wp.vec3d, q1: wp.vec3d, q2: wp.vec3d) -> wp.float64:
    g2 = wp.float64(0.0)
    for d in range(3):
        gap = wp.max(wp.max(_min3(q0[d], q1[d], q2[d]) - _max3(p0[d], p1[d], p2[d]),
                            _min3(p0[d], p1[d], p2[d]) - _max3(q0[d], q1[d], q2[d])), wp.float64(0.0))
        g2 += gap * gap
    return wp.sqrt(g2)


@wp.func
def _boxes_overlap(lo: wp.array2d(dtype=wp.vec3d), hi: wp.array2d(dtype=wp.vec3d), pose: int, a: int,
                   b: int) -> bool:
    """kernels._boxes_overlap (the same comparisons)."""
    la = lo[pose, a]
    ha = hi[pose, a]
    lb = lo[pose, b]
    hb = hi[pose, b]
    for d in range(3):
        if la[d] > hb[d] or lb[d] > ha[d]:
            return False
    return True


@wp.func
def _near_index(near_ptr: wp.array(dtype=wp.int32), near_b: wp.array(dtype=wp.int32), a: int, b: int) -> int:
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
def _record(pose: int, a: int, b: int, depth: wp.float64, c: wp.float64, counted: bool, fa: wp.vec3i,
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


# ----------------------------------------------------------------------------------------- kernels
@wp.kernel
def _boxes_kernel(verts: wp.array2d(dtype=wp.vec3d), faces: wp.array(dtype=wp.vec3i), half_cap: wp.float64,
                  pad: wp.float64, lo0: wp.array2d(dtype=wp.vec3d), hi0: wp.array2d(dtype=wp.vec3d),
                  lo_cap: wp.array2d(dtype=wp.vec3d), hi_cap: wp.array2d(dtype=wp.vec3d),
                  lo32: wp.array(dtype=wp.vec3), hi32: wp.array(dtype=wp.vec3)):
    """Exact boxes, boxes grown by cap / 2 (kernels.triangle_aabbs) and their float32 copy rounded outwards."""
    pose, f = wp.tid()
    fa = faces[f]
    a = verts[pose, fa[0]]
    b = verts[pose, fa[1]]
    c = verts[pose, fa[2]]
    lo = wp.vec3d(_min3(a[0], b[0], c[0]), _min3(a[1], b[1], c[1]), _min3(a[2], b[2], c[2]))
    hi = wp.vec3d(_max3(a[0], b[0], c[0]), _max3(a[1], b[1], c[1]), _max3(a[2], b[2], c[2]))
    lc = wp.vec3d(lo[0] - half_cap, lo[1] - half_cap, lo[2] - half_cap)
    hc = wp.vec3d(hi[0] + half_cap, hi[1] + half_cap, hi[2] + half_cap)
    lo0[pose, f] = lo
    hi0[pose, f] = hi
    lo_cap[pose, f] = lc
    hi_cap[pose, f] = hc
    rel = wp.float64(_F32_REL)
    k = pose * faces.shape[0] + f
    lo32[k] = wp.vec3(wp.float32(lc[0] - (wp.abs(lc[0]) * rel + pad)), wp.float32(lc[1] - (wp.abs(lc[1]) * rel + pad)),
                      wp.float32(lc[2] - (wp.abs(lc[2]) * rel + pad)))
    hi32[k] = wp.vec3(wp.float32(hc[0] + (wp.abs(hc[0]) * rel + pad)), wp.float32(hc[1] + (wp.abs(hc[1]) * rel + pad)),
                      wp.float32(hc[2] + (wp.abs(hc[2]) * rel + pad)))


@wp.kernel
def _near_kernel(verts: wp.array2d(dtype=wp.vec3d), faces: wp.array(dtype=wp.vec3i),
                 part: wp.array(dtype=wp.int32), near_a: wp.array(dtype=wp.int32),
                 near_b: wp.array(dtype=wp.int32), near_rest: wp.array(dtype=wp.float64),
                 near_shared: wp.array(dtype=wp.int32), lo0: wp.array2d(dtype=wp.vec3d),
                 hi0: wp.array2d(dtype=wp.vec3d), lo_cap: wp.array2d(dtype=wp.vec3d),
                 hi_cap: wp.array2d(dtype=wp.vec3d), tiny: wp.float64, tau: wp.float64, cap: wp.float64,
                 clear: wp.array2d(dtype=wp.float64), floor: wp.array2d(dtype=wp.float64),
                 n_pairs: wp.array(dtype=wp.int32), out_pairs: wp.array2d(dtype=wp.int32),
                 out_count: wp.array(dtype=wp.int32)):
    """Near pairs (rows of the rest near table) within cap: kernels._pair_terms with ``idx >= 0``."""
    pose, k = wp.tid()
    a = near_a[k]
    b = near_b[k]
    if not _boxes_overlap(lo_cap, hi_cap, pose, a, b):
        return
    fa = faces[a]
    fb = faces[b]
    p0 = verts[pose, fa[0]]
    p1 = verts[pose, fa[1]]
    p2 = verts[pose, fa[2]]
    q0 = verts[pose, fb[0]]
    q1 = verts[pose, fb[1]]
    q2 = verts[pose, fb[2]]
    shared = near_shared[k]
    zero = wp.float64(0.0)
    depth = wp.float64(-1.0)
    if shared == 1:
        if _opposite_edges_cross(verts, pose, fa, fb):
            depth = _pair_depth(p0, p1, p2, q0, q1, q2, tiny)
    else:
        depth = _pair_depth(p0, p1, p2, q0, q1, q2, tiny)
    c = zero
    if depth <= tau:
        r = near_rest[k]
        if r <= zero:
            c = cap
        elif shared == 1:
            c = cap * _corner_angle(verts, pose, fa, fb) / r
        else:
            c = cap * wp.max(-depth, zero) / r
    counted = depth > tau and _boxes_overlap(lo0, hi0, pose, a, b)
    _record(pose, a, b, depth, c, counted, fa, fb, part, tau, cap, clear, floor, n_pairs, out_pairs, out_count)


@wp.kernel
def _far_kernel(verts: wp.array2d(dtype=wp.vec3d), faces: wp.array(dtype=wp.vec3i),
                part: wp.array(dtype=wp.int32), near_ptr: wp.array(dtype=wp.int32),
                near_b: wp.array(dtype=wp.int32), bvh: wp.uint64, lo32: wp.array(dtype=wp.vec3),
                hi32: wp.array(dtype=wp.vec3), lo0: wp.array2d(dtype=wp.vec3d), hi0: wp.array2d(dtype=wp.vec3d),
                lo_cap: wp.array2d(dtype=wp.vec3d), hi_cap: wp.array2d(dtype=wp.vec3d), tiny: wp.float64,
                tau: wp.float64, cap: wp.float64, clear: wp.array2d(dtype=wp.float64),
                floor: wp.array2d(dtype=wp.float64), n_pairs: wp.array(dtype=wp.int32),
                out_pairs: wp.array2d(dtype=wp.int32), out_count: wp.array(dtype=wp.int32)):
    """Far pairs within cap (grown boxes overlap, no shared vertex, not in the near table): kernels._pair_terms
    with ``idx < 0``. Thread (pose, a) takes the partners b > a its BVH group returns."""
    pose, a = wp.tid()
    n_faces = faces.shape[0]
    base = pose * n_faces
    root = wp.bvh_get_group_root(bvh, pose)
    query = wp.bvh_query_aabb(bvh, lo32[base + a], hi32[base + a], root)
    item = wp.int32(0)
    fa = faces[a]
    zero = wp.float64(0.0)
    while wp.bvh_query_next(query, item):
        b = item - base
        if b <= a or b >= n_faces:
            continue
        if not _boxes_overlap(lo_cap, hi_cap, pose, a, b):
            continue
        fb = faces[b]
        if _shared_count(fa, fb) > 0:
            continue
        if _near_index(near_ptr, near_b, a, b) >= 0:
            continue
        p0 = verts[pose, fa[0]]
        p1 = verts[pose, fa[1]]
        p2 = verts[pose, fa[2]]
        q0 = verts[pose, fb[0]]
        q1 = verts[pose, fb[1]]
        q2 = verts[pose, fb[2]]
        lb = _box_gap(p0, p1, p2, q0, q1, q2)
        if lb > zero and lb >= cap:
            continue  # term = distance >= lb >= cap
        if _plane_separated(p0, p1, p2, q0, q1, q2, cap):
            continue  # apart by more than cap
        depth = wp.float64(-1.0)
        if not _plane_separated(p0, p1, p2, q0, q1, q2, tau):
            depth = _pair_depth(p0, p1, p2, q0, q1, q2, tiny)
        c = zero
        if depth <= tau and depth <= zero:
            c = _triangle_distance(p0, p1, p2, q0, q1, q2)
        counted = depth > tau and _boxes_overlap(lo0, hi0, pose, a, b)
        _record(pose, a, b, depth, c, counted, fa, fb, part, tau, cap, clear, floor, n_pairs, out_pairs,
                out_count)


# ----------------------------------------------------------------------------------------- labeler
def default_device() -> str:
    """``cuda:0`` when Warp sees a CUDA device, else ``cpu``."""
    return "cuda:0" if wp.is_cuda_available() else "cpu"


class BatchedLabeler:
    """Exact labels (those of :class:`~neuralcol.collision.labeler.ExactLabeler`) of batches of poses of one
    topology, with Warp kernels on a CUDA device or on Warp's CPU device (see the module docstring for which
    stage runs where).

    Args:
        faces: (F, 3) int triangles.
        rest_vertices: (V, 3) float rest mesh (sets ell, diag, the near table).
        partition: (V,) int part of each vertex, or None for one part.
        device: Warp device (``"cuda:0"``, ``"cpu"``, ...); None: ``cuda:0`` if available, else ``cpu``.
        touch_tol, clearance_cap, boundary_eps: as for ExactLabeler.
        cell_factor, prune: accepted for ExactLabeler's settings; the device path does not use them (its
            broadphase is a BVH, and it evaluates every pair within cap, which gives the pruned labels).
        max_batch: poses per kernel launch; larger batches are labelled in slices of this size. It is lowered so
            that a launch holds at most 2**22 triangle-poses (about 200 bytes each on the device: 0.8 GB).

    Attributes as ExactLabeler (n_vertices, n_parts, faces, rest, ell, diag, tau, cap, eps, partition, ...),
    plus ``batched = True`` (LabelPool hands it whole chunks) and ``label_kind = "exact"`` (same labels, same
    cache). It pickles: the device arrays are rebuilt lazily in the receiving process (on Warp's CPU device
    if that process has no CUDA device).
    """

    batched = True
    label_kind = "exact"
    _min_pair_list = 1024  # initial room for counted pairs per launch (grown and rerun when it overflows)

    def __init__(self, faces, rest_vertices, partition=None, device: str | None = None, touch_tol: float = 1e-6,
                 clearance_cap: float = 0.01, boundary_eps: float = 2e-3, cell_factor: float = 2.0,
                 prune: bool = True, max_batch: int = 1024):
        del prune  # the device evaluates every pair within cap (the reference); the labels are the same
        self._ref = ExactLabeler(faces, rest_vertices, partition=partition, touch_tol=touch_tol,
                                 clearance_cap=clearance_cap, boundary_eps=boundary_eps, cell_factor=cell_factor)
        ref = self._ref
        self.faces, self.rest, self.n_vertices = ref.faces, ref.rest, ref.n_vertices
        self.edges, self.ell, self.diag = ref.edges, ref.ell, ref.diag
        self.tau, self.cap, self.eps = ref.tau, ref.cap, ref.eps
        self.closed, self.orient = ref.closed, ref.orient
        self.device = str(wp.get_device(device if device is not None else default_device()))
        if int(max_batch) < 1:
            raise ValueError("max_batch must be >= 1")
        # poses per launch: at most max_batch, and at most _MAX_TRI_POSES triangle-poses (device memory, int32)
        self.max_batch = max(1, min(int(max_batch), _MAX_TRI_POSES // max(len(ref.faces), 1)))
        self._tiny = _EPS_AXIS * self.ell**4
        n_faces = len(self.faces)
        self._near_a = np.repeat(np.arange(n_faces), np.diff(ref._near_ptr)).astype(np.int32)
        self._dev = None  # device arrays of the topology (built lazily; not pickled)
        self._bvh = {}  # batch size -> (lo32, hi32, groups, bvh), trees built from the rest boxes
        self.set_partition(partition)

    # ------------------------------------------------------------------ configuration
    def set_partition(self, partition) -> None:
        """Set the vertex partition (V,) int in [0, K) used for PD_i (None: one part)."""
        self._ref.set_partition(partition)
        self.partition = self._ref.partition
        self.n_parts = self._ref.n_parts
        if self._dev is not None:
            self._dev["part"] = wp.array(self.partition.astype(np.int32), dtype=wp.int32, device=self.device)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_dev"] = None
        state["_bvh"] = {}
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        if not wp.get_device(self.device).is_cpu and not wp.is_cuda_available():
            self.device = "cpu"  # unpickled where there is no GPU: label on Warp's CPU device

    def _device_arrays(self) -> dict:
        if self._dev is None:
            ref, d = self._ref, self.device
            self._dev = {
                "faces": wp.array(self.faces.astype(np.int32), dtype=wp.vec3i, device=d),
                "part": wp.array(self.partition.astype(np.int32), dtype=wp.int32, device=d),
                "near_a": wp.array(self._near_a, dtype=wp.int32, device=d),
                "near_b": wp.array(ref._near_b.astype(np.int32), dtype=wp.int32, device=d),
                "near_ptr": wp.array(ref._near_ptr.astype(np.int32), dtype=wp.int32, device=d),
                "near_rest": wp.array(ref._near_rest.astype(np.float64), dtype=wp.float64, device=d),
                "near_shared": wp.array(ref._near_shared.astype(np.int32), dtype=wp.int32, device=d),
            }
        return self._dev

    def _tree(self, n: int):
        """Grouped BVH for ``n`` pose slots (group = slot), built once from the rest boxes, refitted per batch."""
        if n not in self._bvh:
            if len(self._bvh) >= 4:
                self._bvh.pop(next(iter(self._bvh)))
            dev = self._device_arrays()
            n_faces = len(self.faces)
            rest = wp.array(np.broadcast_to(self.rest, (n, self.n_vertices, 3)).copy(), dtype=wp.vec3d,
                            device=self.device)
            shape = (n, n_faces)
            tmp = [wp.empty(shape, dtype=wp.vec3d, device=self.device) for _ in range(4)]
            lo32 = wp.empty(n * n_faces, dtype=wp.vec3, device=self.device)
            hi32 = wp.empty(n * n_faces, dtype=wp.vec3, device=self.device)
            wp.launch(_boxes_kernel, dim=shape, device=self.device,
                      inputs=[rest, dev["faces"], 0.5 * self.cap, 1e-7 * self.cap, *tmp, lo32, hi32])
            groups = wp.array(np.repeat(np.arange(n, dtype=np.int32), n_faces), dtype=wp.int32, device=self.device)
            self._bvh[n] = (lo32, hi32, groups, wp.Bvh(lo32, hi32, groups=groups))
        return self._bvh[n]

    # ------------------------------------------------------------------ input
    def _as_device_batch(self, vertices):
        """(B, V, 3) numpy or torch -> (Warp (B, V) vec3d array on self.device, host accessor of one pose)."""
        n = self.n_vertices
        if hasattr(vertices, "detach"):  # torch tensor
            import torch

            t = vertices.detach()
            if t.ndim != 3 or tuple(t.shape[1:]) != (n, 3):
                raise ValueError(f"vertices have shape {tuple(t.shape)}, expected (B, {n}, 3)")
            if t.dtype.is_complex or not (t.dtype.is_floating_point or t.dtype in (torch.int32, torch.int64)):
                raise ValueError(f"vertices have dtype {t.dtype}, expected real floats")
            dev = wp.get_device(self.device)
            if dev.is_cuda:
                t = t.to(device=wp.device_to_torch(dev), dtype=torch.float64).contiguous()
                if not bool(torch.isfinite(t).all()):
                    raise ValueError("vertices contain NaN or inf; cannot label")
                return wp.from_torch(t, dtype=wp.vec3d), (lambda i: t[i].cpu().numpy())
            vertices = t.cpu().numpy()
        v = np.asarray(vertices)
        if v.ndim != 3 or v.shape[1:] != (n, 3):
            raise ValueError(f"vertices have shape {v.shape}, expected (B, {n}, 3)")
        if not np.issubdtype(v.dtype, np.number) or np.issubdtype(v.dtype, np.complexfloating):
            raise ValueError(f"vertices have dtype {v.dtype}, expected real floats")
        v = np.ascontiguousarray(v, dtype=np.float64)
        if not np.isfinite(v).all():
            raise ValueError("vertices contain NaN or inf; cannot label")
        return wp.array(v, dtype=wp.vec3d, device=self.device), (lambda i: v[i])

    # ------------------------------------------------------------------ labels
    def label_batch(self, vertices) -> Labels:
        """Labels of a batch (B, V, 3) numpy or torch (any device; a CUDA tensor stays on the device)."""
        n_batch = int(vertices.shape[0]) if hasattr(vertices, "shape") else len(vertices)
        if n_batch == 0 or n_batch <= self.max_batch:
            return self._label_slice(vertices)
        parts = [self._label_slice(vertices[i:i + self.max_batch]) for i in range(0, n_batch, self.max_batch)]
        return Labels(*(np.concatenate([getattr(p, k) for p in parts]) for k in Labels._fields))

    def _label_slice(self, vertices) -> Labels:
        verts, host = self._as_device_batch(vertices)
        n_batch = verts.shape[0]
        k_parts = self.n_parts
        if n_batch == 0:
            return Labels.stack([], k_parts)
        dev, d = self._device_arrays(), self.device
        n_faces = len(self.faces)
        shape = (n_batch, n_faces)
        lo32, hi32, _, bvh = self._tree(n_batch)
        lo0, hi0, lo_cap, hi_cap = (wp.empty(shape, dtype=wp.vec3d, device=d) for _ in range(4))
        wp.launch(_boxes_kernel, dim=shape, device=d,
                  inputs=[verts, dev["faces"], 0.5 * self.cap, 1e-7 * self.cap, lo0, hi0, lo_cap, hi_cap, lo32, hi32])
        bvh.refit()
        n_near = len(self._near_a)
        pair_cap = max(self._min_pair_list, 16 * n_batch)
        while True:
            clear = wp.array(np.full((n_batch, k_parts), np.inf), dtype=wp.float64, device=d)
            floor = wp.zeros((n_batch, k_parts), dtype=wp.float64, device=d)
            n_pairs = wp.zeros(n_batch, dtype=wp.int32, device=d)
            out_pairs = wp.empty((pair_cap, 3), dtype=wp.int32, device=d)
            out_count = wp.zeros(1, dtype=wp.int32, device=d)
            common = [clear, floor, n_pairs, out_pairs, out_count]
            scalars = [self._tiny, self.tau, self.cap]
            if n_near:
                wp.launch(_near_kernel, dim=(n_batch, n_near), device=d,
                          inputs=[verts, dev["faces"], dev["part"], dev["near_a"], dev["near_b"], dev["near_rest"],
                                  dev["near_shared"], lo0, hi0, lo_cap, hi_cap, *scalars, *common])
            wp.launch(_far_kernel, dim=shape, device=d,
                      inputs=[verts, dev["faces"], dev["part"], dev["near_ptr"], dev["near_b"], bvh.id, lo32, hi32,
                              lo0, hi0, lo_cap, hi_cap, *scalars, *common])
            count = int(out_count.numpy()[0])
            if count <= pair_cap:
                break
            pair_cap = count  # the list overflowed: run again with room for every counted pair
        clear_h = clear.numpy()
        floor_h = floor.numpy()
        n_pairs_h = n_pairs.numpy().astype(np.int64)
        pd_sub = -np.minimum(self.cap, clear_h)
        hit = np.flatnonzero(n_pairs_h > 0)
        if len(hit):
            self._finish_colliding(hit, out_pairs.numpy()[:count], host, floor_h, clear_h, pd_sub)
        return Labels(n_pairs_h > 0, n_pairs_h, pd_sub.max(1), pd_sub)

    def _finish_colliding(self, hit, pairs, host, floor, clear, pd_sub) -> None:
        """PD_i of the colliding poses on the host: crossing edges, flood fill and vertex depths (numba)."""
        ref = self._ref
        order = np.lexsort((pairs[:, 2], pairs[:, 1], pairs[:, 0]))
        pairs = pairs[order].astype(np.int64)
        starts = np.searchsorted(pairs[:, 0], hit)
        ends = np.searchsorted(pairs[:, 0], hit, side="right")
        k_parts = self.n_parts
        for p, s, e in zip(hit, starts, ends):
            v = np.ascontiguousarray(host(int(p)), dtype=np.float64)
            pp = np.ascontiguousarray(pairs[s:e, 1:])
            _, rec_key, rec_int, n_rec = pair_pass(v, self.faces, pp, self.ell, self.tau, self.cap, self.partition,
                                                   np.full(k_parts, np.inf), np.zeros(k_parts), ref.adj_ptr,
                                                   ref.adj_idx, ref.adj_eid, self.orient, ref._near_ptr, ref._near_b,
                                                   ref._near_rest)
            out, _ = finish_label(v, self.faces, rec_key, rec_int, n_rec, len(self.edges), floor[p].copy(),
                                  clear[p].copy(), self.partition, k_parts, self.cap, ref.adj_ptr, ref.adj_idx,
                                  ref.adj_eid, self.closed)
            pd_sub[p] = out

    def label(self, vertices) -> Label:
        """Verdict, number of counted pairs, PD and PD_i of one mesh (V, 3) (a batch of one)."""
        v = vertices[None] if hasattr(vertices, "detach") else np.asarray(vertices)[None]
        lb = self.label_batch(v)
        return Label(bool(lb.collides[0]), int(lb.n_pairs[0]), float(lb.pd[0]), lb.pd_sub[0])

    def verdict(self, vertices) -> bool:
        """True iff the mesh self-collides."""
        return self.label(vertices).collides

    def subsets(self, pd: np.ndarray) -> np.ndarray:
        """D_p / D_n / D_b codes of PD values with this labeler's ``eps``."""
        return split_subsets(pd, self.eps)

    def __repr__(self) -> str:
        return (f"BatchedLabeler(device={self.device!r}, n_vertices={self.n_vertices}, n_faces={len(self.faces)}, "
                f"n_parts={self.n_parts})")
