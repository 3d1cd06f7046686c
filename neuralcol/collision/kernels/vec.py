"""3-vectors as tuples for the numba kernels: arithmetic, a mesh's points and triangles, and the margins of the
computed lower bounds."""

from __future__ import annotations

from numba import njit

# A computed lower bound of a clearance term (a box gap, a SAT-axis gap, a cone angle) may exceed the computed term
# by a few ulps (different operations); it rules a term out only with this margin, so a skipped term is always
# >= the clearance it was compared with, and the minimum does not depend on the order the pairs are visited in.
BOUND_SHRINK = 1.0 - 1e-9
BOUND_GROW = 1.0 + 1e-9


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
