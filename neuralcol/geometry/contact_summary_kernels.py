"""Compiled kernels of :mod:`neuralcol.geometry.contact_summary`: the close-pair search (a hashed uniform grid), the
vertex normals, each mesh's summaries and the pair behind each minimum, the neighbour lists' matching and the smooth
form's count gradient. Pure functions of arrays; the module that uses them says what the summaries are.

Symbols: B meshes, V vertices, F faces, K sub-domains, P pairs.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True)
def is_near(near_ptr, near_idx, i, j):  # pragma: no cover (compiled)
    """Whether j is among the vertices near i (``near_idx[near_ptr[i]:near_ptr[i + 1]]``, sorted): a binary search."""
    lo, hi = near_ptr[i], near_ptr[i + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        if near_idx[mid] < j:
            lo = mid + 1
        else:
            hi = mid
    return lo < near_ptr[i + 1] and near_idx[lo] == j


@njit(cache=True)
def close_pairs_kernel(v, rest, radius, fold_ratio, near_ptr, near_idx, slack=0.0):  # pragma: no cover (compiled)
    """Close pairs (i < j) of one mesh: a hashed uniform grid of cell ``radius`` (memory O(V) however far the
    vertices spread), each vertex against its own cell and the 13 after it, then the distance, the fold rule
    (loosened by ``slack``: ``d < fold_ratio d_rest + slack``) and the hop rule
    (``near_idx[near_ptr[i]:near_ptr[i + 1]]``, sorted, the vertices near i)."""
    n = v.shape[0]
    lo = v[0].copy()
    for i in range(n):
        for c in range(3):
            lo[c] = min(lo[c], v[i, c])
    size = 1
    while size < 2 * n:
        size *= 2
    mask = size - 1
    cell = np.empty((n, 3), np.int64)
    bucket = np.empty(n, np.int64)
    for i in range(n):
        for c in range(3):
            cell[i, c] = int((v[i, c] - lo[c]) / radius)
        bucket[i] = ((cell[i, 0] * 73856093) ^ (cell[i, 1] * 19349663) ^ (cell[i, 2] * 83492791)) & mask
    start = np.zeros(size + 1, np.int64)  # counting sort by bucket: bucket h holds sorted slots start[h]:start[h + 1]
    for i in range(n):
        start[bucket[i] + 1] += 1
    for h in range(size):
        start[h + 1] += start[h]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        order[fill[bucket[i]]] = i
        fill[bucket[i]] += 1
    for h in range(size):  # within a bucket, its cells one after another (a bucket rarely holds two)
        for s in range(start[h] + 1, start[h + 1]):
            x = order[s]
            t = s
            while t > start[h] and (cell[order[t - 1], 0], cell[order[t - 1], 1], cell[order[t - 1], 2]) > (
                    cell[x, 0], cell[x, 1], cell[x, 2]):
                order[t] = order[t - 1]
                t -= 1
            order[t] = x
    pos = np.empty((n, 3))  # positions and cells in sorted order: the inner loops read memory in a row
    sc = np.empty((n, 3), np.int64)
    for s in range(n):
        for c in range(3):
            pos[s, c] = v[order[s], c]
            sc[s, c] = cell[order[s], c]
    r2 = radius * radius
    cap = 4 * n
    out = np.empty((cap, 2), np.int64)
    m = 0
    a0 = 0
    while a0 < n:  # the run a0:a1 of one cell, against its own cell and the 13 after it (each pair of cells once)
        ci0, ci1, ci2 = sc[a0, 0], sc[a0, 1], sc[a0, 2]
        a1 = a0 + 1
        while a1 < n and sc[a1, 0] == ci0 and sc[a1, 1] == ci1 and sc[a1, 2] == ci2:
            a1 += 1
        for o in range(13, 27):
            a, b, c = ci0 + o // 9 - 1, ci1 + (o // 3) % 3 - 1, ci2 + o % 3 - 1
            h = ((a * 73856093) ^ (b * 19349663) ^ (c * 83492791)) & mask
            b0 = start[h]
            while b0 < start[h + 1] and (sc[b0, 0] != a or sc[b0, 1] != b or sc[b0, 2] != c):
                b0 += 1
            b1 = b0
            while b1 < start[h + 1] and sc[b1, 0] == a and sc[b1, 1] == b and sc[b1, 2] == c:
                b1 += 1
            for si in range(a0, a1):
                i = order[si]
                for sj in range(si + 1 if o == 13 else b0, b1):
                    t0 = pos[sj, 0] - pos[si, 0]
                    t1 = pos[sj, 1] - pos[si, 1]
                    t2 = pos[sj, 2] - pos[si, 2]
                    d2 = t0 * t0 + t1 * t1 + t2 * t2
                    if d2 >= r2:
                        continue
                    j = order[sj]
                    u0 = rest[j, 0] - rest[i, 0]
                    u1 = rest[j, 1] - rest[i, 1]
                    u2 = rest[j, 2] - rest[i, 2]
                    lim = fold_ratio * np.sqrt(u0 * u0 + u1 * u1 + u2 * u2) + slack
                    if d2 >= lim * lim:
                        continue
                    if is_near(near_ptr, near_idx, i, j):
                        continue
                    if m == cap:
                        grown = np.empty((2 * cap, 2), np.int64)
                        grown[:m] = out[:m]
                        out, cap = grown, 2 * cap
                    out[m, 0] = min(i, j)
                    out[m, 1] = max(i, j)
                    m += 1
        a0 = a1
    return out[:m]


@njit(cache=True)
def normals_kernel(v, faces):  # pragma: no cover (compiled)
    """(V, 3) unit area-weighted vertex normals of one mesh, as :func:`vertex_normals_np`."""
    n = np.zeros_like(v)
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        e10, e11, e12 = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
        e20, e21, e22 = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
        x = e11 * e22 - e12 * e21
        y = e12 * e20 - e10 * e22
        z = e10 * e21 - e11 * e20
        n[a, 0] += x
        n[a, 1] += y
        n[a, 2] += z
        n[b, 0] += x
        n[b, 1] += y
        n[b, 2] += z
        n[c, 0] += x
        n[c, 1] += y
        n[c, 2] += z
    for i in range(v.shape[0]):
        length = np.sqrt(n[i, 0] ** 2 + n[i, 1] ** 2 + n[i, 2] ** 2)
        for c in range(3):
            n[i, c] = n[i, c] / length if length > 0 else 0.0
    return n


@njit(cache=True)
def summarize_pairs(v, pr, rest, radius, fold_ratio, faces, partition, clip, smooth, vals,
                    arg):  # pragma: no cover (compiled)
    """One mesh's summaries from pairs ``pr`` (P, 2) into ``vals`` (K, 4) and ``arg`` (K, 3, 2) (see
    :func:`summaries_kernel`); the pairs are checked against the distance and fold rules first, so candidates
    found with a looser rule (a neighbour list with a skin) give the same result as the close pairs themselves."""
    n_parts = vals.shape[0]
    for k in range(n_parts):
        vals[k, 0] = 0.0
        vals[k, 1] = 1.0
        vals[k, 2] = 1.0
        vals[k, 3] = clip
        for s in range(3):
            arg[k, s, 0] = -1
            arg[k, s, 1] = -1
    nrm = np.empty((0, 3))
    for p in range(pr.shape[0]):
        i, j = pr[p, 0], pr[p, 1]
        d2 = 0.0
        q2 = 0.0
        for e in range(3):
            t = v[j, e] - v[i, e]
            u = rest[j, e] - rest[i, e]
            d2 += t * t
            q2 += u * u
        lim = fold_ratio * np.sqrt(q2)
        if d2 >= radius * radius or d2 >= lim * lim:
            continue
        if nrm.shape[0] == 0:
            nrm = normals_kernel(v, faces)
        oi = 0.0
        oj = 0.0
        for e in range(3):
            t = v[j, e] - v[i, e]
            oi += t * nrm[i, e]
            oj -= t * nrm[j, e]
        d = np.sqrt(d2)
        ratio = d / np.sqrt(q2)
        dist = d / radius
        if oi <= oj:
            off, a, b = oi, i, j
        else:
            off, a, b = oj, j, i
        off = min(max(off / radius, -clip), clip)
        w = 1.0
        if smooth:  # the pair's weight falls to 0 where it stops being close: every summary continuous
            w = 1.0 - max(dist, ratio / fold_ratio)
            ratio = 1.0 - w * (1.0 - ratio)
            dist = 1.0 - w * (1.0 - dist)
            off = clip - w * (clip - off)
        for side in (i, j):
            k = partition[side]
            vals[k, 0] += w
            if ratio < vals[k, 1]:
                vals[k, 1] = ratio
                arg[k, 0, 0] = i
                arg[k, 0, 1] = j
            if dist < vals[k, 2]:
                vals[k, 2] = dist
                arg[k, 1, 0] = i
                arg[k, 1, 1] = j
            if off < vals[k, 3]:
                vals[k, 3] = off
                arg[k, 2, 0] = a
                arg[k, 2, 1] = b
    for k in range(n_parts):
        vals[k, 0] = np.log1p(vals[k, 0])


@njit(cache=True)
def sample_pairs(v, sample, rest_s, radius, fold_ratio, near_ptr, near_idx, slack):  # pragma: no cover
    """The close pairs among the vertices ``sample`` (ascending) of one mesh, numbered as the whole mesh's."""
    vs = np.empty((sample.shape[0], 3))
    for q in range(sample.shape[0]):
        for c in range(3):
            vs[q, c] = v[sample[q], c]
    pr = close_pairs_kernel(vs, rest_s, radius, fold_ratio, near_ptr, near_idx, slack)
    for p in range(pr.shape[0]):
        pr[p, 0] = sample[pr[p, 0]]
        pr[p, 1] = sample[pr[p, 1]]
    return pr


@njit(cache=True, parallel=True)
def summaries_kernel(vs, sample, rest_s, radius, fold_ratio, near_ptr, near_idx, rest, faces, partition, n_parts,
                     clip, smooth):  # pragma: no cover (compiled)
    """The summaries of meshes (B, V, 3) in one pass over each mesh's close pairs (among the vertices ``sample``):
    values (B, K, 4) as :meth:`~neuralcol.geometry.contact_summary.ContactSummary.summarize` gives them, and for
    the three minima the pair that attains each, (B, K, 3, 2) (-1 where a sub-domain has no close pair); for
    ``min_offset`` the pair is ordered (a, b) with the offset ``(x_b - x_a) . n_a``, the normal read at a."""
    vals = np.empty((vs.shape[0], n_parts, 4))
    arg = np.empty((vs.shape[0], n_parts, 3, 2), np.int64)
    for m in prange(vs.shape[0]):  # the meshes on every core (each its own: the same numbers on any count)
        pr = sample_pairs(vs[m], sample, rest_s, radius, fold_ratio, near_ptr, near_idx, 0.0)
        summarize_pairs(vs[m], pr, rest, radius, fold_ratio, faces, partition, clip, smooth, vals[m], arg[m])
    return vals, arg


@njit(cache=True, parallel=True)
def summaries_of_candidates(vs, cand, cand_ptr, rest, radius, fold_ratio, faces, partition, n_parts,
                            clip, smooth):  # pragma: no cover (compiled)
    """:func:`summaries_kernel` with each mesh's pairs taken from candidates, mesh m's ``cand[cand_ptr[m]:
    cand_ptr[m + 1]]`` (a superset of its close pairs)."""
    vals = np.empty((vs.shape[0], n_parts, 4))
    arg = np.empty((vs.shape[0], n_parts, 3, 2), np.int64)
    for m in prange(vs.shape[0]):
        summarize_pairs(vs[m], cand[cand_ptr[m]:cand_ptr[m + 1]], rest, radius, fold_ratio, faces, partition,
                         clip, smooth, vals[m], arg[m])
    return vals, arg


@njit(cache=True)
def match_kernel(vs, meshes, sigs, sig_idx, n_stored, guess, half2):  # pragma: no cover (compiled)
    """For each mesh of ``vs`` (B, V, 3), a stored mesh (of the first ``n_stored``) whose every vertex lies within
    ``sqrt(half2)`` of it, or -1: first the guess, then the one nearest on the signature vertices."""
    b, n = vs.shape[0], vs.shape[1]
    pick = np.full(b, -1, np.int64)
    for m in range(b):
        for attempt in range(2):
            e = guess[m] if attempt == 0 else -1
            if attempt == 0 and (e < 0 or e >= n_stored):
                continue
            if attempt == 1:
                best = half2
                for c in range(n_stored):
                    gap = 0.0
                    for q in range(sig_idx.shape[0]):
                        w = sig_idx[q]
                        d2 = ((vs[m, w, 0] - sigs[c, 3 * q]) ** 2 + (vs[m, w, 1] - sigs[c, 3 * q + 1]) ** 2
                              + (vs[m, w, 2] - sigs[c, 3 * q + 2]) ** 2)
                        gap = max(gap, d2)
                        if gap >= best:
                            break
                    if gap < best:
                        best, e = gap, c
                if e < 0:
                    break
            ok = True
            for i in range(n):
                d2 = ((vs[m, i, 0] - meshes[e, i, 0]) ** 2 + (vs[m, i, 1] - meshes[e, i, 1]) ** 2
                      + (vs[m, i, 2] - meshes[e, i, 2]) ** 2)
                if d2 >= half2:
                    ok = False
                    break
            if ok:
                pick[m] = e
                break
    return pick


@njit(cache=True)
def batch_pairs(vs, sample, rest_s, radius, fold_ratio, near_ptr, near_idx):  # pragma: no cover (compiled)
    """Every mesh's close pairs, concatenated (Q, 2), and offsets (B + 1,): mesh m's are ``[ptr[m]:ptr[m + 1]]``."""
    found = [sample_pairs(vs[m], sample, rest_s, radius, fold_ratio, near_ptr, near_idx, 0.0)
             for m in range(vs.shape[0])]
    ptr = np.zeros(vs.shape[0] + 1, np.int64)
    for m in range(vs.shape[0]):
        ptr[m + 1] = ptr[m] + found[m].shape[0]
    out = np.empty((ptr[-1], 2), np.int64)
    for m in range(vs.shape[0]):
        out[ptr[m]:ptr[m + 1]] = found[m]
    return out, ptr


@njit(cache=True)
def soft_count_grad(vs, cand, ptr, rest, radius, fold_ratio, partition, coef):  # pragma: no cover (compiled)
    """The gradient (B, V, 3) of ``sum_{m,k} coef[m, k] * S[m, k]``, S the smooth form's weighted count of
    sub-domain k of mesh m over its close pairs (among the candidates ``cand[ptr[m]:ptr[m + 1]]``): each pair's
    weight ``1 - max(d / radius, d / (fold_ratio d_rest))`` falls with its distance d."""
    grad = np.zeros_like(vs)
    for m in range(vs.shape[0]):
        v = vs[m]
        for p in range(ptr[m], ptr[m + 1]):
            i, j = cand[p, 0], cand[p, 1]
            d2 = 0.0
            q2 = 0.0
            for e in range(3):
                d2 += (v[j, e] - v[i, e]) ** 2
                q2 += (rest[j, e] - rest[i, e]) ** 2
            lim = fold_ratio * np.sqrt(q2)
            if d2 >= radius * radius or d2 >= lim * lim:
                continue
            d = np.sqrt(d2)
            slope = 1.0 / radius if d / radius >= d / lim else 1.0 / lim  # d(1 - weight) / dd
            g = (coef[m, partition[i]] + coef[m, partition[j]]) * slope / d
            for e in range(3):
                t = g * (v[j, e] - v[i, e])
                grad[m, j, e] -= t
                grad[m, i, e] += t
    return grad
