"""Contact repair: remove what self-penetration is left on a mesh, guided by the exact labeler's contacts.

The neural handler moves a code (or a mesh) to where the *detector* calls it free; where the exact labeler
still finds intersecting triangles (the detector erred, or the correction transferred to the user's mesh left
a small overlap), this pushes the two surfaces of every intersecting triangle pair apart and asks the labeler
again (``resolve`` returns the user's mesh collision-free by the exact label, moving as little of it
as it can). It is our addition, never part of the paper's detector-guided numbers: results report it as its
own stage.

One iteration, for every intersecting triangle pair ``(f, g)`` the labeler counts:

* each vertex ``x`` of ``f`` gets the offset ``s = (x - g_0) . n_g`` from ``g``'s plane; on a closed mesh
  ``n_g`` is the outward normal and a vertex with ``s < delta`` (inside, or closer than ``delta``) is pushed
  along ``n_g`` by half of ``delta - s``; on an open mesh the side of ``g`` holding most of ``f`` is the
  target side. The same for ``g``'s vertices against ``f``'s plane (the other half);
* the pushes of a vertex are averaged, spread over the surface by ``smooth_steps`` steps of a symmetric
  normalised-adjacency diffusion (neighbours move along, so no spike or fold is made) and rescaled so the
  largest push is kept;
* the mesh moves by that field; iterations stop when the labeler finds no pair, or after ``max_iter``.

Pure numpy and scipy; the labeler is any object with ``intersecting_pairs(vertices) -> (P, 2)`` triangle
pairs (:class:`~neuralcol.collision.labeler.ExactLabeler`, :class:`~neuralcol.collision.fcl_labeler.FCLLabeler`).

Symbols: V vertices, F faces, P intersecting triangle pairs.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from neuralcol.geometry.topology import edge_adjacency


def outward_sign(faces: np.ndarray, vertices: np.ndarray) -> float:
    """+1 / -1 if the faces of a closed mesh are wound outward / inward (signed volume), 0 for an open mesh."""
    f = np.asarray(faces, np.int64)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    if not (counts == 2).all():
        return 0.0
    v = np.asarray(vertices, np.float64)
    vol = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum()
    return 1.0 if vol >= 0 else -1.0


def diffusion_operator(faces: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """(V, V) symmetric normalised adjacency with self loops, ``D^-1/2 (A + I) D^-1/2`` (one smoothing step)."""
    a = edge_adjacency(faces, n_vertices, self_loops=True)
    d = 1.0 / np.sqrt(np.asarray(a.sum(1)).ravel())
    return (sp.diags(d) @ a @ sp.diags(d)).tocsr()


def contact_push(vertices: np.ndarray, faces: np.ndarray, pairs: np.ndarray, delta: float,
                 sign: float) -> np.ndarray:
    """(V, 3) push that separates every intersecting triangle pair by ``delta`` (see the module docstring).

    Args:
        vertices: (V, 3). faces: (F, 3). pairs: (P, 2) intersecting triangle pairs.
        delta: the separation asked for (mesh units).
        sign: :func:`outward_sign` of the mesh (0: open mesh, majority side).
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    push = np.zeros_like(v)
    count = np.zeros(len(v))
    if len(pairs) == 0:
        return push
    for a, b in ((pairs[:, 0], pairs[:, 1]), (pairs[:, 1], pairs[:, 0])):
        tb = v[f[b]]  # (P, 3, 3)
        n = np.cross(tb[:, 1] - tb[:, 0], tb[:, 2] - tb[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        s = np.einsum("pkj,pj->pk", v[f[a]] - tb[:, :1], n)  # (P, 3) offsets of a's vertices from b's plane
        side = np.full(len(pairs), float(sign)) if sign != 0 else np.where(s.sum(1) >= 0, 1.0, -1.0)
        need = np.maximum(delta - side[:, None] * s, 0.0)  # how far each vertex must go to the target side
        move = 0.5 * need[..., None] * (side[:, None, None] * n[:, None, :])  # (P, 3, 3), half each side
        np.add.at(push, f[a].ravel(), move.reshape(-1, 3))
        np.add.at(count, f[a].ravel(), (need > 0).ravel().astype(np.float64))
    return push / np.maximum(count, 1.0)[:, None]


class Repair(NamedTuple):
    """:func:`repair_contacts` of one mesh: vertices (V, 3) float64; resolved (the labeler finds no pair);
    iterations used; pairs_per_iteration (list of the pair counts seen, the first is the input's)."""

    vertices: np.ndarray
    resolved: bool
    iterations: int
    pairs_per_iteration: list


def repair_contacts(vertices: np.ndarray, faces: np.ndarray, labeler, delta: float, smooth_steps: int = 4,
                    max_iter: int = 30, sign: float | None = None, operator: sp.csr_matrix | None = None,
                    max_step: float | None = None, max_smooth: int | None = None, patience: int = 3) -> Repair:
    """Push the surfaces of a mesh's intersecting triangle pairs apart until the labeler finds none.

    Args:
        vertices: (V, 3) the mesh. faces: (F, 3).
        labeler: has ``intersecting_pairs(vertices) -> (P, 2)``.
        delta: separation asked for per pair (mesh units; a few of the labeler's eps).
        smooth_steps: diffusion steps the push is spread by at first (0: only the pair vertices move).
        max_iter: iterations at most.
        sign: :func:`outward_sign` (default: computed from ``vertices``).
        operator: :func:`diffusion_operator` if already built.
        max_step: no vertex moves more than this per iteration (mesh units; None: no cap).
        max_smooth: when the pair count has not fallen for ``patience`` iterations the diffusion steps double,
            up to this (a deep penetration then moves as a larger piece); None: ``smooth_steps`` throughout.
        patience: see ``max_smooth``.
    """
    v = np.array(vertices, np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"repair_contacts: vertices have shape {v.shape}, expected (V, 3)")
    if delta <= 0 or max_iter < 0 or smooth_steps < 0 or (max_step is not None and max_step <= 0):
        raise ValueError(f"repair_contacts: need delta > 0, max_iter >= 0, smooth_steps >= 0, max_step > 0 "
                         f"(got {delta}, {max_iter}, {smooth_steps}, {max_step})")
    sign = outward_sign(faces, v) if sign is None else float(sign)
    top = smooth_steps if max_smooth is None else max(int(max_smooth), smooth_steps)
    w = diffusion_operator(faces, len(v)) if operator is None and top else operator
    steps, best, stall = int(smooth_steps), np.inf, 0
    seen = []
    for it in range(max_iter + 1):
        pairs = np.asarray(labeler.intersecting_pairs(v)).reshape(-1, 2)
        seen.append(int(len(pairs)))
        if len(pairs) == 0:
            return Repair(v, True, it, seen)
        if it == max_iter:
            break
        if len(pairs) < best:
            best, stall = len(pairs), 0
        else:
            stall += 1
            if stall >= patience and steps < top:
                steps, stall = min(max(2 * steps, 1), top), 0
        push = contact_push(v, faces, pairs, delta, sign)
        peak = np.linalg.norm(push, axis=1).max()
        dx = push
        for _ in range(steps):
            dx = w @ dx
        spread = np.linalg.norm(dx, axis=1).max()
        if spread > 0:
            dx *= (peak if max_step is None else min(peak, max_step)) / spread
        v += dx
    return Repair(v, False, max_iter, seen)
