"""The exact repairs of many meshes of one topology, in this process: the contact push, the untangle where it
fails, the wider untangle where both fail (:func:`repair_meshes`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from neuralcol.repair.contact import diffusion_operator, repair_contacts
from neuralcol.repair.settings import RepairSettings


def repair_meshes(vertices: np.ndarray, faces: np.ndarray, labeler, settings: RepairSettings, eps: float,
                  diagonal: float, sign: float, progress: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The repair of every mesh (N, V, 3), in this process: :func:`repair_contacts`, with ``method: untangle``
    :func:`~neuralcol.repair.untangle.untangle` (``settings.untangle``), with ``method: contact_untangle`` the
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
        from neuralcol.repair.untangle import SmoothField, UntangleSettings, untangle

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


class Repaired(NamedTuple):
    """:func:`repair` of B meshes of one topology, numpy throughout.

    vertices (B, V, 3) float64: the returned meshes (a free input bit for bit). pd_input, pd_after (B,) float64: the
    exact PD of the inputs and of the returned meshes (> 0: collides). repaired (B,) bool: a repair's mesh was kept
    (one that does not lower the PD is not). cap (B,) float64: the cap on the vertex moves the returned mesh was
    clipped to, a fraction of its largest move (NaN where not tried, 1 where not clipped; :mod:`neuralcol.repair.cap`).
    untouched (B,) bool: the input was free and came back as given. largest_move, median_move (B,) float64: each
    mesh's largest and median vertex move, in mesh units. diagonal: the rest mesh's bounding-box diagonal.
    """

    vertices: np.ndarray
    pd_input: np.ndarray
    pd_after: np.ndarray
    repaired: np.ndarray
    cap: np.ndarray
    untouched: np.ndarray
    largest_move: np.ndarray
    median_move: np.ndarray
    mean_move: np.ndarray
    diagonal: float

    @property
    def freed(self) -> np.ndarray:
        """(B,) bool: the returned mesh is free by the exact label."""
        return np.nan_to_num(self.pd_after, nan=np.inf) <= 0

    @property
    def move_to_depth(self) -> np.ndarray:
        """(B,) the largest move over the input's exact PD (NaN for free inputs; see
        :attr:`neuralcol.api.Resolved.move_to_depth`)."""
        from neuralcol.repair.cap import move_to_depth

        return move_to_depth(self.largest_move, self.pd_input, self.diagonal)


# a mesh with this many faces or more takes seconds per exact check: with ``progress``, its checks are counted on
# a bar of their own (the stages' iterations are not known in advance)
LARGE_FACES = 20_000


class CountedChecks:
    """The labeler, with every exact check it makes counted on a progress bar (``checks``, with the pairs left)."""

    def __init__(self, labeler, bar):
        self._labeler, self._bar = labeler, bar

    def __getattr__(self, name):
        attr = getattr(self._labeler, name)
        if name not in ("intersecting_pairs", "penetrations", "verdict", "label_batch"):
            return attr

        def counted(*args, **kwargs):
            out = attr(*args, **kwargs)
            pairs = getattr(out, "n_pairs", None)
            if pairs is None and name == "intersecting_pairs":
                pairs = len(out)
            if pairs is not None and np.ndim(pairs) == 0:
                self._bar.set_postfix_str(f"{int(pairs)} pairs", refresh=False)
            self._bar.update(1)
            return out

        return counted


def repair(vertices: np.ndarray, faces: np.ndarray, labeler, settings: RepairSettings | None = None,
           rest: np.ndarray | None = None, progress: bool = False) -> Repaired:
    """The exact repairs of meshes (B, V, 3) of one topology, without a trained run: each colliding mesh is repaired
    (:func:`repair_meshes`: the contact push, the untangle where it fails, the wider untangle where both fail), the
    repair kept where it lowers the exact PD, and a freed mesh's moves capped (:func:`~neuralcol.repair.cap.cap_freed`);
    each free mesh comes back untouched, bit for bit.

    Args:
        vertices: (B, V, 3) float64 meshes. faces: (F, 3) int64 triangles.
        labeler: the exact labeler of the topology (:class:`~neuralcol.collision.labeler.ExactLabeler`), built on
            ``rest``: its ``eps`` and ``diag`` set the repairs' scale.
        settings: :class:`RepairSettings` (None: the defaults, ``handler.repair`` of ``conf/handler/default.yaml``).
        rest: (V, 3) the mesh whose winding says which side is out on a closed mesh (None: the first mesh).
        progress: a progress bar over the colliding meshes; on a mesh of :data:`LARGE_FACES` faces or more, one that
            counts the exact checks instead (a large mesh's repair takes minutes).
    """
    from neuralcol.repair.cap import cap_freed, displacement_stats
    from neuralcol.repair.contact import outward_sign

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    if progress and len(f) >= LARGE_FACES:
        from neuralcol.utils.progress import progress_bar

        with progress_bar(desc=f"exact checks ({len(f)} faces)", unit="check") as bar:
            return repair(v, f, CountedChecks(labeler, bar), settings, rest, progress=False)
    settings = RepairSettings() if settings is None else settings
    base = v[0] if rest is None else np.asarray(rest, np.float64)
    pd_in = labeler.label_batch(v).pd
    out, pd_out = v.copy(), pd_in.copy()
    rows = np.flatnonzero(pd_in > 0)
    repaired, cap = np.zeros(len(v), bool), np.full(len(v), np.nan)  # (cap: NaN where not tried)
    if len(rows):
        fixed, _, _ = repair_meshes(v[rows], f, labeler, settings, float(labeler.eps), float(labeler.diag),
                                    outward_sign(f, base), progress=progress)
        pd_fix = labeler.label_batch(fixed).pd
        better = pd_fix < pd_in[rows]  # (a repair that makes things worse is not kept)
        keep = rows[better]
        out[keep], pd_out[keep], repaired[keep] = fixed[better], pd_fix[better], True
        cap = cap_freed(v, out, pd_in, pd_out, lambda m: labeler.label_batch(m).pd, settings.cap_steps, labeler)
    moved = displacement_stats(v, out, float(labeler.diag))
    return Repaired(out, pd_in, pd_out, repaired, cap, pd_in <= 0, moved["max"], moved["median"], moved["mean"],
                    float(labeler.diag))
