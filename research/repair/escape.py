"""A probe: move each penetrating region of a mesh out as one piece, instead of each vertex to its nearest exit.

The region push of :mod:`neuralcol.repair.untangle` gives every vertex inside another part's volume its own target
(the nearest point of the surface it entered through); for a limb passed through a torso those targets point back
through the entry, out through the exit and sideways, and the field crumples. Here a penetrating region (a connected
set of vertices inside another part, :meth:`~neuralcol.collision.labeler.ExactLabeler.penetrations`) moves by one
translation ``s u``, carried by a smooth weight ``phi`` (1 on the region, dying out over the surface around it: the
membrane of :class:`~neuralcol.repair.untangle.SmoothField` with one scalar right-hand side, the same for the three
coordinates). The direction ``u`` (of ``n_dirs`` spread over the sphere) and the length ``s`` (multiples of the
region's depth) are searched on the exact labeler's pair count; the best move is kept and the search repeated, for at
most ``max_steps`` steps (:func:`escape`).

:func:`directed_escape` chooses the move from the geometry instead of searching it on the labeler: the weight is 1 on
the region and held at 0 on the triangles across its intersection curves (the other side stays put), and for each
direction ``u`` the length that takes every vertex of the region out is the farthest of the first hits of rays from
its vertices along ``u`` on the triangles that do not move (:func:`first_hits`); the ``tries`` shortest directions of
each region are tried on the labeler, the move that leaves the fewest pairs kept, for at most ``max_steps`` steps.

Research probes (docs/studies/deep_collisions.md), not repairs the package runs.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as spla
from numba import njit

from neuralcol.geometry.topology import edge_adjacency
from neuralcol.repair.untangle import edge_laplacian


def sphere_directions(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    polar, azimuth = np.arccos(1 - 2 * i / n), np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], 1)


class RegionField:
    """The penetrating regions of one topology and the smooth weight that carries each as one piece."""

    def __init__(self, faces: np.ndarray, n_vertices: int, stiffness: float = 1.0, anchor: float = 0.01,
                 hold: float = 10.0):
        self.adjacency = edge_adjacency(faces, n_vertices).tocsr()
        self.base = (stiffness * edge_laplacian(faces, n_vertices) + anchor * sp.eye(n_vertices)).tocsc()
        self.hold = hold

    def regions(self, inside: np.ndarray) -> list[np.ndarray]:
        """The connected sets of the vertices ``inside`` (V,) bool."""
        idx = np.flatnonzero(inside)
        n, label = csgraph.connected_components(self.adjacency[idx][:, idx], directed=False)
        return [idx[label == k] for k in range(n)]

    def weight(self, region: np.ndarray) -> np.ndarray:
        """(V,) the membrane field held at 1 on ``region``."""
        w = np.zeros(self.base.shape[0])
        w[region] = self.hold
        return spla.spsolve((self.base + sp.diags(w)).tocsc(), w)


class Escaped(NamedTuple):
    vertices: np.ndarray
    pairs_per_step: list


def escape(vertices: np.ndarray, labeler, field: RegionField, n_dirs: int = 64, scales=(0.5, 1.0, 1.5, 2.0, 3.0),
           max_steps: int = 4, max_regions: int = 4, keep_dirs: int | None = None) -> Escaped:
    """Translate penetrating regions of a mesh (V, 3) as whole pieces while that lowers the pair count. Every
    direction at every length, shortest length first; with ``keep_dirs`` the directions are first ranked at the
    region's own depth and only the ``keep_dirs`` best are tried at every length (``n_dirs + keep_dirs * len(scales)``
    checks per region instead of ``n_dirs * len(scales)``)."""
    dirs = sphere_directions(n_dirs)

    def best_move(v, pen, depth):
        best_count, best, best_len = pen.n_pairs, None, np.inf
        for region in sorted(field.regions(depth > 0), key=lambda r: -depth[r].max())[:max_regions]:
            phi = field.weight(region)[:, None]
            deepest = float(depth[region].max())
            use = dirs
            if keep_dirs is not None:
                counts = [int(len(labeler.intersecting_pairs(v + deepest * phi * u))) for u in dirs]
                use = dirs[np.argsort(counts, kind="stable")[:keep_dirs]]
            for s in scales:
                length = s * deepest
                for u in use:
                    moved = v + length * phi * u
                    count = int(len(labeler.intersecting_pairs(moved)))
                    if count < best_count or (count == best_count and best is not None and length < best_len):
                        best_count, best, best_len = count, moved, length
                if best_count == 0:
                    return best_count, best
        return best_count, best

    return greedy_steps(vertices, labeler, max_steps, best_move, int(len(labeler.intersecting_pairs(vertices))))


def greedy_steps(vertices: np.ndarray, labeler, max_steps: int, best_move, first: int) -> Escaped:
    """Up to ``max_steps`` moves of a mesh (V, 3), each ``best_move(v, penetrations, depth) -> (pair count, moved mesh
    or None)``, while a move lowers the pair count; ``first``: the input's pair count (the first of ``seen``)."""
    v = np.array(vertices, np.float64)
    seen = [first]
    for _ in range(max_steps):
        pen = labeler.penetrations(v, 0.3, seed_vectors=False)
        if pen.n_pairs == 0:
            break
        count, best = best_move(v, pen, np.linalg.norm(pen.vector, axis=1))
        if best is None:
            break
        v = best
        seen.append(count)
    return Escaped(v, seen)


@njit(cache=True)
def first_hits(origins, dirs, tri):
    """(D, R) distance along each direction ``dirs`` (D, 3) from each origin (R, 3) to the first of the triangles
    ``tri`` (S, 3, 3) a ray hits (Moller-Trumbore; inf: none)."""
    n_dirs, n_rays, n_tri = dirs.shape[0], origins.shape[0], tri.shape[0]
    out = np.full((n_dirs, n_rays), np.inf)
    for d in range(n_dirs):
        ux, uy, uz = dirs[d, 0], dirs[d, 1], dirs[d, 2]
        for s in range(n_tri):
            ax, ay, az = tri[s, 0, 0], tri[s, 0, 1], tri[s, 0, 2]
            e1x, e1y, e1z = tri[s, 1, 0] - ax, tri[s, 1, 1] - ay, tri[s, 1, 2] - az
            e2x, e2y, e2z = tri[s, 2, 0] - ax, tri[s, 2, 1] - ay, tri[s, 2, 2] - az
            px, py, pz = uy * e2z - uz * e2y, uz * e2x - ux * e2z, ux * e2y - uy * e2x
            det = e1x * px + e1y * py + e1z * pz
            if abs(det) < 1e-300:
                continue
            inv = 1.0 / det
            for r in range(n_rays):
                tx, ty, tz = origins[r, 0] - ax, origins[r, 1] - ay, origins[r, 2] - az
                b1 = (tx * px + ty * py + tz * pz) * inv
                if b1 < 0.0 or b1 > 1.0:
                    continue
                qx, qy, qz = ty * e1z - tz * e1y, tz * e1x - tx * e1z, tx * e1y - ty * e1x
                b2 = (ux * qx + uy * qy + uz * qz) * inv
                if b2 < 0.0 or b1 + b2 > 1.0:
                    continue
                t = (e2x * qx + e2y * qy + e2z * qz) * inv
                if 0.0 < t < out[d, r]:
                    out[d, r] = t
    return out


def rings(adjacency: sp.csr_matrix, index: np.ndarray, k: int) -> np.ndarray:
    """(V,) bool: the vertices within ``k`` edges of ``index``."""
    m = np.zeros(adjacency.shape[0], bool)
    m[index] = True
    for _ in range(k):
        m = m | (adjacency @ m.astype(np.float64) > 0)
    return m


def two_sided_weight(field: RegionField, faces: np.ndarray, region: np.ndarray, pairs: np.ndarray,
                     k: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """(V,) the membrane field held at 1 on ``region`` and at 0 on the vertices of the triangles across its
    intersection curves (pairs with one triangle within ``k`` rings of the region and the other not), and those
    vertices."""
    n = field.base.shape[0]
    near = rings(field.adjacency, region, k)[faces].any(1)
    a, b = pairs[:, 0], pairs[:, 1]
    across = np.unique(faces[np.concatenate([b[near[a] & ~near[b]], a[near[b] & ~near[a]]])].ravel())
    w = np.zeros(n)
    w[region] = w[across] = field.hold
    rhs = np.zeros(n)
    rhs[region] = field.hold
    return spla.spsolve((field.base + sp.diags(w)).tocsc(), rhs), across


def directed_escape(vertices: np.ndarray, faces: np.ndarray, labeler, field: RegionField, n_dirs: int = 128,
                    max_steps: int = 10, max_regions: int = 6, margin: float = 0.5, static: float = 0.05,
                    tries: int = 4) -> Escaped:
    """Move penetrating regions of a mesh (V, 3) out along the directions that take them out soonest (module
    docstring). ``margin``: mean edge lengths beyond the farthest hit; ``static``: triangles whose vertices all weigh
    less than this do not move (the rays' targets)."""
    dirs = sphere_directions(n_dirs)
    ell = float(labeler.ell)

    def best_move(v, pen, depth):
        pairs = np.asarray(labeler.intersecting_pairs(v)).reshape(-1, 2)
        candidates = []
        for region in sorted(field.regions(depth > 0), key=lambda r: -depth[r].max())[:max_regions]:
            phi, across = two_sided_weight(field, faces, region, pairs)
            if not len(across):
                continue
            still = (phi[faces] < static).all(1)
            hits = first_hits(v[region], dirs, v[faces[still]])
            need = np.where(np.isfinite(hits), hits, 0.0).max(1)  # (D,) takes every region vertex past its hit
            candidates += [(need[d] + margin * ell, d, phi) for d in np.argsort(need)[:tries] if need[d] > 0]
        candidates.sort(key=lambda c: c[0])
        best_count, best = pen.n_pairs, None
        for length, d, phi in candidates[:3 * tries]:
            moved = v + length * phi[:, None] * dirs[d]
            count = int(labeler.penetrations(moved, 0.3, seed_vectors=False).n_pairs)
            if count < best_count:
                best_count, best = count, moved
            if count == 0:
                break
        return best_count, best

    first = int(labeler.penetrations(vertices, 0.3, seed_vectors=False).n_pairs)
    return greedy_steps(vertices, labeler, max_steps, best_move, first)
