"""Untangling a self-intersecting mesh: the region push, then intersection contour minimisation, as smooth fields.

**Region push**: move every penetrating region of a mesh out of the volume it entered, as one smooth field.

The contact repair (:mod:`neuralcol.repair.contact`) pushes the two triangles of each intersecting pair
apart; a deep penetration (an arm in the torso, a thigh in a calf) has its intersecting triangles along the
intersection curve only, and pushing them crumples the surface into new contacts. The exact labeler knows more:
on a closed mesh the flood fill bounded by the intersection curves gives every vertex inside another part's
volume and the nearest point of the surface it must come back through
(:meth:`~neuralcol.collision.labeler.ExactLabeler.penetrations`). One iteration:

* each penetrating vertex ``i`` gets the target ``t_i = share * (x_i* - x_i) + delta * u_i`` (``x_i*`` the nearest
  opposing point, ``u_i`` the unit direction towards it): both sides of a contact move, each by ``share`` of the
  way (1/2 meets in the middle) plus a separation ``delta``;
* the displacement field ``d`` (V, 3) minimises ``hold * sum_i |d_i - t_i|^2 + stiffness * sum_edges |d_i - d_j|^2
  + anchor * |d|^2`` over the whole mesh: a smooth field that meets the targets and dies out over the surface around
  them (about ``sqrt(stiffness / anchor)`` rings), one sparse solve of three right-hand sides;
* the mesh moves by ``d``; iterations stop when the labeler counts no pair, or after ``max_iter``.

On a mesh with boundary (cloth) and in local folds there are no enclosed regions: contour minimisation takes over.

**Contour minimisation** (ICM, Volino & Magnenat-Thalmann, "Resolving surface collisions through intersection
contour minimization", SIGGRAPH 2006): where no region is enclosed (local folds, cloth, what the push leaves), every
counted pair's intersection segment (between its two edge/triangle crossing points) has a length; the gradient of
their sum moves the surfaces so that the intersection curves shrink until they vanish, whatever their depth. Its
step: the gradient scaled so that the largest move is ``contour_step`` mean edge lengths, spread by the same smooth
field. Pairs whose crossings do not give two points (touching, coplanar) contribute nothing. The step adapts: x1.3
while the total length falls, x0.8 when it rises; and regions shallower than ``min_push`` edge lengths are left to it
(a push of a one-vertex region moved that vertex alone and left the curves around it untouched, step after step).
Together, on SCAPE's colliding realistic meshes (seed-0 run), freed 67.5 -> 80 % of the first 40 (tuned there and on
proc_cloth's first 60) and 72.5 -> 78.8 % of the next 80 (held out).

Symbols: V vertices, F faces, P intersecting pairs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch

from neuralcol.geometry.topology import edge_adjacency


class Untangled(NamedTuple):
    """:func:`untangle` of one mesh: vertices (V, 3) float64; resolved (the labeler finds no pair); iterations used;
    pairs_per_iteration (the pair counts seen, the first is the input's)."""

    vertices: np.ndarray
    resolved: bool
    iterations: int
    pairs_per_iteration: list


@dataclass(frozen=True)
class UntangleSettings:
    """Settings of :func:`untangle` (``handler.repair`` with ``method: untangle``, conf/handler/default.yaml)."""

    share: float = 0.5  # region push: the fraction of the way to the opposing surface a penetrating vertex moves
    delta: float = 0.25  # region push: separation beyond it, in mean edge lengths
    contour_step: float = 0.1  # contour minimisation: the first step's largest move, in mean edge lengths
    contour_max: float = 1.0  # the step grows x contour_grow while the contour length falls, up to this
    contour_min: float = 0.02  # and shrinks x contour_shrink when it rises, down to this
    contour_grow: float = 1.3
    contour_shrink: float = 0.8
    min_push: float = 0.3  # region push only while an enclosed vertex lies deeper than this (mean edge lengths)
    hold: float = 10.0  # weight of a target against the smoothness
    stiffness: float = 1.0  # weight of the membrane term sum over edges |d_i - d_j|^2
    anchor: float = 0.05  # weight of |d|^2: what no target reaches stays put (falloff ~ sqrt(stiffness / anchor))
    max_region: float = 0.3  # a flood-filled region with more of the vertices is the outside of an open curve
    max_iter: int = 80
    extra_iter: int = 160  # past max_iter, go on (0: never) while the fewest pairs of the last `window`
    window: int = 40       # iterations is below `progress` x the fewest before them
    progress: float = 0.9

    def __post_init__(self):
        steps_ok = 0 < self.contour_min <= self.contour_step <= self.contour_max
        if not (0 < self.share <= 1 and self.delta >= 0 and steps_ok and self.contour_grow >= 1
                and 0 < self.contour_shrink <= 1 and self.min_push >= 0 and self.hold > 0
                and self.stiffness >= 0 and self.anchor > 0 and 0 < self.max_region <= 1 and self.max_iter >= 0
                and self.extra_iter >= 0 and self.window >= 1 and 0 < self.progress <= 1):
            raise ValueError(f"handler.repair (untangle): need 0 < share <= 1, delta >= 0, 0 < contour_min <= "
                             f"contour_step <= contour_max, contour_grow >= 1, 0 < contour_shrink <= 1, min_push >= 0, "
                             f"hold > 0, stiffness >= 0, anchor > 0, 0 < max_region <= 1, max_iter >= 0, "
                             f"extra_iter >= 0, window >= 1, 0 < progress <= 1; got {self}")


def edge_laplacian(faces: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """(V, V) graph Laplacian ``D - A`` of the mesh's edges: ``d^T (D - A) d`` = sum over edges of
    ``|d_i - d_j|^2`` (per coordinate)."""
    a = edge_adjacency(faces, n_vertices)
    return (sp.diags(np.asarray(a.sum(1)).ravel()) - a).tocsr()


class SmoothField:
    """The quadratic form ``stiffness * (D - A) + anchor * I`` of one topology (a membrane: the field has no
    overshoot, unlike a thin plate's ``|L d|^2``, which bulged nearby surfaces into new contacts in the probes),
    and the field that meets targets on some vertices: :meth:`solve`."""

    # The field decays by about e per sqrt(stiffness / anchor) edge rings away from its targets; past this many
    # such lengths it is below ~1e-6 of the targets' moves (measured: 1e-5 at 12 lengths on a fine sphere), so the
    # solve can leave those vertices out.
    REACH = 14.0
    # ... and does, where the vertices within reach are fewer than this share of the mesh (large meshes with local
    # collisions: the factorisation is then of the neighbourhood, not of the whole mesh).
    LOCAL_SHARE = 0.5

    def __init__(self, faces: np.ndarray, n_vertices: int, stiffness: float, anchor: float):
        self.base = (stiffness * edge_laplacian(faces, n_vertices) + anchor * sp.eye(n_vertices)).tocsc()
        self.rings = int(np.ceil(self.REACH * np.sqrt(stiffness / anchor)))
        self._adjacency = None

    def within_reach(self, index: np.ndarray) -> np.ndarray:
        """(V,) bool: the vertices within :attr:`rings` edge rings of ``index``."""
        if self._adjacency is None:
            self._adjacency = (self.base != 0).astype(np.int8).tocsr()
        near = np.zeros(self.base.shape[0], bool)
        near[index] = True
        front = near.copy()
        for _ in range(self.rings):
            front = (self._adjacency @ front.astype(np.int8)) > 0
            front &= ~near
            if not front.any():
                break
            near |= front
        return near

    def solve(self, index: np.ndarray, targets: np.ndarray, hold: float = 1.0) -> np.ndarray:
        """(V, 3) field minimising ``hold * sum_k |d[index[k]] - targets[k]|^2`` plus the form. Where the vertices
        within reach of the targets (:attr:`REACH` decay lengths) are fewer than :attr:`LOCAL_SHARE` of the mesh,
        the field is solved on those alone, zero beyond (the vertices there stay exactly where they are);
        otherwise on the whole mesh."""
        n = self.base.shape[0]
        w = np.zeros(n)
        w[index] = hold
        rhs = np.zeros((n, 3))
        np.add.at(rhs, index, hold * targets)
        system = self.base + sp.diags(w)
        keep = self.within_reach(index) if n > 1000 else None
        if keep is not None and keep.sum() < self.LOCAL_SHARE * n:
            sub = np.flatnonzero(keep)
            out = np.zeros((n, 3))
            out[sub] = _factor(system[sub][:, sub]).solve(rhs[sub])
            return out
        return _factor(system).solve(rhs)


def _factor(system: sp.spmatrix):
    """The sparse LU of a symmetric positive definite system (the symmetric ordering: 25 % faster than COLAMD on
    anny_body)."""
    return spla.splu(sp.csc_matrix(system), permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})


def push_targets(vector: np.ndarray, share: float, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """The penetrating vertices (those with a nonzero vector) and their targets (see the module docstring)."""
    norm = np.linalg.norm(vector, axis=1)
    index = np.flatnonzero(norm > 0)
    unit = vector[index] / norm[index, None]
    return index, share * vector[index] + delta * unit


def _crossings(p, q, a, b, c):
    """Points where the segments p -> q (P, 3) cross the triangles abc (P, 3 each), and whether they do."""
    n = torch.cross(b - a, c - a, dim=-1)
    sp, sq = ((p - a) * n).sum(-1), ((q - a) * n).sum(-1)
    den = sp - sq
    t = sp / torch.where(den != 0, den, torch.ones_like(den))
    x = p + t[:, None] * (q - p)
    ok = sp * sq < 0
    for u, w in ((a, b), (b, c), (c, a)):
        ok = ok & ((torch.cross(w - u, x - u, dim=-1) * n).sum(-1) >= 0)
    return x, ok


def contour_gradient(vertices: np.ndarray, faces: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, float]:
    """Gradient (V, 3) of the total length of the intersection segments of ``pairs`` (P, 2) with respect to the
    vertices, and that length. A pair's segment joins the two farthest of its edge/triangle crossing points and,
    for a pair sharing a vertex, that vertex."""
    v = torch.tensor(np.asarray(vertices, np.float64), requires_grad=True)
    f = torch.as_tensor(np.asarray(faces, np.int64))
    pairs = torch.as_tensor(np.asarray(pairs, np.int64)).reshape(-1, 2)
    if len(pairs) == 0:
        return np.zeros(tuple(v.shape)), 0.0
    tf, tg = v[f[pairs[:, 0]]], v[f[pairs[:, 1]]]
    pts, oks = [], []
    for t, u in ((tf, tg), (tg, tf)):
        for i in range(3):
            x, ok = _crossings(t[:, i], t[:, (i + 1) % 3], u[:, 0], u[:, 1], u[:, 2])
            pts.append(x)
            oks.append(ok)
    fa, fb = f[pairs[:, 0]], f[pairs[:, 1]]
    eq = fa[:, :, None] == fb[:, None, :]  # (P, 3, 3): a pair sharing a vertex (not an edge) meets the other
    shared = fa.gather(1, eq.any(2).int().argmax(1, keepdim=True))[:, 0]  # triangle's plane there: its segment
    pts.append(v[shared])  # runs from that vertex to one crossing point (no edge from the vertex crosses)
    oks.append(eq.any((1, 2)))
    x, ok = torch.stack(pts, 1), torch.stack(oks, 1)  # (P, 7, 3), (P, 7)
    dist = torch.cdist(x, x)
    dist = torch.where(ok[:, :, None] & ok[:, None, :], dist, torch.zeros_like(dist))
    length = dist.flatten(1).max(1).values.sum()
    if not length.requires_grad:  # no pair has two crossing points
        return np.zeros(tuple(v.shape)), 0.0
    length.backward()
    return v.grad.numpy(), float(length.detach())


def still_falling(seen: list, settings: UntangleSettings) -> bool:
    """Past ``max_iter``: whether the pair counts ``seen`` still fall (the fewest of the last ``window`` below
    ``progress`` x the fewest before them) and ``extra_iter`` is not spent. Measured on anny_body's first 40
    colliding realistic meshes: the contour steps of large tangles (250-680 pairs) were still shrinking them at 80
    iterations (160 more freed 2 of 3), while SCAPE's heavy tangles hover (160 more freed none of 8)."""
    if len(seen) - 1 >= settings.max_iter + settings.extra_iter or len(seen) <= settings.window:
        return False
    return min(seen[-settings.window:]) < settings.progress * min(seen[:-settings.window])


def untangle(vertices: np.ndarray, labeler, settings: UntangleSettings, field: SmoothField | None = None) -> Untangled:
    """Untangle one mesh (V, 3) until the labeler counts no pair (module docstring): the region push while a region
    is enclosed, contour minimisation otherwise. ``labeler``: an
    :class:`~neuralcol.collision.labeler.ExactLabeler` (``penetrations``, ``intersecting_pairs``, ``faces``,
    ``ell``). ``field``: the :class:`SmoothField` of its topology and settings (built here if None)."""
    v = np.array(vertices, np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"untangle: vertices have shape {v.shape}, expected (V, 3)")
    if field is None:
        field = SmoothField(labeler.faces, len(v), settings.stiffness, settings.anchor)
    ell = float(labeler.ell)
    step, last_length = settings.contour_step, np.inf
    seen = []
    for it in range(settings.max_iter + settings.extra_iter + 1):
        pen = labeler.penetrations(v, settings.max_region, seed_vectors=False)
        seen.append(int(pen.n_pairs))
        if pen.n_pairs == 0:
            return Untangled(v, True, it, seen)
        if it >= settings.max_iter and not still_falling(seen, settings):
            break
        index, targets = push_targets(pen.vector, settings.share, settings.delta * ell)
        deepest = float(np.linalg.norm(pen.vector[index], axis=1).max()) if len(index) else 0.0
        if deepest <= settings.min_push * ell:  # no region deep enough to push: shrink the intersection curves
            grad, length = contour_gradient(v, labeler.faces, pen.crossing_pairs)
            norm = np.linalg.norm(grad, axis=1)
            moved = np.flatnonzero(norm > 0)
            if len(moved):
                grow = length < last_length
                step = float(np.clip(step * (settings.contour_grow if grow else settings.contour_shrink),
                                     settings.contour_min, settings.contour_max))
                last_length = length
                index, targets = moved, -grad[moved] * (step * ell / norm.max())
            elif len(index) == 0:
                break
        v += field.solve(index, targets, settings.hold)
    return Untangled(v, False, len(seen) - 1, seen)
