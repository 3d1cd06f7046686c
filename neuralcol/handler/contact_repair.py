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

from dataclasses import dataclass, field
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


REPAIR_METHODS = ("contact", "untangle", "contact_untangle")


@dataclass(frozen=True)
class RepairSettings:
    """Settings of the contact repair (``handler.repair`` in ``conf/handler/default.yaml``)."""

    enabled: bool = True
    delta: float = 3.0          # separation asked for per intersecting pair, in the labeler's eps
    smooth_steps: int = 16      # diffusion steps the push is spread by
    max_smooth: int | None = None  # grow the diffusion up to this when stalled (None: fixed)
    max_iter: int = 60
    max_step: float = 0.002     # no vertex moves more than this fraction of the diagonal per iteration
    first: bool = True          # resolve: repair the input first, the neural handler only for what it leaves
    method: str = "contact_untangle"  # contact: this module's push; untangle: region push + contour
                                # minimisation; contact_untangle (default, rule v2): the push, and untangle
                                # (from the input) where it fails
    untangle: dict | None = None  # settings of neuralcol.handler.untangle.UntangleSettings (None: its defaults)
    retry: dict | None = field(default_factory=lambda: {"anchor": 0.01})  # untangle settings changed for a third
    # attempt, from the input, where the repairs above leave a mesh colliding; kept only where it frees it (None: no
    # third attempt). Default: a wider field (docs/studies/wider_untangle.md)
    shrink_steps: int = 0       # resolve: bisection steps shrinking the neural path's correction (0: off)
    cap_steps: int = 6          # resolve: bisection steps capping a freed result's displacement (0: off; the
                                # default, rule v10 met)

    def __post_init__(self):
        if self.delta <= 0 or self.smooth_steps < 0 or self.max_iter < 0 or self.max_step <= 0:
            raise ValueError(f"handler.repair {self}: need delta > 0, smooth_steps >= 0, max_iter >= 0, "
                             "max_step > 0")
        for key in ("shrink_steps", "cap_steps"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"handler.repair.{key}={value!r}; use 0 (off) or a whole number of steps")
        if self.method not in REPAIR_METHODS:
            raise ValueError(f"handler.repair.method={self.method!r}; use one of {', '.join(REPAIR_METHODS)}")
        if self.retry is not None:
            from neuralcol.handler.untangle import UntangleSettings

            known = set(UntangleSettings.__dataclass_fields__)
            if not isinstance(self.retry, dict) or set(self.retry) - known:
                raise ValueError(f"handler.repair.retry={self.retry!r}; give null or untangle settings to change "
                                 f"(keys of {sorted(known)})")


def repair_settings(cfg) -> RepairSettings | None:
    """:class:`RepairSettings` from a ``handler.repair`` mapping (None or ``enabled: false``: no repair)."""
    if cfg is None:
        return None
    c = dict(cfg)
    unknown = set(c) - set(RepairSettings.__dataclass_fields__)
    if unknown:
        raise ValueError(f"handler.repair: unknown keys {sorted(unknown)}; known: "
                         f"{sorted(RepairSettings.__dataclass_fields__)}")
    s = RepairSettings(**c)
    return s if s.enabled else None


def repair_from_config(cfg, enabled: bool | None = None, overrides=()) -> RepairSettings | None:
    """The contact repair a run's config asks for: its ``handler.repair`` (a run older than the repair has none:
    off), with ``key=value`` ``overrides`` and ``enabled`` forcing it on or off; None when off. The one reading of
    the setting (``experiments.run``, :meth:`neuralcol.api.TrainedRun.resolve`, ``experiments.evaluate_realistic``).
    """
    from omegaconf import OmegaConf

    node = OmegaConf.select(cfg, "handler.repair")
    base = OmegaConf.create({"enabled": False} if node is None else OmegaConf.to_container(node, resolve=True))
    c = OmegaConf.to_container(OmegaConf.merge(base, OmegaConf.from_dotlist(list(overrides))), resolve=True)
    if enabled is not None:
        c["enabled"] = bool(enabled)
    return repair_settings(c)


def repair_meshes(vertices: np.ndarray, faces: np.ndarray, labeler, settings: RepairSettings, eps: float,
                  diagonal: float, sign: float, progress: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The repair of every mesh (N, V, 3), in this process: :func:`repair_contacts`, with ``method: untangle``
    :func:`~neuralcol.handler.untangle.untangle` (``settings.untangle``), with ``method: contact_untangle`` the
    former and, for the meshes it leaves colliding, the latter from the input (iterations: the two summed). With
    ``settings.retry`` (untangle settings changed) and an untangle in the method, a mesh still colliding gets one more
    untangle from the input with those settings; its result replaces the one before only where it is free.

    Args:
        eps: the labeler's boundary width (``settings.delta`` is in its units).
        diagonal: the rest mesh's bounding-box diagonal (``settings.max_step`` is a fraction of it).
        sign: :func:`outward_sign` of the rest mesh.

    Returns:
        (vertices (N, V, 3) float64, resolved (N,) bool, iterations (N,) int).
    """
    from neuralcol.utils.progress import progress_bar

    v = np.asarray(vertices, np.float64)
    out, ok, its = np.empty_like(v), np.zeros(len(v), bool), np.zeros(len(v), np.int64)
    untangle_one = contact_one = retry_one = None
    if settings.method in ("untangle", "contact_untangle") and len(v):
        from neuralcol.handler.untangle import SmoothField, UntangleSettings, untangle

        us = UntangleSettings(**(settings.untangle or {}))
        field = SmoothField(faces, v.shape[1], us.stiffness, us.anchor)
        untangle_one = lambda x: untangle(x, labeler, us, field)  # noqa: E731
        if settings.retry:
            ur = UntangleSettings(**{**(settings.untangle or {}), **settings.retry})
            field_r = SmoothField(faces, v.shape[1], ur.stiffness, ur.anchor) if (
                (ur.stiffness, ur.anchor) != (us.stiffness, us.anchor)) else field
            retry_one = lambda x: untangle(x, labeler, ur, field_r)  # noqa: E731
    if settings.method in ("contact", "contact_untangle") and len(v):
        w = diffusion_operator(faces, v.shape[1])
        contact_one = lambda x: repair_contacts(  # noqa: E731
            x, faces, labeler, settings.delta * eps, settings.smooth_steps, settings.max_iter, sign, w,
            max_step=settings.max_step * diagonal, max_smooth=settings.max_smooth)
    for k in progress_bar(range(len(v)), desc="contact repair", unit="mesh", disable=not progress or len(v) == 0):
        r = (contact_one or untangle_one)(v[k])
        out[k], ok[k], its[k] = r.vertices, r.resolved, r.iterations
        if not r.resolved and contact_one is not None and untangle_one is not None:
            u = untangle_one(v[k])
            out[k], ok[k], its[k] = u.vertices, u.resolved, r.iterations + u.iterations
        if not ok[k] and retry_one is not None:
            u = retry_one(v[k])
            its[k] += u.iterations
            if u.resolved:
                out[k], ok[k] = u.vertices, True
    return out, ok, its
