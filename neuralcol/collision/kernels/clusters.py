"""Triangle clusters of the far pass (:func:`~neuralcol.collision.kernels.pruned_pass.far_pass_clusters`): groups of
a few triangles that are close in the rest mesh, and the far triangle pairs of the cluster pairs whose rest boxes
overlap (the "blocks"), all fixed by the rest mesh and made once per labeler (``ExactLabeler(far_clusters=...)``).

Why: most triangle pairs whose boxes overlap in a posed mesh are neighbours at rest (sharing a vertex, or in the
near table: ~88 % of the pairs a grid over SCAPE's posed triangles meets), and a grid cannot tell them from far
pairs without a lookup per pair. Here the pairs of the blocks are listed once without the adjacent and near ones
(a bit mask per block), so per mesh they only get a box test, and a grid over the few cluster boxes finds the
cluster pairs that come close in the posed mesh only (the "moved" ones), whose pairs are all tested. Together they
hold every pair with overlapping boxes that is neither adjacent nor near, and of the others only those of moved
cluster pairs (:func:`cluster_candidates`; the far pass skips them as the grid path does).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from neuralcol.collision.kernels.broadphase import boxes_overlap, shared_vertex_count, sorted_cells
from neuralcol.collision.kernels.pair_terms import near_index


@njit(cache=True)
def rest_clusters(pts, size):
    """Triangles grouped by recursive median splits of their rest centroids ``pts`` (F, 3) along the longest axis
    of each group's centroid box, down to groups of at most ``size``; a split gives the lower half a multiple of
    ``size`` triangles, so all but a few groups hold exactly ``size``.

    Returns:
        order (F,) the triangles cluster by cluster (depth first: neighbouring clusters are mostly close),
        ptr (C + 1,) offsets of each cluster's triangles in ``order``.
    """
    n = pts.shape[0]
    order = np.arange(n)
    ptr = np.zeros(n + 1, dtype=np.int64)
    n_clusters = 0
    stack = np.empty((2 * n + 2, 2), dtype=np.int64)
    stack[0, 0] = 0
    stack[0, 1] = n
    top = 1
    while top > 0:
        top -= 1
        start = stack[top, 0]
        end = stack[top, 1]
        m = end - start
        k = (m + size - 1) // size  # clusters this group makes
        if k <= 1:
            if m > 0:
                n_clusters += 1
                ptr[n_clusters] = end
            continue
        axis = 0
        ext = -1.0
        for d in range(3):
            lo = np.inf
            hi = -np.inf
            for i in range(start, end):
                lo = min(lo, pts[order[i], d])
                hi = max(hi, pts[order[i], d])
            if hi - lo > ext:
                ext = hi - lo
                axis = d
        seg = order[start:end].copy()
        by = np.argsort(pts[seg, axis], kind="mergesort")
        order[start:end] = seg[by]
        mid = start + (k // 2) * size
        stack[top, 0] = mid  # upper half below the lower one on the stack: the lower half is done first
        stack[top, 1] = end
        stack[top + 1, 0] = start
        stack[top + 1, 1] = mid
        top += 2
    return order, ptr[:n_clusters + 1].copy()


@njit(cache=True)
def cluster_boxes(lo, hi, order, ptr):
    """Box of each cluster: the union of its triangles' boxes ``lo``/``hi`` (F, 3) -> (C, 3), (C, 3). A pair of
    triangle boxes that overlap lies in a pair of cluster boxes that overlap (min and max are exact)."""
    n_clusters = ptr.shape[0] - 1
    clo = np.empty((n_clusters, 3))
    chi = np.empty((n_clusters, 3))
    for c in range(n_clusters):
        for d in range(3):
            lo_d = np.inf
            hi_d = -np.inf
            for i in range(ptr[c], ptr[c + 1]):
                lo_d = min(lo_d, lo[order[i], d])
                hi_d = max(hi_d, hi[order[i], d])
            clo[c, d] = lo_d
            chi[c, d] = hi_d
    return clo, chi


@njit(cache=True)
def static_blocks(faces, order, ptr, cluster_pairs, near_ptr, near_b):
    """The far triangle pairs of the given cluster pairs (the pairs whose rest boxes overlap), as one bit mask per
    cluster pair: bit ``8 i + j`` of the mask of (c0, c1) is set iff the i-th triangle of c0 and the j-th of c1
    (j > i for c0 == c1) share no vertex and are not in the near table (CSR ``near_ptr``, ``near_b``). Clusters hold
    at most 8 triangles.

    Args:
        cluster_pairs: (S, 2) int64 cluster pairs c0 <= c1 (each once, the pairs (c, c) included).

    Returns:
        blocks (B, 2) int64 the cluster pairs with some far pair, masks (B,) int64 their bit masks.
    """
    blocks = np.empty((cluster_pairs.shape[0], 2), dtype=np.int64)
    masks = np.zeros(cluster_pairs.shape[0], dtype=np.int64)
    m = 0
    for s in range(cluster_pairs.shape[0]):
        c0 = cluster_pairs[s, 0]
        c1 = cluster_pairs[s, 1]
        mask = 0
        for i in range(ptr[c0], ptr[c0 + 1]):
            j0 = i + 1 if c0 == c1 else ptr[c1]
            for j in range(j0, ptr[c1 + 1]):
                a = min(order[i], order[j])
                b = max(order[i], order[j])
                if shared_vertex_count(faces, a, b) > 0 or near_index(near_ptr, near_b, a, b) >= 0:
                    continue
                mask |= np.int64(1) << (8 * (i - ptr[c0]) + (j - ptr[c1]))
        if mask != 0:
            blocks[m, 0] = c0
            blocks[m, 1] = c1
            masks[m] = mask
            m += 1
    return blocks[:m].copy(), masks[:m].copy()


@njit(cache=True)
def moved_cluster_pairs(clo, chi, cell, rest_lo, rest_hi):
    """Pairs c0 < c1 of cluster boxes ``clo``/``chi`` that overlap while their rest boxes ``rest_lo``/``rest_hi``
    do not (the pairs that are not blocks of :func:`static_blocks`): a uniform grid of ``cell``, swept along x in
    each cell (:func:`~neuralcol.collision.kernels.broadphase.sorted_cells`), each pair reported once, by the cell of
    the lower corner of the two boxes' intersection (as :func:`~neuralcol.collision.kernels.broadphase.grid_pairs`).

    Returns:
        (P, 2) int64 cluster pairs.
    """
    grid = sorted_cells(clo, chi, cell)
    size = max(64, 4 * clo.shape[0])
    while True:  # an output array that is not reallocated inside the sweep (which would slow the sweep down)
        out = np.empty((size, 2), dtype=np.int64)
        m = _moved_fill(out, clo, chi, rest_lo, rest_hi, *grid)
        if m >= 0:
            return out[:m]
        size *= 4


@njit(cache=True)
def _moved_fill(out, clo, chi, rest_lo, rest_hi, cell_keys, cell_start, ids, ilo, dims):
    """The sweep of :func:`moved_cluster_pairs` into ``out``: the number of pairs, or -1 if ``out`` is too short."""
    m = 0
    for ci in range(cell_keys.shape[0]):
        start = cell_start[ci]
        end = cell_start[ci + 1]
        key = cell_keys[ci]
        cz = key % dims[2]
        cy = (key // dims[2]) % dims[1]
        cx = key // (dims[2] * dims[1])
        for i in range(start, end):
            a0 = ids[i]
            for j in range(i + 1, end):
                b0 = ids[j]
                if clo[b0, 0] > chi[a0, 0]:
                    break  # this and every later entry of the cell start beyond a0's box in x
                if (clo[b0, 1] > chi[a0, 1] or clo[a0, 1] > chi[b0, 1] or clo[b0, 2] > chi[a0, 2]
                        or clo[a0, 2] > chi[b0, 2]):
                    continue
                if boxes_overlap(rest_lo, rest_hi, a0, b0):
                    continue  # a block of static_blocks
                if (max(ilo[a0, 0], ilo[b0, 0]) != cx or max(ilo[a0, 1], ilo[b0, 1]) != cy
                        or max(ilo[a0, 2], ilo[b0, 2]) != cz):
                    continue
                if m == out.shape[0]:
                    return -1
                out[m, 0] = min(a0, b0)
                out[m, 1] = max(a0, b0)
                m += 1
    return m


@njit(cache=True)
def cluster_candidates(lo, hi, order, ptr, rest_lo, rest_hi, blocks, masks, n_bits, cell):
    """Every pair (a < b) of triangles whose boxes ``lo``/``hi`` overlap, minus pairs that share a vertex or are near
    (the far pass's candidates, :func:`~neuralcol.collision.kernels.pruned_pass.far_pass_clusters`), found over the
    clusters ``order``/``ptr``: (P, 2) int64, the moved cluster pairs' first, then the blocks'.

    Each such pair lies in one cluster pair (c0, c1), c0 <= c1. If the clusters' rest boxes ``rest_lo``/``rest_hi``
    overlap (always for c0 == c1), the pair is a bit of the mask of (c0, c1) (``blocks``/``masks`` of
    :func:`static_blocks` for the cluster pairs with overlapping rest boxes; ``n_bits`` bits set in all) unless it
    shares a vertex or is near, and its boxes are tested here. Otherwise the clusters' boxes (unions of their
    triangles' boxes) overlap, so :func:`moved_cluster_pairs` (grid cell ``cell``) reports (c0, c1), and all its
    pairs are tested (pairs that share a vertex or are near may remain among those). Each pair is found once; the
    box test is :func:`~neuralcol.collision.kernels.broadphase.boxes_overlap`'s (negated, the same for finite
    values), so the pairs are exactly those of :func:`~neuralcol.collision.kernels.broadphase.grid_pairs`.
    """
    total = order.shape[0]
    ob = np.empty((total, 6))  # boxes in cluster order: lower x, y, z, upper x, y, z
    for i in range(total):
        f = order[i]
        for d in range(3):
            ob[i, d] = lo[f, d]
            ob[i, 3 + d] = hi[f, d]
    clo, chi = cluster_boxes(lo, hi, order, ptr)
    moved = moved_cluster_pairs(clo, chi, cell, rest_lo, rest_hi)
    size = n_bits
    for k in range(moved.shape[0]):
        size += (ptr[moved[k, 0] + 1] - ptr[moved[k, 0]]) * (ptr[moved[k, 1] + 1] - ptr[moved[k, 1]])
    cand = np.empty((size, 2), dtype=np.int64)  # long enough: no reallocation inside the loops
    n_cand = _cluster_fill(cand, ob, order, ptr, clo, chi, moved, blocks, masks)
    return cand[:n_cand]


@njit(cache=True, inline="always")
def _meets(x0, y0, z0, x1, y1, z1, lo, hi, j):
    """Whether the box (x0, y0, z0)-(x1, y1, z1) overlaps box j of ``lo``/``hi``: the comparisons of
    :func:`~neuralcol.collision.kernels.broadphase.boxes_overlap`, negated, without branches."""
    return ((x0 <= hi[j, 0]) & (lo[j, 0] <= x1) & (y0 <= hi[j, 1]) & (lo[j, 1] <= y1) & (z0 <= hi[j, 2])
            & (lo[j, 2] <= z1))


@njit(cache=True)
def _cluster_fill(cand, ob, order, ptr, clo, chi, moved, blocks, masks):
    """The loops of :func:`cluster_candidates` into ``cand`` (long enough): returns the number of pairs. A pair is
    written always and kept (the count advanced) if its boxes overlap, which avoids a hard-to-predict branch."""
    olo = ob[:, :3]
    ohi = ob[:, 3:]
    n_cand = 0
    for k in range(moved.shape[0]):
        c0 = moved[k, 0]
        c1 = moved[k, 1]
        for i in range(ptr[c0], ptr[c0 + 1]):
            x0, y0, z0, x1, y1, z1 = ob[i, 0], ob[i, 1], ob[i, 2], ob[i, 3], ob[i, 4], ob[i, 5]
            if not _meets(x0, y0, z0, x1, y1, z1, clo, chi, c1):
                continue  # meets no box of c1's triangles
            for j in range(ptr[c1], ptr[c1 + 1]):
                cand[n_cand, 0] = min(order[i], order[j])
                cand[n_cand, 1] = max(order[i], order[j])
                n_cand += _meets(x0, y0, z0, x1, y1, z1, olo, ohi, j)
    for k in range(blocks.shape[0]):
        c0 = blocks[k, 0]
        c1 = blocks[k, 1]
        if not _meets(clo[c0, 0], clo[c0, 1], clo[c0, 2], chi[c0, 0], chi[c0, 1], chi[c0, 2], clo, chi, c1):
            continue  # no two of their triangles' boxes overlap
        mask = masks[k]
        p0 = ptr[c0]
        p1 = ptr[c1]
        for i in range(p0, ptr[c0 + 1]):
            row = (mask >> (8 * (i - p0))) & 255
            if row == 0:
                continue
            x0, y0, z0, x1, y1, z1 = ob[i, 0], ob[i, 1], ob[i, 2], ob[i, 3], ob[i, 4], ob[i, 5]
            if not _meets(x0, y0, z0, x1, y1, z1, clo, chi, c1):
                continue
            for j in range(p1, ptr[c1 + 1]):
                cand[n_cand, 0] = min(order[i], order[j])
                cand[n_cand, 1] = max(order[i], order[j])
                n_cand += (((row >> (j - p1)) & 1) == 1) & _meets(x0, y0, z0, x1, y1, z1, olo, ohi, j)
    return n_cand
