"""Broadphase of the exact labeler: triangle boxes, the uniform grid that pairs overlapping boxes, and the
adjacency of two triangles (shared vertices)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def triangle_aabbs(verts, faces, inflate):
    """Axis-aligned boxes of all triangles, each grown by ``inflate`` on every side -> (F, 3), (F, 3)."""
    n = faces.shape[0]
    lo = np.empty((n, 3))
    hi = np.empty((n, 3))
    for f in range(n):
        for d in range(3):
            a = verts[faces[f, 0], d]
            b = verts[faces[f, 1], d]
            c = verts[faces[f, 2], d]
            lo[f, d] = min(a, b, c) - inflate
            hi[f, d] = max(a, b, c) + inflate
    return lo, hi


@njit(cache=True)
def grid_pairs(lo, hi, cell):
    """All pairs (a < b) of boxes that overlap, found with a uniform grid of cell size ``cell``.

    Each box is entered in every cell it touches; a pair is reported once, by the cell that holds the
    lower corner of the two boxes' intersection. Cost is linear in the number of boxes for boxes of
    bounded size.

    Returns:
        (P, 2) int64 pairs.
    """
    return grid_pairs_active(lo, hi, cell, np.ones(lo.shape[0], dtype=np.bool_), lo, -1.0)


@njit(cache=True)
def cell_ranges(lo, hi, cell):
    """The cells each box ``lo``/``hi`` (F, 3) spans in a uniform grid of ``cell`` anchored at the boxes' lower
    corner: ilo, ihi (F, 3) its first and last cell per axis, total (box, cell) entries, dims (3,) cells per axis."""
    n = lo.shape[0]
    origin = np.empty(3)
    for d in range(3):
        origin[d] = lo[:, d].min()
    inv = 1.0 / cell
    ilo = np.empty((n, 3), dtype=np.int64)
    ihi = np.empty((n, 3), dtype=np.int64)
    total = 0
    for f in range(n):
        cnt = 1
        for d in range(3):
            ilo[f, d] = int((lo[f, d] - origin[d]) * inv)
            ihi[f, d] = int((hi[f, d] - origin[d]) * inv)
            cnt *= ihi[f, d] - ilo[f, d] + 1
        total += cnt
    dims = np.empty(3, dtype=np.int64)
    for d in range(3):
        dims[d] = ihi[:, d].max() + 1
    return ilo, ihi, total, dims


@njit(cache=True)
def grid_cells(lo, hi, cell):
    """Boxes ``lo``/``hi`` (F, 3) binned into a uniform grid of ``cell``: one entry per (box, cell) it touches.

    Returns:
        keys (E,) cell keys in ascending order, ids (E,) the box of each entry, ilo (F, 3) each box's lower
        cell, dims (3,) cells per axis (key = (x * dims[1] + y) * dims[2] + z).
    """
    n = lo.shape[0]
    ilo, ihi, total, dims = cell_ranges(lo, hi, cell)
    keys = np.empty(total, dtype=np.int64)
    ids = np.empty(total, dtype=np.int64)
    k = 0
    for f in range(n):
        for x in range(ilo[f, 0], ihi[f, 0] + 1):
            for y in range(ilo[f, 1], ihi[f, 1] + 1):
                for z in range(ilo[f, 2], ihi[f, 2] + 1):
                    keys[k] = (x * dims[1] + y) * dims[2] + z
                    ids[k] = f
                    k += 1
    order = np.argsort(keys, kind="quicksort")
    keys = keys[order]
    ids = ids[order]
    return keys, ids, ilo, dims


@njit(cache=True)
def sorted_cells(lo, hi, cell):
    """Boxes ``lo``/``hi`` (F, 3) binned into a uniform grid of ``cell``, each cell's entries in ascending order of
    their box's lower x (ties: ascending box index), for a sweep along x that stops at the first entry starting
    beyond a box's end. A counting sort over the cells (a stable argsort of the keys when the grid is much larger
    than the number of entries); no per-cell sort.

    Returns:
        cell_keys (C,) the non-empty cells in ascending order, start (C + 1,) offsets of each cell's entries,
        ids (E,) the box of each entry, ilo (F, 3) each box's lower cell, dims (3,) cells per axis
        (key = (x * dims[1] + y) * dims[2] + z).
    """
    n = lo.shape[0]
    ilo, ihi, total, dims = cell_ranges(lo, hi, cell)
    n_cells = dims[0] * dims[1] * dims[2]
    order = np.argsort(lo[:, 0], kind="mergesort")
    ids = np.empty(total, dtype=np.int64)
    if n_cells <= 4 * total + 4096:
        count = np.zeros(n_cells + 1, dtype=np.int64)
        for f in range(n):
            for x in range(ilo[f, 0], ihi[f, 0] + 1):
                for y in range(ilo[f, 1], ihi[f, 1] + 1):
                    for z in range(ilo[f, 2], ihi[f, 2] + 1):
                        count[(x * dims[1] + y) * dims[2] + z + 1] += 1
        n_used = 0
        for c in range(n_cells):
            if count[c + 1] > 0:
                n_used += 1
            count[c + 1] += count[c]
        fill = count[:-1].copy()
        for k in range(n):
            f = order[k]
            for x in range(ilo[f, 0], ihi[f, 0] + 1):
                for y in range(ilo[f, 1], ihi[f, 1] + 1):
                    for z in range(ilo[f, 2], ihi[f, 2] + 1):
                        c = (x * dims[1] + y) * dims[2] + z
                        ids[fill[c]] = f
                        fill[c] += 1
        cell_keys = np.empty(n_used, dtype=np.int64)
        start = np.empty(n_used + 1, dtype=np.int64)
        m = 0
        for c in range(n_cells):
            if count[c + 1] > count[c]:
                cell_keys[m] = c
                start[m] = count[c]
                m += 1
        start[n_used] = total
        return cell_keys, start, ids, ilo, dims
    keys = np.empty(total, dtype=np.int64)
    k = 0
    for r in range(n):
        f = order[r]
        for x in range(ilo[f, 0], ihi[f, 0] + 1):
            for y in range(ilo[f, 1], ihi[f, 1] + 1):
                for z in range(ilo[f, 2], ihi[f, 2] + 1):
                    keys[k] = (x * dims[1] + y) * dims[2] + z
                    ids[k] = f
                    k += 1
    by_cell = np.argsort(keys, kind="mergesort")  # stable: each cell's entries stay in lower-x order
    keys = keys[by_cell]
    ids = ids[by_cell]
    n_used = 0
    for e in range(total):
        if e == 0 or keys[e] != keys[e - 1]:
            n_used += 1
    cell_keys = np.empty(n_used, dtype=np.int64)
    start = np.empty(n_used + 1, dtype=np.int64)
    m = 0
    for e in range(total):
        if e == 0 or keys[e] != keys[e - 1]:
            cell_keys[m] = keys[e]
            start[m] = e
            m += 1
    start[n_used] = total
    return cell_keys, start, ids, ilo, dims


@njit(cache=True)
def grid_pairs_active(lo, hi, cell, active, pts, skip2):
    """Like :func:`grid_pairs`, only the pairs with at least one box marked in ``active`` (F,) bool and whose
    points ``pts`` (F, 3) are at least ``sqrt(skip2)`` apart (``skip2 < 0``: no such filter)."""
    n = lo.shape[0]
    keys, ids, ilo, dims = grid_cells(lo, hi, cell)
    total = keys.shape[0]
    cap = max(16, 8 * n)
    out = np.empty((cap, 2), dtype=np.int64)
    m = 0
    start = 0
    while start < total:
        end = start + 1
        while end < total and keys[end] == keys[start]:
            end += 1
        key = keys[start]
        cz = key % dims[2]
        cy = (key // dims[2]) % dims[1]
        cx = key // (dims[2] * dims[1])
        for i in range(start, end):
            a = ids[i]
            for j in range(i + 1, end):
                b = ids[j]
                if not (active[a] or active[b]):
                    continue
                if skip2 >= 0.0:
                    dd = 0.0
                    for d in range(3):
                        dd += (pts[a, d] - pts[b, d]) ** 2
                    if dd < skip2:
                        continue
                ok = True
                for d in range(3):
                    if lo[a, d] > hi[b, d] or lo[b, d] > hi[a, d]:
                        ok = False
                        break
                if not ok:
                    continue
                # report in the cell of the lower corner of the intersection box only
                if (max(ilo[a, 0], ilo[b, 0]) != cx or max(ilo[a, 1], ilo[b, 1]) != cy
                        or max(ilo[a, 2], ilo[b, 2]) != cz):
                    continue
                if m == cap:
                    cap *= 2
                    grown = np.empty((cap, 2), dtype=np.int64)
                    grown[:m] = out[:m]
                    out = grown
                out[m, 0] = min(a, b)
                out[m, 1] = max(a, b)
                m += 1
        start = end
    return out[:m]


@njit(cache=True, inline="always")
def boxes_overlap(lo, hi, a, b):
    """The test of :func:`grid_pairs` (same comparisons, so the same pairs)."""
    for d in range(3):
        if lo[a, d] > hi[b, d] or lo[b, d] > hi[a, d]:
            return False
    return True


@njit(cache=True)
def shared_vertex_count(faces, a, b):
    """Number of vertices triangles a and b share (0, 1, 2 or 3)."""
    s = 0
    for i in range(3):
        for j in range(3):
            if faces[a, i] == faces[b, j]:
                s += 1
    return s


@njit(cache=True)
def drop_adjacent(faces, pairs):
    keep = np.empty(pairs.shape[0], dtype=np.bool_)
    for k in range(pairs.shape[0]):
        keep[k] = shared_vertex_count(faces, pairs[k, 0], pairs[k, 1]) < 2
    return pairs[keep]
