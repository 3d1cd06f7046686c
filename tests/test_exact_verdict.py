"""The labeler's verdict is exact: checked against a slow rational reference written here, on hard configurations
(coplanar overlaps, near-coplanar crossings, one-vertex folds, exact touching, random small integers) at scales
1e-2 .. 1e2.

The reference decides, in exact rational arithmetic on the float coordinates, whether two triangles' relative
interiors intersect by looking for a *proper* separating plane (Rockafellar, Convex Analysis, Thm. 11.3: the
relative interiors of two convex sets are disjoint iff a hyperplane has one set on each closed side and not both
in it). For two triangles the candidate normals are those of the faces of their Minkowski difference: the two
face normals, the nine edge-edge cross products and the six in-plane edge normals. That is another algorithm than
the labeler's orientation-sign test, so agreement is evidence for both.
"""

from __future__ import annotations

import zlib
from fractions import Fraction

import numpy as np
import pytest

from neuralcol.collision.kernels.predicates import orient2d, orient3d, triangles_intersect
from neuralcol.collision.labeler import ExactLabeler

SCALES = (1e-2, 1.0, 1e2)


# ------------------------------------------------------------------------------------------- rational reference
def _sub(a, b):
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def interiors_intersect_ref(p, q) -> bool:
    """Exact: do the relative interiors of triangles p and q (3 x 3 floats) intersect? Zero-area triangles have no
    interior (the labeler's rule)."""
    p = [[Fraction(float(x)) for x in row] for row in p]
    q = [[Fraction(float(x)) for x in row] for row in q]
    n_p = _cross(_sub(p[1], p[0]), _sub(p[2], p[0]))
    n_q = _cross(_sub(q[1], q[0]), _sub(q[2], q[0]))
    if not any(n_p) or not any(n_q):
        return False
    e = [_sub(p[(i + 1) % 3], p[i]) for i in range(3)]
    f = [_sub(q[(i + 1) % 3], q[i]) for i in range(3)]
    axes = [n_p, n_q] + [_cross(a, b) for a in e for b in f] + [_cross(n_p, a) for a in e] + [_cross(n_q, b) for b in f]
    for ax in axes:
        if not any(ax):
            continue
        a = [_dot(ax, x) for x in p]
        b = [_dot(ax, x) for x in q]
        if (max(a) <= min(b) or max(b) <= min(a)) and not (min(a) == max(a) == min(b) == max(b)):
            return False  # a proper separating plane
    return True


def counted_pairs_ref(verts, faces) -> int:
    """Number of counted pairs: non-adjacent (sharing at most one vertex) with intersecting interiors."""
    n = 0
    for a in range(len(faces)):
        for b in range(a + 1, len(faces)):
            if len(set(faces[a]) & set(faces[b])) >= 2:
                continue
            n += interiors_intersect_ref(verts[faces[a]], verts[faces[b]])
    return n


def _orient3d_ref(a, b, c, d) -> int:
    a, b, c, d = ([Fraction(float(x)) for x in v] for v in (a, b, c, d))
    det = _dot(_cross(_sub(b, a), _sub(c, a)), _sub(d, a))
    return (det > 0) - (det < 0)


# --------------------------------------------------------------------------------------------- hard configurations
def _rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


def _far_triangle(scale):
    return np.array([[50.0, 50.0, 50.0], [51.0, 50.0, 50.0], [50.0, 51.0, 50.0]]) * scale


def _mesh(p, q, scale, shared=False):
    """Triangles p, q (3, 3) and a far triangle as one mesh; with ``shared`` p[0] and q[0] are one vertex."""
    if shared:
        verts = np.concatenate([p, q[1:], _far_triangle(scale)])
        faces = np.array([[0, 1, 2], [0, 3, 4], [5, 6, 7]])
    else:
        verts = np.concatenate([p, q, _far_triangle(scale)])
        faces = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    return verts.astype(np.float64), faces


def coplanar_overlaps(rng, scale):
    """Two vertex-disjoint triangles in one plane overlapping with positive area: in an axis plane (exactly
    coplanar at any scale) and in a tilted plane through small integers and half-integers (scaled by a power of
    two, so still exactly coplanar)."""
    out = []
    for _ in range(6):
        p = np.c_[rng.uniform(-1, 1, (3, 2)), np.zeros(3)]
        q = p.mean(0) + 0.8 * (p[[1, 2, 0]] - p.mean(0)) + np.r_[rng.uniform(-0.1, 0.1, 2), 0]
        perm = rng.permutation(3)
        z = rng.uniform(-3, 3)
        out.append(_mesh((p + [0, 0, z])[:, perm] * scale, (q + [0, 0, z])[:, perm] * scale, scale))
    for _ in range(4):  # plane x + y + z = c through integer points
        uv = rng.integers(-6, 7, size=(3, 2)).astype(float)
        d1, d2 = uv[1] - uv[0], uv[2] - uv[0]
        if abs(d1[0] * d2[1] - d1[1] * d2[0]) < 1:
            continue
        wq = 0.5 * (uv + uv[[1, 2, 0]])  # the medial triangle: its corners on P's edges, its interior in P's
        lift = lambda w: np.c_[w[:, 0], w[:, 1], 5 - w[:, 0] - w[:, 1]]  # noqa: E731
        s2 = 2.0 ** np.round(np.log2(scale))
        out.append(_mesh(lift(uv) * s2, lift(wq) * s2, scale))
    return out


def near_coplanar(rng, scale, tilts=(1e-3, 1e-6, 1e-9, 1e-12)):
    """Q coplanar with P and overlapping it, then tilted by ``tilt`` (radians-ish) about a line through both
    interiors: it crosses P there."""
    out = []
    for tilt in tilts:
        for _ in range(2):
            p = np.c_[rng.uniform(-1, 1, (3, 2)), np.zeros(3)]
            c = p.mean(0)
            q = c + 0.8 * (p[[1, 2, 0]] - c)
            q[:, 2] = tilt * (q[:, 0] - c[0])  # rotate about the line x = c_x through the common centroid
            rot = _rotation(rng)
            out.append(_mesh((p @ rot.T + 0.3) * scale, (q @ rot.T + 0.3) * scale, scale))
    return out


def one_vertex_folds(rng, scale, angles=(1e-3, 1e-6, 1e-9, 1e-12)):
    """P and Q share one vertex; Q folds through P by ``angle`` away from it (intersecting), or lies on one side
    of P touching only at the shared vertex (free)."""
    out = []
    for ang in angles:
        for through in (True, False):
            p = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
            q = np.array([[0.0, 0, 0], [0.7, 0.2, ang], [0.2, 0.7, -ang if through else ang]])
            rot = _rotation(rng)
            out.append(_mesh((p @ rot.T - 0.2) * scale, (q @ rot.T - 0.2) * scale, scale, shared=True))
    return out


def touching(rng, scale):
    """Exact contact without overlap (free): a corner on the other face, an edge in the other's plane, coplanar
    triangles apart or sharing part of an edge line."""
    p = np.array([[0.0, 0, 0], [4, 0, 0], [0, 4, 0]])
    cases = [
        np.array([[1.0, 1, 0], [1, 2, 3], [2, 1, 2]]),  # a corner on P's interior, the rest above
        np.array([[1.0, 1, 0], [2, 1, 0], [1, 2, 5]]),  # an edge in P's face
        np.array([[5.0, 0, 0], [8, 0, 0], [5, 3, 0]]),  # coplanar, apart
        np.array([[1.0, 0, 0], [3, 0, 0], [2, -2, 0]]),  # coplanar, sharing part of P's edge line from outside
        np.array([[1.0, 1, 0], [3, 1, 0], [2, 1, 2]]),  # an edge in P's face, the triangle standing up
    ]
    out = []
    for q in cases:  # axes permuted and flipped (exact in floats, unlike a rotation, which would round a contact
        for _ in range(2):  # into a crossing or a gap)
            perm, sign = rng.permutation(3), rng.choice([-1.0, 1.0], 3)
            out.append(_mesh(p[:, perm] * sign * scale + 0.25, q[:, perm] * sign * scale + 0.25, scale))
    return out


def small_integers(rng, scale, n=40):
    """Random corners on a small integer grid (many exact coincidences), vertex-disjoint or sharing one."""
    out = []
    for k in range(n):
        pts = rng.integers(-2, 3, size=(6, 3)).astype(float) * scale
        out.append(_mesh(pts[:3], pts[3:], scale, shared=bool(k % 3 == 0)))
    return out


FAMILIES = {"coplanar_overlap": coplanar_overlaps, "near_coplanar": near_coplanar, "one_vertex_fold": one_vertex_folds,
            "touching": touching, "small_integers": small_integers}


_UNIT = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])


def _rest_meshes(n_vertices, scale):
    """Free rest meshes of the cases' topologies and scale: the two triangles within the clearance cap of each
    other (near pairs) and, sharing no vertex, far apart (far pairs). The verdict does not depend on the rest mesh;
    the label passes it selects do."""
    far = _far_triangle(1.0)
    if n_vertices == 8:  # sharing vertex 0: opposite corners
        return [np.concatenate([_UNIT, -_UNIT[1:], far]) * scale]
    return [np.concatenate([_UNIT, _UNIT + [0, 0, 1e-3], far]) * scale,
            np.concatenate([_UNIT, _UNIT + [0, 0, 5.0], far]) * scale]


def _labelers(verts, faces, scale):
    """The default pruned labeler over each rest mesh, and the reference path (every pair within cap)."""
    rests = _rest_meshes(len(verts), scale)
    return [ExactLabeler(faces, r) for r in rests] + [ExactLabeler(faces, rests[0], prune=False)]


@pytest.mark.parametrize("family", sorted(FAMILIES))
@pytest.mark.parametrize("scale", SCALES)
def test_verdicts_match_the_rational_reference(family, scale):
    rng = np.random.default_rng(zlib.crc32(f"{family} {scale}".encode()))
    cases = FAMILIES[family](rng, scale)
    wrong = []
    for k, (verts, faces) in enumerate(cases):
        ref = counted_pairs_ref(verts, faces)
        for lab in _labelers(verts, faces, scale):
            label = lab.label(verts)
            got = (lab.verdict(verts), label.collides, label.pd > 0, label.n_pairs, len(lab.intersecting_pairs(verts)))
            if got != (ref > 0, ref > 0, ref > 0, ref, ref):
                wrong.append((k, got, ref, verts.tolist()))
    assert not wrong, f"{len(wrong)} of {len(cases)} {family} cases at scale {scale} disagree, first: {wrong[0]}"


def test_the_families_hold_both_verdicts():
    """The generated cases are hard ones of both kinds: every family but 'touching' has intersecting cases, and
    folds and integers have free ones (a test that could only see one answer could not fail)."""
    rng = np.random.default_rng(0)
    for family, make in FAMILIES.items():
        refs = [counted_pairs_ref(v, f) > 0 for v, f in make(rng, 1.0)]
        if family == "touching":
            assert not any(refs)
        elif family in ("coplanar_overlap", "near_coplanar"):
            assert all(refs), family
        else:
            assert any(refs) and not all(refs), family


def test_coplanar_overlap_gets_its_in_plane_depth():
    """PD > 0 for a coplanar overlap: the in-plane translation that separates the triangles, not 0."""
    p = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0]])
    q = p + [0.5, 0.5, 0]  # overlapping, shifted diagonally
    verts, faces = _mesh(p, q, 1.0)
    label = ExactLabeler(faces, verts).label(verts)
    assert label.collides and label.n_pairs == 1
    # the shortest in-plane push: along the hypotenuse's normal (1, 1) / sqrt(2), by (2 - 1) / sqrt(2)
    assert label.pd == pytest.approx(np.sqrt(0.5), rel=1e-12)


def test_touch_tolerance_is_an_explicit_setting():
    """touch_tol > 0 drops crossings shallower than tau (the tolerance the labeler had by default); 0 is exact."""
    p = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    c = p.mean(0)
    q = c + 0.8 * (p[[1, 2, 0]] - c)
    q[:, 2] = 1e-9 * (q[:, 0] - c[0])
    verts, faces = _mesh(p, q, 1.0)
    assert ExactLabeler(faces, verts).verdict(verts)
    assert not ExactLabeler(faces, verts, touch_tol=1e-6).verdict(verts)


@pytest.mark.parametrize("scale", (1e-7, 1e-2, 1.0, 1e3, 3e8))
def test_orient3d_is_exact_near_degenerate(scale):
    rng = np.random.default_rng(1)
    wrong = 0
    for k in range(400):
        pts = rng.integers(-3, 4, size=(4, 3)).astype(float) * scale + rng.uniform(-1, 1, 3) * scale * 1e3
        if k % 2:  # d on the plane of a, b, c up to the last bits
            pts[3] = pts[0] + 0.37 * (pts[1] - pts[0]) + 0.21 * (pts[2] - pts[0])
            pts[3] += rng.integers(-2, 3, 3) * np.spacing(pts[3])
        wrong += orient3d(*map(tuple, pts)) != _orient3d_ref(*pts)
    assert wrong == 0


def test_orient2d_is_exact_near_degenerate():
    rng = np.random.default_rng(2)
    for _ in range(400):
        a, b = rng.normal(size=(2, 2)) * 1e4
        c = a + 0.3 * (b - a)
        c += rng.integers(-2, 3, 2) * np.spacing(c)
        fa, fb, fc = ([Fraction(float(x)) for x in v] for v in (a, b, c))
        det = (fb[0] - fa[0]) * (fc[1] - fa[1]) - (fb[1] - fa[1]) * (fc[0] - fa[0])
        assert orient2d(a[0], a[1], b[0], b[1], c[0], c[1]) == (det > 0) - (det < 0)


def test_triangle_test_is_symmetric_and_ignores_corner_order():
    rng = np.random.default_rng(3)
    for _ in range(300):
        pts = rng.integers(-2, 3, size=(6, 3)).astype(float)
        p, q = [tuple(x) for x in pts[:3]], [tuple(x) for x in pts[3:]]
        ref = interiors_intersect_ref(pts[:3], pts[3:])
        assert (triangles_intersect(*p, *q) > 0) == ref
        assert (triangles_intersect(*q, *p) > 0) == ref
        assert (triangles_intersect(p[1], p[0], p[2], q[2], q[1], q[0]) > 0) == ref
