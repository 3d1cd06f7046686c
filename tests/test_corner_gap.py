"""``corner_gap`` (the near pass's wedge gap from per-mesh corner frames) equals ``corner_angle`` bit for bit."""

import numpy as np

from neuralcol.collision.kernels.broadphase import shared_vertex_count
from neuralcol.collision.kernels.distance import corner_angle, corner_cones, corner_gap


def _fan(n, seed, degenerate=False):
    """A fan of n triangles around vertex 0 with random rim points (some pairs crossing, some apart)."""
    rng = np.random.default_rng(seed)
    verts = np.concatenate([np.zeros((1, 3)), rng.normal(size=(2 * n, 3))])
    if degenerate:
        verts[2] = verts[1]  # a zero-length edge: a corner whose unit directions are (partly) zero vectors
        verts[4] = 0.0  # a rim point on the centre: a degenerate corner at the shared vertex
    faces = np.array([[0, 1 + 2 * i, 2 + 2 * i] for i in range(n)])
    return verts, faces


def test_corner_gap_equals_corner_angle_bit_for_bit():
    from numba import njit

    @njit
    def both(verts, faces, units, normals):
        n = faces.shape[0]
        out = np.zeros((n * n, 2))
        m = 0
        for a in range(n):
            for b in range(a + 1, n):
                if shared_vertex_count(faces, a, b) == 1:
                    out[m, 0] = corner_angle(verts, faces, a, b)
                    out[m, 1] = corner_gap(faces, a, b, units, normals)
                    m += 1
        return out[:m]

    for seed, degenerate in ((0, False), (1, False), (2, True)):
        verts, faces = _fan(12, seed, degenerate)
        units = np.empty((len(faces), 3, 2, 3))
        normals = np.empty((len(faces), 3, 3))
        axis, rho = corner_cones(verts, faces, units, normals)
        axis2, rho2 = corner_cones(verts, faces)
        assert np.array_equal(axis, axis2) and np.array_equal(rho, rho2)
        pairs = both(verts, faces, units, normals)
        assert len(pairs) == 66
        assert np.array_equal(pairs[:, 0], pairs[:, 1])
        assert (pairs[:, 0] == 0).any() and (pairs[:, 0] > 0).any()  # crossing corners and separate ones
