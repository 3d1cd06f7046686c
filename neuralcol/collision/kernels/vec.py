"""3-vectors as tuples for the numba kernels: arithmetic, a mesh's points and triangles, and the margins of the
computed lower bounds."""

from __future__ import annotations

from numba import njit

# A computed lower bound of a clearance term (a box gap, a SAT-axis gap, a cone angle) may exceed the computed term
# by a few ulps (different operations); it rules a term out only with this margin, so a skipped term is always
# >= the clearance it was compared with, and the minimum does not depend on the order the pairs are visited in.
BOUND_SHRINK = 1.0 - 1e-9
BOUND_GROW = 1.0 + 1e-9

# A gap between two triangles computed along a separating axis (SAT depth, ``axes_gap``) is off from the gap along
# that axis by at most ~10 unit round-offs of the largest coordinate (each projection is a 3-term dot product
# scaled by the axis' inverse length). So a computed gap > GAP_ROUNDOFF * max|coordinate| proves the triangles
# apart; below that, the exact predicate (:mod:`~neuralcol.collision.kernels.predicates`) decides.
GAP_ROUNDOFF = 2.0**-45

# The penetration of a counted pair whose computed depth is <= 0 (an exact intersection below round-off: a
# crossing at a tilt of ~1e-16): the smallest normal float32, so PD > 0 survives a cast to float32.
MIN_PENETRATION = 2.0**-126


@njit(cache=True, inline="always")
def vsub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, inline="always")
def vdot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, inline="always")
def vcross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, inline="always")
def vscale(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


@njit(cache=True, inline="always")
def vadd(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@njit(cache=True, inline="always")
def point(verts, i):
    return (verts[i, 0], verts[i, 1], verts[i, 2])


@njit(cache=True, inline="always")
def corners(verts, faces, f):
    """The three corners of triangle f, each an (x, y, z) tuple."""
    return point(verts, faces[f, 0]), point(verts, faces[f, 1]), point(verts, faces[f, 2])
