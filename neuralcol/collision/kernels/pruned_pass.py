"""The pruned label passes of :class:`~neuralcol.collision.labeler.ExactLabeler`: near pairs from the rest mesh's
table and far pairs from one grid, skipping the pairs that provably cannot change a label
(``docs/studies/labeler_scaling.md``)."""

from __future__ import annotations

import numpy as np
from numba import njit

from neuralcol.collision.kernels.broadphase import boxes_overlap, shared_vertex_count, sorted_cells
from neuralcol.collision.kernels.clusters import cluster_candidates
from neuralcol.collision.kernels.depth import axes_gap
from neuralcol.collision.kernels.distance import cone_gap, corner_gap
from neuralcol.collision.kernels.pair_terms import count_pair, lower_clearance, near_index, pair_terms, part_min
from neuralcol.collision.kernels.vec import BOUND_SHRINK, corners


@njit(cache=True)
def near_pass(verts, faces, near_ptr, near_b, near_rest, near_shared, lo0, hi0, lo_cap, hi_cap, axes, inv, ax_lo,
              ax_hi, cone_axis, cone_rho, cone_units, cone_normals, scale, tau, gerr, cap, clear, floor, part, adj_ptr,
              adj_idx, adj_eid, orient, rec_key, rec_int, n_rec, scratch_i, scratch_f):
    """Every near pair (the rest mesh's table) that the reference considers (boxes within cap): counted pairs,
    their crossings, and the clearance terms that can lower a part's clearance. Lowers ``clear`` and raises
    ``floor`` in place.

    A pair whose boxes overlap may be counted; a pair whose boxes are disjoint cannot. The per-triangle SAT axes
    give ``g <= -depth`` exactly (:func:`axes_gap`), and a computed gap is off by at most ``gerr``, so a pair not
    sharing a vertex with ``g > tau + gerr`` is apart (not counted) and its term
    ``c = cap * max(-depth, 0) / r >= cap * g / r``: it is evaluated only if that bound
    is below the largest current clearance of its parts (then it might lower one). To make that threshold
    low early, the pair with the smallest bound of each part is evaluated first. Pairs sharing a vertex and
    pairs touching at rest (no bound) are always evaluated, as in the reference. Skipping a term that is
    >= the current clearance leaves every minimum, maximum and count unchanged, so the labels equal the
    reference's bit for bit.

    ``scratch_i`` (2, N) int64 and ``scratch_f`` (N,) float64 (N = number of near pairs) are work space, reused
    between meshes (allocating them per mesh costs more than the pass on finely subdivided meshes).

    Returns:
        n_pairs (counted), rec_key, rec_int, n_rec (crossing records, possibly grown).
    """
    n_faces = faces.shape[0]
    n_parts = clear.shape[0]
    todo_a = scratch_i[0]  # preallocated (2, N) int64 and (N,) float64 for N = len(near_b)
    todo_i = scratch_i[1]
    todo_bound = scratch_f
    n_todo = 0
    best_bound = np.full(n_parts, np.inf)
    best_k = np.full(n_parts, -1, dtype=np.int64)
    n_pairs = 0
    sep = tau + gerr  # a computed gap beyond this proves the pair apart
    for a in range(n_faces):
        p0, p1, p2 = corners(verts, faces, a)
        t_all = min(clear.max(), cap)  # no term >= this can lower any clearance (they only fall)
        for idx in range(near_ptr[a], near_ptr[a + 1]):
            b = near_b[idx]
            if t_all <= 0.0 and not boxes_overlap(lo0, hi0, a, b):
                continue  # not counted, and no term can lower a clearance that is 0 everywhere (limit 0)
            if not boxes_overlap(lo_cap, hi_cap, a, b):
                continue  # not a candidate of the reference
            overlap = boxes_overlap(lo0, hi0, a, b)
            r = near_rest[idx]
            bound = -np.inf
            if near_shared[idx]:
                # c = cap * wedge_gap / r; a positive cone bound also rules out an overlap beyond the vertex
                g = cone_gap(faces, a, b, cone_axis, cone_rho)
                if g > 0.0:
                    bound = cap if r <= 0.0 else cap * (g * BOUND_SHRINK) / r
            else:
                q0, q1, q2 = corners(verts, faces, b)
                g = axes_gap(axes, inv, ax_lo, ax_hi, a, q0, q1, q2)
                if (not overlap or g > sep) and (r <= 0.0 or cap * (g * BOUND_SHRINK) / r >= t_all):
                    continue  # not counted, and its term cannot lower any clearance
                g = max(g, axes_gap(axes, inv, ax_lo, ax_hi, b, p0, p1, p2))
                if not overlap or g > sep:  # not counted; c >= bound (c = cap when the pair touches at rest)
                    bound = cap if r <= 0.0 else cap * (g * BOUND_SHRINK) / r
            if overlap and bound == -np.inf:  # may be counted: evaluate now
                shared = 1 if near_shared[idx] else 0
                evaluated, counted, pen, c = pair_terms(verts, faces, a, b, shared, idx, near_rest, scale, tau,
                                                        gerr, cap, clear, part)
                if evaluated:
                    lower_clearance(clear, part, faces, a, b, c)
                    if counted:
                        n_pairs += 1
                        rec_key, rec_int, n_rec = count_pair(verts, faces, a, b, pen, part, floor, adj_ptr,
                                                             adj_idx, adj_eid, orient, rec_key, rec_int, n_rec)
                continue
            if bound >= t_all:
                continue  # not counted (bound > -inf), and its term cannot lower any clearance
            todo_a[n_todo] = a
            todo_i[n_todo] = idx
            todo_bound[n_todo] = bound
            for t in (a, b):
                for i in range(3):
                    pi = part[faces[t, i]]
                    if bound < best_bound[pi]:
                        best_bound[pi] = bound
                        best_k[pi] = n_todo
            n_todo += 1
    # the most promising pair of each part first, then the rest against the lowered thresholds
    for step in range(n_parts + n_todo):
        k = best_k[step] if step < n_parts else step - n_parts
        if k < 0:
            continue
        if step >= n_parts and todo_bound[k] == np.inf:
            continue  # done in the first round
        a = todo_a[k]
        idx = todo_i[k]
        b = near_b[idx]
        thr = part_min(clear, part, faces, a, b, cap)
        if thr <= 0.0 or todo_bound[k] >= thr:
            continue
        todo_bound[k] = np.inf  # mark done
        if near_shared[idx]:
            # its cone bound is > 0 (no bound otherwise): the corners do not overlap, so pair_terms would give
            # depth -1 and c = cap * corner_angle / r; corner_gap is corner_angle from the mesh's corner frames
            r = near_rest[idx]
            c = cap if r <= 0.0 else cap * corner_gap(faces, a, b, cone_units, cone_normals) / r
            lower_clearance(clear, part, faces, a, b, c)
            continue
        evaluated, _, _, c = pair_terms(verts, faces, a, b, 0, idx, near_rest, scale, tau, gerr, cap, clear, part)
        if evaluated:
            lower_clearance(clear, part, faces, a, b, c)
    return n_pairs, rec_key, rec_int, n_rec


@njit(cache=True, inline="always")
def _far_gap(verts, faces, a, b, axes, inv, ax_lo, ax_hi):
    """Largest gap between triangles a and b along their own SAT axes: ``<= -depth`` and ``<= distance``."""
    p0, p1, p2 = corners(verts, faces, a)
    q0, q1, q2 = corners(verts, faces, b)
    return max(axes_gap(axes, inv, ax_lo, ax_hi, a, q0, q1, q2), axes_gap(axes, inv, ax_lo, ax_hi, b, p0, p1, p2))


@njit(cache=True)
def far_pairs(verts, faces, cand, n_cand, lo0, hi0, lo_cap, hi_cap, tri_thr, pts, skip2, near_ptr, near_b, near_rest,
              axes, inv, ax_lo, ax_hi, scale, tau, gerr, cap, clear, floor, part, adj_ptr, adj_idx, adj_eid, orient,
              rec_key, rec_int, n_rec):
    """The far pass's treatment of the candidate pairs ``cand[:n_cand]`` (a < b, boxes grown as the broadphase grew
    them overlap), one after the other: a pair is skipped if it is adjacent or near (or, with disjoint boxes ``lo0``/
    ``hi0``, when neither triangle has a clearance to lower (``tri_thr``, :func:`far_thresholds`) or the rest
    centroids ``pts`` are closer than ``sqrt(skip2)``), evaluated in full if its boxes ``lo0``/``hi0`` overlap (it
    may be counted), else evaluated for its clearance term unless a bound rules the term out. Lowers ``clear`` and
    raises ``floor`` in place.

    The labels do not depend on the order of the pairs: a skipped term is >= the clearance it would have to beat
    (``BOUND_SHRINK``), clearances are minima, floors maxima, the counted pairs do not depend on the clearances,
    and :func:`~neuralcol.collision.kernels.label_pass.finish_label` sorts the crossing records.

    Returns:
        n_pairs (counted), rec_key, rec_int, n_rec.
    """
    n_pairs = 0
    for k in range(n_cand):
        a = cand[k, 0]
        b = cand[k, 1]
        if boxes_overlap(lo0, hi0, a, b):
            if shared_vertex_count(faces, a, b) > 0 or near_index(near_ptr, near_b, a, b) >= 0:
                continue  # adjacent or near: not a far pair
            g = _far_gap(verts, faces, a, b, axes, inv, ax_lo, ax_hi)
            if g > tau + gerr and g * BOUND_SHRINK >= part_min(clear, part, faces, a, b, cap):
                continue  # apart (depth <= -g, beyond round-off), and its distance >= g cannot lower a clearance
            evaluated, counted, pen, c = pair_terms(verts, faces, a, b, 0, -1, near_rest, scale, tau, gerr, cap, clear,
                                                    part)
            if evaluated:
                lower_clearance(clear, part, faces, a, b, c)
                if counted:
                    n_pairs += 1
                    rec_key, rec_int, n_rec = count_pair(verts, faces, a, b, pen, part, floor, adj_ptr, adj_idx,
                                                         adj_eid, orient, rec_key, rec_int, n_rec)
            continue
        t = max(tri_thr[a], tri_thr[b])  # >= the pair's current threshold (clearances only fall)
        if t <= 0.0 or not boxes_overlap(lo_cap, hi_cap, a, b):
            continue
        g2 = 0.0  # Euclidean gap of the boxes, as pair_terms computes it: a lower bound of the distance
        for d in range(3):
            gap = max(lo0[b, d] - hi0[a, d], lo0[a, d] - hi0[b, d], 0.0)
            g2 += gap * gap
        lb = np.sqrt(g2)
        if lb > 0.0 and lb * BOUND_SHRINK >= t:
            continue
        dd = 0.0
        for d in range(3):
            dd += (pts[a, d] - pts[b, d]) ** 2
        if dd < skip2:
            continue  # closer than cap at rest: near
        if near_index(near_ptr, near_b, a, b) >= 0 or shared_vertex_count(faces, a, b) > 0:
            continue
        thr = part_min(clear, part, faces, a, b, cap)
        if thr <= 0.0 or _far_gap(verts, faces, a, b, axes, inv, ax_lo, ax_hi) * BOUND_SHRINK >= thr:
            continue  # its distance >= the gap cannot lower a clearance
        evaluated, _, _, c = pair_terms(verts, faces, a, b, 0, -1, near_rest, scale, tau, gerr, cap, clear, part)
        if evaluated:
            lower_clearance(clear, part, faces, a, b, c)
    return n_pairs, rec_key, rec_int, n_rec


@njit(cache=True)
def far_thresholds(faces, active, clear, part, cap):
    """Per triangle, the largest clearance (capped) among its vertices' parts when the far pass starts; 0 for a
    triangle that is not ``active``."""
    n = faces.shape[0]
    tri_thr = np.zeros(n)
    for f in range(n):
        if active[f]:
            for i in range(3):
                tri_thr[f] = max(tri_thr[f], min(clear[part[faces[f, i]]], cap))
    return tri_thr


@njit(cache=True)
def far_pass(verts, faces, lo, hi, cell, lo0, hi0, lo_cap, hi_cap, active, pts, skip2, near_ptr, near_b, near_rest,
             axes, inv, ax_lo, ax_hi, scale, tau, gerr, cap, clear, floor, part, adj_ptr, adj_idx, adj_eid, orient,
             rec_key, rec_int, n_rec):
    """Every far pair (not adjacent, sharing no vertex, not in the near table) that matters, found with one
    uniform grid over the boxes ``lo``/``hi`` (grown by at least half the largest clearance still to beat):
    far pairs with overlapping boxes are evaluated in full (they may be counted), far pairs with disjoint
    boxes within cap lower the clearance (their term is the distance; only when a triangle is ``active``,
    i.e. some part of its vertices still has a clearance > 0, and the rest centroids ``pts`` are at least
    ``sqrt(skip2)`` apart: closer pairs are near). Each pair whose grown boxes overlap is found once (the cell of
    the lower corner of the two boxes' intersection) and treated by :func:`far_pairs`. The path of
    ``ExactLabeler(far_clusters=0)``; :func:`far_pass_clusters` finds the same pairs without visiting the adjacent
    and near ones.

    Returns:
        n_pairs (counted), rec_key, rec_int, n_rec.
    """
    grid = sorted_cells(lo, hi, cell)
    size = max(1024, 8 * lo.shape[0])
    while True:  # an output array that is not reallocated inside the sweep (which would slow the sweep down)
        cand = np.empty((size, 2), dtype=np.int64)
        n_cand = _grid_fill(cand, lo, hi, *grid)
        if n_cand >= 0:
            break
        size *= 4
    return far_pairs(verts, faces, cand, n_cand, lo0, hi0, lo_cap, hi_cap, far_thresholds(faces, active, clear, part,
                     cap), pts, skip2, near_ptr, near_b, near_rest, axes, inv, ax_lo, ax_hi, scale, tau, gerr, cap,
                     clear, floor, part, adj_ptr, adj_idx, adj_eid, orient, rec_key, rec_int, n_rec)


@njit(cache=True)
def _grid_fill(cand, lo, hi, cell_keys, cell_start, ids, ilo, dims):
    """The pairs (a < b) whose boxes ``lo``/``hi`` overlap, from the grid of
    :func:`~neuralcol.collision.kernels.broadphase.sorted_cells`, into ``cand``: their number, or -1 if ``cand`` is
    too short."""
    total = ids.shape[0]
    # the entries' boxes, contiguous per coordinate in entry order (each cell's entries by ascending lower x)
    xl = np.empty(total)
    xh = np.empty(total)
    yl = np.empty(total)
    yh = np.empty(total)
    zl = np.empty(total)
    zh = np.empty(total)
    for e in range(total):
        f = ids[e]
        xl[e] = lo[f, 0]
        xh[e] = hi[f, 0]
        yl[e] = lo[f, 1]
        yh[e] = hi[f, 1]
        zl[e] = lo[f, 2]
        zh[e] = hi[f, 2]
    m = 0
    for ci in range(cell_keys.shape[0]):
        start = cell_start[ci]
        end = cell_start[ci + 1]
        if end - start < 2:
            continue
        key = cell_keys[ci]
        cz = key % dims[2]
        cy = (key // dims[2]) % dims[1]
        cx = key // (dims[2] * dims[1])
        for i in range(start, end):
            a0 = ids[i]
            ax1 = xh[i]
            ay0 = yl[i]
            ay1 = yh[i]
            az0 = zl[i]
            az1 = zh[i]
            for j in range(i + 1, end):
                if xl[j] > ax1:
                    break  # this and every later entry of the cell start beyond a0's box in x
                if yl[j] > ay1 or ay0 > yh[j] or zl[j] > az1 or az0 > zh[j]:
                    continue  # (x overlaps: xl[i] <= xl[j] <= xh[i])
                b0 = ids[j]
                if (max(ilo[a0, 0], ilo[b0, 0]) != cx or max(ilo[a0, 1], ilo[b0, 1]) != cy
                        or max(ilo[a0, 2], ilo[b0, 2]) != cz):
                    continue
                if m == cand.shape[0]:
                    return -1
                cand[m, 0] = min(a0, b0)
                cand[m, 1] = max(a0, b0)
                m += 1
    return m


@njit(cache=True)
def far_pass_clusters(verts, faces, lo, hi, order, cl_ptr, rest_lo, rest_hi, blocks, masks, n_bits, cluster_cell, lo0,
                      hi0, lo_cap, hi_cap, active, pts, skip2, near_ptr, near_b, near_rest, axes, inv, ax_lo, ax_hi,
                      scale, tau, gerr, cap, clear, floor, part, adj_ptr, adj_idx, adj_eid, orient, rec_key, rec_int,
                      n_rec):
    """:func:`far_pass` with the rest mesh's clusters instead of a grid over every triangle: the candidates of
    :func:`~neuralcol.collision.kernels.clusters.cluster_candidates` (the pairs of the grid minus adjacent and near
    ones, which :func:`far_pairs` skips anyway), treated by :func:`far_pairs` in another order (the labels do not
    depend on it). The path of ``ExactLabeler(far_clusters > 0)``, the default.

    Returns:
        n_pairs (counted), rec_key, rec_int, n_rec.
    """
    cand = cluster_candidates(lo, hi, order, cl_ptr, rest_lo, rest_hi, blocks, masks, n_bits, cluster_cell)
    return far_pairs(verts, faces, cand, cand.shape[0], lo0, hi0, lo_cap, hi_cap, far_thresholds(faces, active, clear,
                     part, cap), pts, skip2, near_ptr, near_b, near_rest, axes, inv, ax_lo, ax_hi, scale, tau, gerr,
                     cap, clear, floor, part, adj_ptr, adj_idx, adj_eid, orient, rec_key, rec_int, n_rec)
