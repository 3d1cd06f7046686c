"""The closed-triangle rule of CGAL's Polygon Mesh Processing (``self_intersections``), exact: the verdict a user
comparing with CGAL expects (``neuralcol check --rule cgal``).

Where the paper's rule (:mod:`~neuralcol.collision.kernels.predicates`) counts two triangles only when their
*interiors* meet and never counts triangles sharing an edge, this rule takes the triangles *closed*:

* sharing no vertex: they intersect when they have any point in common (touching counts);
* sharing one vertex: when they have a point in common besides it (the edge opposite that vertex of one meets the
  other triangle);
* sharing an edge: when they are folded flat onto each other (coplanar, the two other corners on the same side of
  the edge);
* the same three vertices (a duplicated face): always;
* a triangle with collinear corners (degenerate) is reported with itself, as the pair (f, f), and with no other.

Built from the same exact orientation predicates: two closed triangles meet iff an edge of one meets the other
(the ends of their common segment lie on edges), and a closed segment meets a closed triangle iff it reaches the
triangle's plane and the line through it passes the three edges on one side (zeros allowed), or, lying in the plane,
an end is inside the triangle or the segment meets an edge (exact in the projection on a coordinate plane where the
triangle stays non-degenerate). On the public test meshes (107 of 111 that CGAL reads) the pairs are CGAL's, pair for
pair; on the other 4 CGAL's extra pairs were its degenerate faces paired with themselves, which the last rule adds.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from neuralcol.collision.kernels.broadphase import shared_vertex_count
from neuralcol.collision.kernels.predicates import _drop_axis, orient2d, orient3d
from neuralcol.collision.kernels.vec import point


@njit(cache=True, inline="always")
def _on_segment_2d(p, q, r, i, j):
    """For r collinear with p, q (in the plane of axes i, j): does r lie on the closed segment [p, q]?"""
    return (min(p[i], q[i]) <= r[i] <= max(p[i], q[i])) and (min(p[j], q[j]) <= r[j] <= max(p[j], q[j]))


@njit(cache=True)
def _segments_meet_2d(p, q, r, s, i, j):
    """Do the closed segments [p, q] and [r, s] meet (projected on axes i, j)? Exact."""
    o1 = orient2d(p[i], p[j], q[i], q[j], r[i], r[j])
    o2 = orient2d(p[i], p[j], q[i], q[j], s[i], s[j])
    o3 = orient2d(r[i], r[j], s[i], s[j], p[i], p[j])
    o4 = orient2d(r[i], r[j], s[i], s[j], q[i], q[j])
    if o1 * o2 < 0 and o3 * o4 < 0:
        return True
    return ((o1 == 0 and _on_segment_2d(p, q, r, i, j)) or (o2 == 0 and _on_segment_2d(p, q, s, i, j))
            or (o3 == 0 and _on_segment_2d(r, s, p, i, j)) or (o4 == 0 and _on_segment_2d(r, s, q, i, j)))


@njit(cache=True, inline="always")
def _inside_2d(p, t0, t1, t2, i, j, o):
    """Is p in the closed triangle (t0, t1, t2) of orientation o (axes i, j)?"""
    return (o * orient2d(t0[i], t0[j], t1[i], t1[j], p[i], p[j]) >= 0
            and o * orient2d(t1[i], t1[j], t2[i], t2[j], p[i], p[j]) >= 0
            and o * orient2d(t2[i], t2[j], t0[i], t0[j], p[i], p[j]) >= 0)


@njit(cache=True)
def segment_meets_triangle(a, b, t0, t1, t2):
    """Does the closed segment [a, b] meet the closed triangle (t0, t1, t2)? Exact (module docstring)."""
    sa = orient3d(t0, t1, t2, a)
    sb = orient3d(t0, t1, t2, b)
    if (sa > 0 and sb > 0) or (sa < 0 and sb < 0):
        return False
    if sa == 0 and sb == 0:  # in the plane (or the triangle is degenerate)
        k, o = _drop_axis(t0, t1, t2)
        if k < 0:
            return False
        i = 1 if k == 0 else 0
        j = 1 if k == 2 else 2
        return (_inside_2d(a, t0, t1, t2, i, j, o) or _inside_2d(b, t0, t1, t2, i, j, o)
                or _segments_meet_2d(a, b, t0, t1, i, j) or _segments_meet_2d(a, b, t1, t2, i, j)
                or _segments_meet_2d(a, b, t2, t0, i, j))
    o0 = orient3d(a, b, t0, t1)
    o1 = orient3d(a, b, t1, t2)
    o2 = orient3d(a, b, t2, t0)
    return (o0 >= 0 and o1 >= 0 and o2 >= 0) or (o0 <= 0 and o1 <= 0 and o2 <= 0)


@njit(cache=True)
def closed_triangles_meet(p0, p1, p2, q0, q1, q2):
    """Do the closed triangles meet? Exact: an edge of one meets the other."""
    return (segment_meets_triangle(p0, p1, q0, q1, q2) or segment_meets_triangle(p1, p2, q0, q1, q2)
            or segment_meets_triangle(p2, p0, q0, q1, q2) or segment_meets_triangle(q0, q1, p0, p1, p2)
            or segment_meets_triangle(q1, q2, p0, p1, p2) or segment_meets_triangle(q2, q0, p0, p1, p2))


@njit(cache=True)
def closed_pair_intersects(verts, faces, a, b):
    """Do triangles a and b intersect under the closed rule (module docstring)? Exact."""
    shared = shared_vertex_count(faces, a, b)
    p = (point(verts, faces[a, 0]), point(verts, faces[a, 1]), point(verts, faces[a, 2]))
    q = (point(verts, faces[b, 0]), point(verts, faces[b, 1]), point(verts, faces[b, 2]))
    if _drop_axis(p[0], p[1], p[2])[0] < 0 or _drop_axis(q[0], q[1], q[2])[0] < 0:
        return False  # a triangle with collinear corners
    if shared == 0:
        return closed_triangles_meet(p[0], p[1], p[2], q[0], q[1], q[2])
    if shared == 3:
        return True
    own_p = _own_corners(faces, a, b)  # the corners of each that the other lacks
    own_q = _own_corners(faces, b, a)
    if shared == 1:  # the edges opposite the shared vertex
        return (segment_meets_triangle(p[own_p[0]], p[own_p[1]], q[0], q[1], q[2])
                or segment_meets_triangle(q[own_q[0]], q[own_q[1]], p[0], p[1], p[2]))
    # shared == 2: one edge (u, w); folded flat onto each other?
    po, qo = p[own_p[0]], q[own_q[0]]
    pu, pw = p[(own_p[0] + 1) % 3], p[(own_p[0] + 2) % 3]
    if orient3d(pu, pw, po, qo) != 0:
        return False
    k, _ = _drop_axis(p[0], p[1], p[2])
    i = 1 if k == 0 else 0
    j = 1 if k == 2 else 2
    sp = orient2d(pu[i], pu[j], pw[i], pw[j], po[i], po[j])
    sq = orient2d(pu[i], pu[j], pw[i], pw[j], qo[i], qo[j])
    return sp * sq > 0


@njit(cache=True, inline="always")
def _own_corners(faces, a, b):
    """The corner indices (0-2) of triangle a whose vertex is not one of b's, in order (unused slots -1)."""
    out = np.full(3, -1, dtype=np.int64)
    n = 0
    for k in range(3):
        v = faces[a, k]
        if v != faces[b, 0] and v != faces[b, 1] and v != faces[b, 2]:
            out[n] = k
            n += 1
    return out


@njit(cache=True)
def closed_pairs_mask(verts, faces, pairs):
    """(P,) bool: which candidate pairs (P, 2) intersect under the closed rule."""
    out = np.empty(pairs.shape[0], dtype=np.bool_)
    for k in range(pairs.shape[0]):
        out[k] = closed_pair_intersects(verts, faces, pairs[k, 0], pairs[k, 1])
    return out


@njit(cache=True)
def degenerate_faces(verts, faces):
    """(F,) bool: triangles with collinear corners (exact)."""
    out = np.empty(faces.shape[0], dtype=np.bool_)
    for f in range(faces.shape[0]):
        out[f] = _drop_axis(point(verts, faces[f, 0]), point(verts, faces[f, 1]), point(verts, faces[f, 2]))[0] < 0
    return out
