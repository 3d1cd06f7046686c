"""Penetrating vertices of a self-intersecting mesh, from the crossing records of the label passes: which edges
separate inside from outside (the seeds), the penetrating regions (a flood fill bounded by those edges), each
region's opposing triangles, and per vertex the depth (the labeler's PD) or the vector to the nearest opposing
point (what a repair must move it by; :mod:`neuralcol.repair.untangle`). Definitions: the module docstring of
:mod:`neuralcol.collision.labeler` ("Penetrating vertices", "Depth")."""

from __future__ import annotations

import numpy as np
from numba import njit

from neuralcol.collision.kernels.distance import closest_point_triangle, point_triangle_distance
from neuralcol.collision.kernels.vec import corners, point, vsub


@njit(cache=True)
def crossing_seeds(rec_key, rec_int, n_rec, n_edges):
    """The edges that separate inside from outside and the seeds of the penetrating regions.

    An edge separates only if it crosses the surface an odd number of times (an edge through a corner enters and
    leaves). Crossings at the same point (through a shared edge or vertex of the other surface) count once if they
    agree on the side, and not at all if they disagree (a graze).

    Returns:
        seeds (S, 3) int64: (vertex behind the pierced triangle, the edge's other vertex, the pierced triangle);
        blocked (E,) bool: the separating edges.
    """
    blocked = np.zeros(n_edges, dtype=np.bool_)
    order = np.argsort(rec_key[:n_rec])
    seeds = np.empty((max(n_rec, 1), 3), dtype=np.int64)
    n_seeds = 0
    keep = np.zeros(n_rec, dtype=np.bool_)
    k = 0
    while k < n_rec:
        e = rec_int[order[k], 0]
        end = k
        while end < n_rec and rec_int[order[end], 0] == e:
            end += 1
        n_cross = 0
        c0 = k
        while c0 < end:  # clusters of equal crossing parameter
            c1 = c0 + 1
            agree = True
            while c1 < end and rec_key[order[c1]] - rec_key[order[c0]] <= 1e-12:
                if rec_int[order[c1], 1] != rec_int[order[c0], 1]:
                    agree = False
                c1 += 1
            if agree:
                n_cross += 1
                for j in range(c0, c1):
                    keep[order[j]] = True
            c0 = c1
        if n_cross % 2 == 1:
            blocked[e] = True
            for j in range(k, end):
                r = order[j]
                if keep[r] and rec_int[r, 4] == 1:
                    seeds[n_seeds, 0] = rec_int[r, 1]
                    seeds[n_seeds, 1] = rec_int[r, 2]
                    seeds[n_seeds, 2] = rec_int[r, 3]
                    n_seeds += 1
        k = end
    return seeds[:n_seeds], blocked


@njit(cache=True)
def penetrating_regions(n_vert, seeds, adj_ptr, adj_idx, adj_eid, blocked, closed, max_region):
    """Region of every vertex (V,) (-1: none), whether each region is enclosed by the intersection curves (R,), and
    R. On a closed mesh the region of a seed is everything reachable from it over edges that do not cross; a region
    that holds both ends of one of its crossing edges is not enclosed (a local fold) and keeps its seeds only. On a
    mesh with boundary there are no regions (seeds only). A region of more than ``max_region`` vertices is not
    enclosed either (the labeler passes V: never; a repair passes less, since a region that holds most of the mesh
    is the outside of a curve that does not close)."""
    region = np.full(n_vert, -1, dtype=np.int64)
    n_regions = 0
    if closed:
        queue = np.empty(n_vert, dtype=np.int64)
        for k in range(seeds.shape[0]):
            s = seeds[k, 0]
            if region[s] >= 0:
                continue
            head = 0
            tail = 0
            queue[tail] = s
            tail += 1
            region[s] = n_regions
            while head < tail:
                v = queue[head]
                head += 1
                for j in range(adj_ptr[v], adj_ptr[v + 1]):
                    w = adj_idx[j]
                    if region[w] >= 0 or blocked[adj_eid[j]]:
                        continue
                    region[w] = n_regions
                    queue[tail] = w
                    tail += 1
            n_regions += 1
    valid = np.ones(n_regions, dtype=np.bool_)
    if max_region < n_vert:
        size = np.zeros(n_regions, dtype=np.int64)
        for v in range(n_vert):
            if region[v] >= 0:
                size[region[v]] += 1
        for r in range(n_regions):
            if size[r] > max_region:
                valid[r] = False
    for k in range(seeds.shape[0]):
        r = region[seeds[k, 0]]
        if r >= 0 and region[seeds[k, 1]] == r:
            valid[r] = False
    return region, valid, n_regions


@njit(cache=True)
def _opposing(faces, region, pierced, r, opp):
    """Fill ``opp`` with region r's opposing triangles (those it pierces + the triangles of every other region);
    returns their number."""
    n_opp = 0
    for f in range(faces.shape[0]):
        own = False
        other = False
        for i in range(3):
            rf = region[faces[f, i]]
            if rf == r:
                own = True
            elif rf >= 0:
                other = True
        if not own and (pierced[r, f] or other):
            opp[n_opp] = f
            n_opp += 1
    return n_opp


@njit(cache=True)
def _bounds(verts, faces, opp, n_opp):
    """Centroid (n, 3) and radius (n,) of each opposing triangle: |p - c| - r bounds the distance from below."""
    cen = np.empty((n_opp, 3))
    rad = np.empty(n_opp)
    for k in range(n_opp):
        f = opp[k]
        for d in range(3):
            cen[k, d] = (verts[faces[f, 0], d] + verts[faces[f, 1], d] + verts[faces[f, 2], d]) / 3.0
        r2 = 0.0
        for i in range(3):
            e = 0.0
            for d in range(3):
                e += (verts[faces[f, i], d] - cen[k, d]) ** 2
            r2 = max(r2, e)
        rad[k] = np.sqrt(r2)
    return cen, rad


@njit(cache=True)
def _nearest(verts, faces, p, opp, n_opp, cen, rad, lb):
    """Distance from p to the nearest opposing triangle, and that triangle."""
    k_best = 0
    for k in range(n_opp):
        e = 0.0
        for d in range(3):
            e += (p[d] - cen[k, d]) ** 2
        lb[k] = np.sqrt(e) - rad[k]
        if lb[k] < lb[k_best]:
            k_best = k
    f_best = opp[k_best]
    t0, t1, t2 = corners(verts, faces, f_best)
    best = point_triangle_distance(p, t0, t1, t2)
    for k in range(n_opp):
        if lb[k] >= best:
            continue
        f = opp[k]
        t0, t1, t2 = corners(verts, faces, f)
        d = point_triangle_distance(p, t0, t1, t2)
        if d < best:
            best = d
            f_best = f
    return best, f_best


@njit(cache=True)
def penetration(verts, faces, seeds, adj_ptr, adj_idx, adj_eid, blocked, closed, want_vectors, max_region):
    """Depth (V,) of every penetrating vertex (0 elsewhere) and, with ``want_vectors`` 1, the vector (V, 3) from each
    vertex of an enclosed region to the nearest point of the opposing surface (zeros elsewhere); with 2 also for
    each seed outside an enclosed region: from the nearer end of its crossing edge to the pierced triangle, given to
    that end. ``max_region``: see
    :func:`penetrating_regions`."""
    n_vert = verts.shape[0]
    depth = np.zeros(n_vert)
    vec = np.zeros((n_vert if want_vectors > 0 else 0, 3))
    region, valid, n_regions = penetrating_regions(n_vert, seeds, adj_ptr, adj_idx, adj_eid, blocked, closed,
                                                   max_region)
    for k in range(seeds.shape[0]):
        r = region[seeds[k, 0]]
        if r < 0 or not valid[r]:
            v = seeds[k, 0]
            ta, tb, tc = corners(verts, faces, seeds[k, 2])
            d0 = point_triangle_distance(point(verts, v), ta, tb, tc)
            d1 = point_triangle_distance(point(verts, seeds[k, 1]), ta, tb, tc)
            d = min(d0, d1)
            if d > depth[v]:
                depth[v] = d
                if want_vectors == 2:
                    u = v if d0 <= d1 else seeds[k, 1]
                    p = point(verts, u)
                    x = vsub(closest_point_triangle(p, ta, tb, tc), p)
                    for i in range(3):
                        vec[u, i] = x[i]
    if n_regions == 0:
        return depth, vec
    pierced = np.zeros((n_regions, faces.shape[0]), dtype=np.bool_)
    for k in range(seeds.shape[0]):
        pierced[region[seeds[k, 0]], seeds[k, 2]] = True
    opp = np.empty(faces.shape[0], dtype=np.int64)
    for r in range(n_regions):
        if not valid[r]:
            continue
        n_opp = _opposing(faces, region, pierced, r, opp)
        if n_opp == 0:
            continue
        cen, rad = _bounds(verts, faces, opp, n_opp)
        lb = np.empty(n_opp)
        for v in range(n_vert):
            if region[v] != r:
                continue
            p = point(verts, v)
            best, f = _nearest(verts, faces, p, opp, n_opp, cen, rad, lb)
            depth[v] = best
            if want_vectors > 0:
                t0, t1, t2 = corners(verts, faces, f)
                x = vsub(closest_point_triangle(p, t0, t1, t2), p)
                for i in range(3):
                    vec[v, i] = x[i]
    return depth, vec
