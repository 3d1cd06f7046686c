"""Quad meshes: box-lattice construction, patch boundaries, Catmull-Clark subdivision and triangulation.

Pure numpy functions on ``verts (V, D) float`` (positions in the first 3 columns) and ``quads (Q, 4) int``
(counter-clockwise seen from outside). Used by the procedural hand (:mod:`neuralcol.data.procedural.hand`).
"""

from __future__ import annotations

import numpy as np


def box_lattice(xs: np.ndarray, ys: np.ndarray, zs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface quads of a box lattice with outward orientation.

    Args:
        xs, ys, zs: (n_a + 1,) increasing lattice coordinates along each axis.

    Returns:
        verts (V, 3), quads (Q, 4) int64 (counter-clockwise seen from outside), grid (nx+1, ny+1, nz+1)
        int64 vertex index of each lattice point (-1 inside).
    """
    coords = (xs, ys, zs)
    n = tuple(len(c) - 1 for c in coords)
    ii, jj, kk = np.meshgrid(*(np.arange(m + 1) for m in n), indexing="ij")
    surf = (ii == 0) | (ii == n[0]) | (jj == 0) | (jj == n[1]) | (kk == 0) | (kk == n[2])
    grid = np.full(surf.shape, -1, dtype=np.int64)
    grid[surf] = np.arange(int(surf.sum()))
    verts = np.stack([xs[ii[surf]], ys[jj[surf]], zs[kk[surf]]], axis=-1)
    quads = []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        ib, ic = (m.ravel() for m in np.meshgrid(np.arange(n[b]), np.arange(n[c]), indexing="ij"))
        for side, sign in ((0, -1), (n[a], 1)):
            def at(db: int, dc: int, side=side, ib=ib, ic=ic, a=a, b=b, c=c) -> np.ndarray:
                idx = [None, None, None]
                idx[a], idx[b], idx[c] = np.full_like(ib, side), ib + db, ic + dc
                return grid[idx[0], idx[1], idx[2]]

            q = np.stack([at(0, 0), at(1, 0), at(1, 1), at(0, 1)], axis=1)  # normal e_b x e_c = +e_a
            quads.append(q if sign > 0 else q[:, ::-1])
    return verts, np.concatenate(quads).astype(np.int64), grid


def patch_boundary_loop(quads: np.ndarray, patch: np.ndarray) -> np.ndarray:
    """Boundary loop of a quad patch, in the patch's orientation.

    Args:
        quads: (Q, 4) all quads.
        patch: (P,) indices into quads forming a disk.

    Returns:
        (L,) int64 vertex indices, starting at the smallest; the patch quads traverse edge
        loop[j] -> loop[j+1].

    Raises:
        ValueError: the patch boundary is not a single loop.
    """
    q = quads[patch]
    half = np.stack([q, np.roll(q, -1, axis=1)], axis=-1).reshape(-1, 2)
    hs = {tuple(h) for h in half.tolist()}
    nxt = {a: b for a, b in half.tolist() if (b, a) not in hs}
    start = min(nxt)
    loop = [start]
    while nxt[loop[-1]] != start:
        loop.append(nxt[loop[-1]])
        if len(loop) > len(nxt):
            raise ValueError("patch boundary is not a single loop")
    return np.asarray(loop, dtype=np.int64)


def catmull_clark(verts: np.ndarray, quads: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One Catmull-Clark step on a closed quad mesh; also subdivides any extra vertex attributes.

    Args:
        verts: (V, D) float, positions in the first 3 columns (all columns are subdivided linearly).
        quads: (Q, 4) int, closed 2-manifold.

    Returns:
        verts (V + E + Q, D) ordered [vertex points, edge points, face points], quads (4 Q, 4) int64.

    Raises:
        ValueError: an edge does not have exactly two quads.
    """
    nv, nq = len(verts), len(quads)
    half = np.stack([quads, np.roll(quads, -1, axis=1)], axis=-1).reshape(-1, 2)  # (4Q, 2)
    edges, inv = np.unique(np.sort(half, axis=1), axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    ne = len(edges)
    if not np.all(np.bincount(inv, minlength=ne) == 2):
        raise ValueError("catmull_clark: control mesh is not closed 2-manifold (an edge without two quads)")
    fp = verts[quads].mean(axis=1)  # (Q, D)
    fsum = np.zeros((ne, verts.shape[1]))
    np.add.at(fsum, inv, np.repeat(fp, 4, axis=0))
    ep = (verts[edges[:, 0]] + verts[edges[:, 1]] + fsum) / 4.0
    val = np.bincount(edges.ravel(), minlength=nv).astype(np.float64)  # valence = incident faces (closed)
    qsum = np.zeros_like(verts)
    np.add.at(qsum, quads.ravel(), np.repeat(fp, 4, axis=0))
    mid = 0.5 * (verts[edges[:, 0]] + verts[edges[:, 1]])
    rsum = np.zeros_like(verts)
    np.add.at(rsum, edges[:, 0], mid)
    np.add.at(rsum, edges[:, 1], mid)
    n = val[:, None]
    vp = (qsum / n + 2.0 * rsum / n + (n - 3.0) * verts) / n
    e_of = inv.reshape(nq, 4)  # edge (c, c+1) of each quad corner c
    fidx = nv + ne + np.arange(nq)
    new_quads = np.concatenate(
        [np.stack([quads[:, c], nv + e_of[:, c], fidx, nv + e_of[:, (c - 1) % 4]], axis=1) for c in range(4)]
    )
    return np.concatenate([vp, ep, fp]), new_quads.astype(np.int64)


def triangulate_quads(verts: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Split every quad along its shorter diagonal.

    Args:
        verts: (V, 3) float positions.
        quads: (Q, 4) int.

    Returns:
        (2 Q, 3) int64 faces: the first triangles of all quads, then the second ones (same orientation).
    """
    a, b, c, d = quads.T
    d_ac = np.linalg.norm(verts[a] - verts[c], axis=1)
    d_bd = np.linalg.norm(verts[b] - verts[d], axis=1)
    use_ac = (d_ac <= d_bd)[:, None]
    t1 = np.where(use_ac, np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    t2 = np.where(use_ac, np.stack([a, c, d], 1), np.stack([b, c, d], 1))
    return np.concatenate([t1, t2]).astype(np.int64)
