"""Warp kernels of :class:`~neuralcol.collision.warp_labeler.WarpLabeler` over a batch of poses: triangle boxes, near
pairs (the rest near table) and far pairs (a grouped BVH). Stages and layout: the labeler's module docstring."""

from __future__ import annotations

import warp as wp

from neuralcol.collision.warp_funcs import (
    box_gap,
    boxes_overlap,
    corner_angle,
    max3,
    min3,
    near_index,
    opposite_edges_cross,
    pair_depth,
    plane_separated,
    record,
    shared_count,
    triangle_distance,
)

wp.set_module_options({"fuse_fp": False, "enable_backward": False})

F32_REL = wp.constant(1e-6)  # outward rounding of the float32 broadphase boxes (float32 rounds within 6e-8 relative)


@wp.kernel
def boxes_kernel(verts: wp.array2d(dtype=wp.vec3d), faces: wp.array(dtype=wp.vec3i), half_cap: wp.float64,
                 pad: wp.float64, lo0: wp.array2d(dtype=wp.vec3d), hi0: wp.array2d(dtype=wp.vec3d),
                 lo_cap: wp.array2d(dtype=wp.vec3d), hi_cap: wp.array2d(dtype=wp.vec3d),
                 lo32: wp.array(dtype=wp.vec3), hi32: wp.array(dtype=wp.vec3)):
    """Exact boxes, boxes grown by cap / 2 (kernels.broadphase.triangle_aabbs) and their float32 copy rounded
    outwards."""
    pose, f = wp.tid()
    fa = faces[f]
    a = verts[pose, fa[0]]
    b = verts[pose, fa[1]]
    c = verts[pose, fa[2]]
    lo = wp.vec3d(min3(a[0], b[0], c[0]), min3(a[1], b[1], c[1]), min3(a[2], b[2], c[2]))
    hi = wp.vec3d(max3(a[0], b[0], c[0]), max3(a[1], b[1], c[1]), max3(a[2], b[2], c[2]))
    lc = wp.vec3d(lo[0] - half_cap, lo[1] - half_cap, lo[2] - half_cap)
    hc = wp.vec3d(hi[0] + half_cap, hi[1] + half_cap, hi[2] + half_cap)
    lo0[pose, f] = lo
    hi0[pose, f] = hi
    lo_cap[pose, f] = lc
    hi_cap[pose, f] = hc
    rel = wp.float64(F32_REL)
    k = pose * faces.shape[0] + f
    lo32[k] = wp.vec3(wp.float32(lc[0] - (wp.abs(lc[0]) * rel + pad)), wp.float32(lc[1] - (wp.abs(lc[1]) * rel + pad)),
                      wp.float32(lc[2] - (wp.abs(lc[2]) * rel + pad)))
    hi32[k] = wp.vec3(wp.float32(hc[0] + (wp.abs(hc[0]) * rel + pad)), wp.float32(hc[1] + (wp.abs(hc[1]) * rel + pad)),
                      wp.float32(hc[2] + (wp.abs(hc[2]) * rel + pad)))


@wp.kernel
def near_kernel(verts: wp.array2d(dtype=wp.vec3d), faces: wp.array(dtype=wp.vec3i),
                part: wp.array(dtype=wp.int32), near_a: wp.array(dtype=wp.int32),
                near_b: wp.array(dtype=wp.int32), near_rest: wp.array(dtype=wp.float64),
                near_shared: wp.array(dtype=wp.int32), lo0: wp.array2d(dtype=wp.vec3d),
                hi0: wp.array2d(dtype=wp.vec3d), lo_cap: wp.array2d(dtype=wp.vec3d),
                hi_cap: wp.array2d(dtype=wp.vec3d), tiny: wp.float64, tau: wp.float64, cap: wp.float64,
                clear: wp.array2d(dtype=wp.float64), floor: wp.array2d(dtype=wp.float64),
                n_pairs: wp.array(dtype=wp.int32), out_pairs: wp.array2d(dtype=wp.int32),
                out_count: wp.array(dtype=wp.int32)):
    """Near pairs (rows of the rest near table) within cap: kernels.pair_terms.pair_terms with ``idx >= 0``."""
    pose, k = wp.tid()
    a = near_a[k]
    b = near_b[k]
    if not boxes_overlap(lo_cap, hi_cap, pose, a, b):
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
        if opposite_edges_cross(verts, pose, fa, fb):
            depth = pair_depth(p0, p1, p2, q0, q1, q2, tiny)
    else:
        depth = pair_depth(p0, p1, p2, q0, q1, q2, tiny)
    c = zero
    if depth <= tau:
        r = near_rest[k]
        if r <= zero:
            c = cap
        elif shared == 1:
            c = cap * corner_angle(verts, pose, fa, fb) / r
        else:
            c = cap * wp.max(-depth, zero) / r
    counted = depth > tau and boxes_overlap(lo0, hi0, pose, a, b)
    record(pose, a, b, depth, c, counted, fa, fb, part, tau, cap, clear, floor, n_pairs, out_pairs, out_count)


@wp.kernel
def far_kernel(verts: wp.array2d(dtype=wp.vec3d), faces: wp.array(dtype=wp.vec3i),
               part: wp.array(dtype=wp.int32), near_ptr: wp.array(dtype=wp.int32),
               near_b: wp.array(dtype=wp.int32), bvh: wp.uint64, lo32: wp.array(dtype=wp.vec3),
               hi32: wp.array(dtype=wp.vec3), lo0: wp.array2d(dtype=wp.vec3d), hi0: wp.array2d(dtype=wp.vec3d),
               lo_cap: wp.array2d(dtype=wp.vec3d), hi_cap: wp.array2d(dtype=wp.vec3d), tiny: wp.float64,
               tau: wp.float64, cap: wp.float64, clear: wp.array2d(dtype=wp.float64),
               floor: wp.array2d(dtype=wp.float64), n_pairs: wp.array(dtype=wp.int32),
               out_pairs: wp.array2d(dtype=wp.int32), out_count: wp.array(dtype=wp.int32)):
    """Far pairs within cap (grown boxes overlap, no shared vertex, not in the near table):
    kernels.pair_terms.pair_terms with ``idx < 0``. Thread (pose, a) takes the partners b > a its BVH group
    returns."""
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
        if not boxes_overlap(lo_cap, hi_cap, pose, a, b):
            continue
        fb = faces[b]
        if shared_count(fa, fb) > 0:
            continue
        if near_index(near_ptr, near_b, a, b) >= 0:
            continue
        p0 = verts[pose, fa[0]]
        p1 = verts[pose, fa[1]]
        p2 = verts[pose, fa[2]]
        q0 = verts[pose, fb[0]]
        q1 = verts[pose, fb[1]]
        q2 = verts[pose, fb[2]]
        lb = box_gap(p0, p1, p2, q0, q1, q2)
        if lb > zero and lb >= cap:
            continue  # term = distance >= lb >= cap
        if plane_separated(p0, p1, p2, q0, q1, q2, cap):
            continue  # apart by more than cap
        depth = wp.float64(-1.0)
        if not plane_separated(p0, p1, p2, q0, q1, q2, tau):
            depth = pair_depth(p0, p1, p2, q0, q1, q2, tiny)
        c = zero
        if depth <= tau and depth <= zero:
            c = triangle_distance(p0, p1, p2, q0, q1, q2)
        counted = depth > tau and boxes_overlap(lo0, hi0, pose, a, b)
        record(pose, a, b, depth, c, counted, fa, fb, part, tau, cap, clear, floor, n_pairs, out_pairs,
               out_count)
