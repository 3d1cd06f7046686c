"""Region push: move every penetrating region of a mesh out of the volume it entered, as one smooth field.

The contact repair (:mod:`neuralcol.handler.contact_repair`) pushes the two triangles of each intersecting pair
apart; a deep penetration (an arm in the torso, a thigh in a calf) has its intersecting triangles along the
intersection curve only, and pushing them crumples the surface into new contacts. The exact labeler knows more:
on a closed mesh the flood fill bounded by the intersection curves gives every vertex inside another part's
volume and the nearest point of the surface it must come back through
(:meth:`~neuralcol.collision.labeler.ExactLabeler.penetrations`). One iteration:

* each penetrating vertex ``i`` gets the target ``t_i = share * (x_i* - x_i) + delta * u_i`` (``x_i*`` the nearest
  opposing point, ``u_i`` the unit direction towards it): both sides of a contact move, each by ``share`` of the
  way (1/2 meets in the middle) plus a separation ``delta``;
* the displacement field ``d`` (V, 3) minimises ``sum_i |d_i - t_i|^2 + stiffness * |L d|^2 + anchor * |d|^2``
  over the whole mesh, ``L`` the mesh's uniform graph Laplacian: a smooth field that meets the targets and dies
  out over the surface around them (``stiffness`` sets how far: the squared Laplacian's falloff, about
  ``stiffness ** (1/4)`` rings; ``anchor`` keeps what is far away in place), one sparse solve of three right-hand
  sides;
* the mesh moves by ``d``; iterations stop when the labeler counts no pair, or after ``max_iter``.

On a mesh with boundary (cloth) and in local folds there are no enclosed regions: the targets are the nearer ends of
the crossing edges, pulled back through the triangle they pierce. Pure numpy / scipy over any labeler with
``penetrations(vertices)`` (:class:`~neuralcol.collision.labeler.ExactLabeler`).

Symbols: V vertices, F faces.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from neuralcol.handler.contact_repair import contact_push, outward_sign


@dataclass(frozen=True)
class PushSettings:
    """Settings of :func:`region_push` (``handler.push`` in conf/handler/)."""

    share: float = 0.5  # fraction of the way to the opposing surface each penetrating vertex is asked to move
    delta: float = 0.25  # separation beyond it, in units of the labeler's mean edge length ell
    hold: float = 10.0  # weight of a target (against the smoothness)
    stiffness: float = 4.0  # weight of |L d|^2 (smoothness; larger: wider, gentler fields)
    anchor: float = 1e-4  # weight of |d|^2 (what no target reaches stays put)
    max_region: float = 0.3  # a region with more of the vertices is the outside of an open curve: seeds only
    max_iter: int = 40
    contacts: str = "fallback"  # push counted pairs apart: "always", or only when no region has a target
    form: str = "membrane"  # smoothness: membrane (|grad d|^2, no overshoot) or thin_plate (|L d|^2)

    def __post_init__(self):
        if not (0 < self.share <= 1 and self.delta >= 0 and self.stiffness >= 0 and self.anchor > 0
                and self.max_iter >= 1):
            raise ValueError(f"handler.push: need 0 < share <= 1, delta >= 0, stiffness >= 0, anchor > 0 and "
                             f"max_iter >= 1, got {self}")


class PushResult(NamedTuple):
    """Result of :func:`region_push` on one mesh: the vertices (V, 3), whether the labeler finds it free, the
    iterations run and the counted pairs before each iteration (the trace)."""

    vertices: np.ndarray
    free: bool
    iterations: int
    pairs: tuple


def laplacian(faces: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """(V, V) uniform graph Laplacian ``I - D^-1 A`` of the mesh's edges."""
    f = np.asarray(faces, np.int64)
    a = sp.coo_matrix((np.ones(3 * len(f)), (f.ravel(), np.roll(f, -1, 1).ravel())), shape=(n_vertices,) * 2)
    a = ((a + a.T) > 0).astype(np.float64).tocsr()
    deg = np.asarray(a.sum(1)).ravel()
    return (sp.eye(n_vertices) - sp.diags(1.0 / np.maximum(deg, 1.0)) @ a).tocsr()


class SmoothField:
    """The quadratic form ``stiffness * L^T L + anchor * I`` of one topology (built once), and the field that
    meets targets on some vertices: :meth:`solve`."""

    def __init__(self, faces: np.ndarray, n_vertices: int, stiffness: float, anchor: float, form: str = "membrane"):
        lap = laplacian(faces, n_vertices)
        if form == "membrane":  # sum over edges of |d_i - d_j|^2: no overshoot (a maximum principle)
            deg = sp.diags(np.asarray((sp.eye(n_vertices) - lap).astype(bool).sum(1)).ravel().astype(np.float64))
            quad = deg @ lap
        elif form == "thin_plate":
            quad = lap.T @ lap
        else:
            raise ValueError(f"form={form!r}; use membrane or thin_plate")
        self.base = (stiffness * quad + anchor * sp.eye(n_vertices)).tocsc()

    def solve(self, index: np.ndarray, targets: np.ndarray, hold: float = 1.0) -> np.ndarray:
        """(V, 3) field minimising ``hold * sum_k |d[index[k]] - targets[k]|^2`` plus the form."""
        n = self.base.shape[0]
        w = np.zeros(n)
        w[index] = hold
        rhs = np.zeros((n, 3))
        np.add.at(rhs, index, hold * targets)
        return spla.splu((self.base + sp.diags(w)).tocsc()).solve(rhs)


def push_targets(vector: np.ndarray, share: float, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """The penetrating vertices (those with a nonzero vector) and their targets (see the module docstring)."""
    norm = np.linalg.norm(vector, axis=1)
    index = np.flatnonzero(norm > 0)
    unit = vector[index] / norm[index, None]
    return index, share * vector[index] + delta * unit


def region_push(vertices: np.ndarray, labeler, settings: PushSettings, field: SmoothField | None = None) \
        -> PushResult:
    """Push the penetrating regions of one mesh (V, 3) out until the labeler counts no pair (module docstring).

    ``field``: the :class:`SmoothField` of the labeler's topology and ``settings`` (built here if None; pass one to
    reuse its form over many meshes)."""
    v = np.array(vertices, np.float64)
    if field is None:
        field = SmoothField(labeler.faces, len(v), settings.stiffness, settings.anchor, settings.form)
    delta = settings.delta * float(labeler.ell)
    sign = outward_sign(labeler.faces, v)
    trace = []
    for it in range(settings.max_iter):
        pen = labeler.penetrations(v, settings.max_region, seed_vectors=False)
        trace.append(pen.n_pairs)
        if pen.n_pairs == 0:
            return PushResult(v, True, it, tuple(trace))
        # enclosed regions: towards the opposing surface; every counted pair: its two triangles apart
        index, targets = push_targets(pen.vector, settings.share, delta)
        if settings.contacts == "always" or len(index) == 0:
            push = contact_push(v, labeler.faces, labeler.intersecting_pairs(v), delta, sign)
            extra = np.setdiff1d(np.flatnonzero(np.abs(push).sum(1) > 0), index)
            index, targets = np.concatenate([index, extra]), np.concatenate([targets, push[extra]])
        if len(index) == 0:
            break
        v += field.solve(index, targets, settings.hold)
    free = labeler.penetrations(v).n_pairs == 0 if len(trace) == settings.max_iter else False
    return PushResult(v, free, len(trace), tuple(trace))
