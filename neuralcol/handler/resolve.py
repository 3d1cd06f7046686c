"""Resolving self-collisions with a trained detector: the augmented-Lagrangian handler over many codes
(:func:`handle_codes`), exact verification with margin escalation (:func:`verified_escalation`) and the
handler on the user's own meshes (:func:`resolve_meshes`: the correction the handled code implies, carried
onto the input mesh, then the contact repair where the exact labeler still finds a penetration).

Used by :meth:`neuralcol.api.TrainedRun.resolve` and by the pipeline's handler and realistic-set stages.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import replace
from typing import NamedTuple

import numpy as np
import torch

from neuralcol.geometry.contact_summary import reusing_neighbours
from neuralcol.handler.alm import ALMSettings, Resolution, alm_resolve
from neuralcol.handler.objectives import LatentObjective
from neuralcol.nn.inference import batched_logits
from neuralcol.repair.cap import cap_freed
from neuralcol.utils.config import as_dict

ANCHORS = ("median", "none")
UNTOUCHED = -1  # MeshResolution.stage of a free input returned as given (resolve_meshes with keep_free)


def alm_settings(cfg) -> ALMSettings:
    return ALMSettings(**as_dict(cfg))


def handle_codes(net: torch.nn.Module, z_user: torch.Tensor, box_lo: torch.Tensor, box_hi: torch.Tensor,
                 settings: ALMSettings, objective=None, batch_size: int = 256, desc: str | None = None) -> Resolution:
    """Run the handler over many codes in batches (on the detector's device); results on the CPU.

    Args:
        net: the detector (its ``logit`` is the constraint).
        z_user: (N, D) codes to resolve.
        box_lo, box_hi: (D,) the latent box.
        settings: ALM settings.
        objective: ``(z, idx) -> (len(idx),)`` over the N problems; default ``|Z - Z_user|^2 / 2``.
        batch_size: problems solved together.
        desc: a progress bar over the codes with this label (None: none).
    """
    from neuralcol.utils.progress import progress_bar

    dev = next(net.parameters()).device
    # float64 on a copy of the detector: in float32 the Armijo tests of nearly converged problems fail on
    # rounding noise (each burns every backtrack and stops unconverged); float64 halves the detector
    # evaluations per L-BFGS iteration and lets problems stop on the gradient tolerance
    net = copy.deepcopy(net).double().eval()
    z_user = z_user.double()
    objective = objective or LatentObjective(z_user.to(dev))
    parts = []
    with progress_bar(total=len(z_user), desc=desc or "", unit="code", disable=desc is None) as bar, \
            reusing_neighbours():  # a detector that reads contact summaries sees the same meshes move
        for start in range(0, len(z_user), batch_size):
            rows = torch.arange(start, min(start + batch_size, len(z_user)), device=dev)
            res = alm_resolve(lambda z, idx, rows=rows: objective(z, rows[idx]), lambda z: net(z).logit,
                              z_user[rows.cpu()].to(dev), box_lo.to(dev), box_hi.to(dev), settings)
            parts.append(Resolution(*(t.detach().cpu() for t in res)))
            bar.update(len(rows))
    if not parts:
        empty = torch.zeros(0)
        return Resolution(torch.zeros(0, z_user.shape[1]), *(empty.bool(),) * 3, empty.long(), empty, empty)
    return Resolution(*(torch.cat([getattr(p, f) for p in parts]) for f in Resolution._fields))


def verified_escalation(handle: Callable[[np.ndarray, float], Resolution],
                        label: Callable[[torch.Tensor], np.ndarray], z_user: torch.Tensor, z: torch.Tensor,
                        pd_after: np.ndarray, margins) -> tuple[torch.Tensor, np.ndarray, np.ndarray, list[int]]:
    """Exact verification with margin escalation (our addition; the paper trusts the detector).

    Inputs whose handled code the exact labeler still finds self-penetrating (PD > 0, or NaN) are handled
    again from Z_user with the next, larger, margin on the detector's logit, i.e. pushed deeper into the
    region the detector calls collision-free; a new result replaces the old one when its PD is lower.

    Args:
        handle: ``(rows, margin) -> Resolution``: handle the inputs ``rows`` (indices into z_user) from Z_user.
        label: ``(codes (n, D), rows (n,)) -> exact PD (n,)`` (NaN for non-finite codes); ``rows`` are the
            inputs (indices into z_user) the codes belong to.
        z_user: (N, D) inputs; z, pd_after: the first handling's codes and exact PD.
        margins: increasing margins, one per extra stage.

    Returns:
        (z (N, D), pd (N,), stage (N,) int: 0 = first handling kept, k = the k-th margin's result kept,
        handled (list: inputs handled again at each stage)).
    """
    z, pd = z.clone(), np.asarray(pd_after, np.float64).copy()
    stage = np.zeros(len(pd), dtype=np.int64)
    handled = []
    for k, margin in enumerate(margins, 1):
        todo = np.flatnonzero(~(pd <= 0))
        handled.append(len(todo))
        if len(todo) == 0:
            continue
        res = handle(todo, float(margin))
        pd_new = np.full(len(todo), np.nan)
        ok = res.finite.numpy()
        if ok.any():
            pd_new[ok] = label(res.z[res.finite], todo[ok])
        better = np.nan_to_num(pd_new, nan=np.inf) < np.nan_to_num(pd[todo], nan=np.inf)
        rows = todo[better]
        z[torch.as_tensor(rows)] = res.z[torch.as_tensor(better)].to(z)
        pd[rows], stage[rows] = pd_new[better], k
    return z, pd, stage, handled


def detector_logits(net: torch.nn.Module, z: torch.Tensor, batch: int = 4096) -> np.ndarray:
    """(n,) float64 logits of the latent detector on codes (eval mode, no gradient; the net left as it was)."""
    z = torch.as_tensor(z).detach().float()
    return batched_logits(net, z, batch=batch).double().numpy()


class CertifiedLabel:
    """The verdict on handled codes through the certified cascade (:mod:`neuralcol.metrics.cascade`):
    the exact labeler only where the detector is in doubt.

    Called as ``(codes (n, D), rows (n,) or None) -> (n,)`` "PD for deciding", the ``label`` of
    :func:`verified_escalation`: the exact PD (``label(codes, rows)`` on the subset) where the detector's logit lies
    in the band ``[lo, hi)``; ``-inf`` where it lies below ``lo`` (the detector is trusted: free, no exact call);
    ``+inf`` where it lies at or above ``hi`` (trusted: still colliding, so escalated; a non-finite logit too).
    :func:`verified_escalation` then handles again exactly the results judged colliding, and a ``-inf`` result
    replaces any other. ``decisions`` and ``exact_calls`` count the codes judged and the ones labeled exactly.

    Args:
        band: :class:`~neuralcol.metrics.cascade.Band`.
        logits: ``codes (n, D) -> (n,)`` the detector's logits (e.g. :func:`detector_logits` of the detector).
        label: ``(codes (m, D), rows (m,) or None) -> exact PD (m,)``.
    """

    def __init__(self, band, logits: Callable[[torch.Tensor], np.ndarray], label: Callable):
        self.band, self.logits, self.label = band, logits, label
        self.decisions, self.exact_calls = 0, 0

    def __call__(self, z: torch.Tensor, rows=None) -> np.ndarray:
        from neuralcol.metrics.cascade import band_mask

        logit = np.asarray(self.logits(z), np.float64)
        out = np.where(logit < self.band.lo, -np.inf, np.inf)  # (NaN logits: +inf, never trusted free)
        inside = np.flatnonzero(band_mask(logit, self.band))
        self.decisions += len(logit)
        self.exact_calls += len(inside)
        if len(inside):
            sub = None if rows is None else np.asarray(rows)[inside]
            out[inside] = self.label(z[torch.as_tensor(inside)], sub)
        return out

    @property
    def exact_share(self) -> float:
        """Exact calls per decision (NaN before any)."""
        return self.exact_calls / self.decisions if self.decisions else float("nan")


def certified_outcome(pd_decided: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """From :class:`CertifiedLabel`'s decisions (after :func:`verified_escalation`): (pd (n,): the exact PD where the
    exact labeler judged, NaN where the detector was trusted or nothing was labeled; exact (n,) bool: the verdict
    is the exact labeler's; free (n,) bool: the cascade calls the result collision-free)."""
    d = np.asarray(pd_decided, np.float64)
    exact = np.isfinite(d)
    return np.where(exact, d, np.nan), exact, d <= 0


def transfer_displacement(v_user: torch.Tensor, decoded_before: torch.Tensor, decoded_after: torch.Tensor,
                          anchor: str = "median") -> torch.Tensor:
    """The user's meshes moved by the correction the handler's decoded codes imply.

    ``v_user + (D(Z) - D(Z_user))``: the input keeps its own detail and frame, and only what the handler
    changed moves. The decoder pins the centroid of every decoded mesh to the rest mesh's, so a limb moved
    by the handler shifts every other vertex by a little; ``anchor="median"`` removes that translation (the
    coordinate-wise median of the displacement over the vertices, the shift that leaves most of the mesh in
    place); ``"none"`` keeps the raw difference.

    Args:
        v_user: (B, V, 3) the input meshes.
        decoded_before: (B, V, 3) their round trips ``D(Z_user)``.
        decoded_after: (B, V, 3) the handled codes decoded, ``D(Z)``.
        anchor: ``"median"`` or ``"none"``.

    Returns:
        (B, V, 3) in the dtype of ``v_user``.
    """
    if anchor not in ANCHORS:
        raise ValueError(f"anchor={anchor!r}; use one of {ANCHORS}")
    d = decoded_after.to(v_user) - decoded_before.to(v_user)
    if anchor == "median":
        d = d - d.median(dim=1, keepdim=True).values
    return v_user + d


class MeshResolution(NamedTuple):
    """:func:`resolve_meshes` for N input meshes.

    vertices (N, V, 3) float64: the returned meshes (input + transferred correction). decoded (N, V, 3): the
    handled codes decoded (the latent result). codes, codes_before (N, D) float32. pd_input (N,): exact PD of
    the inputs. pd_after_detector (N,): exact PD of the returned mesh after the detector-guided handling alone;
    pd_after (N,): after exact verification and the contact repair (equal to the former without either).
    stage (N,) int: which margin's result was kept (0: the first; ``len(margins) + 1``: the contact repair's;
    :data:`UNTOUCHED`: a free input returned as given, every PD then the input's).
    feasible (N,) bool: the detector calls the first result free (False where the detector was not asked).
    pd_after_escalation (N,): after the margins, before the repair. repaired (N,) bool: the contact repair's mesh was
    kept.
    With ``certify`` (else None): exact (N,) bool: the verdict on the returned mesh is the exact labeler's (the
    PDs are NaN where the detector was trusted instead); free (N,) bool: the cascade calls it collision-free;
    exact_share: exact labels per verification decision.
    shrink (N,) float or None (no repair): the scale s of the neural path's correction the kept mesh was repaired
    from (``repair.shrink_steps``, :func:`shrink_corrections`); NaN where not tried, 1 where tried and not kept.
    cap (N,) float or None (no repair): the cap on the displacement, a fraction of its largest, that the returned
    mesh was clipped to (``repair.cap_steps``, :func:`cap_displacements`); NaN where not tried, 1 where not clipped.
    """

    vertices: np.ndarray
    decoded: np.ndarray
    codes: torch.Tensor
    codes_before: torch.Tensor
    pd_input: np.ndarray
    pd_after_detector: np.ndarray
    pd_after: np.ndarray
    stage: np.ndarray
    feasible: np.ndarray
    pd_after_escalation: np.ndarray
    repaired: np.ndarray
    exact: np.ndarray | None = None
    free: np.ndarray | None = None
    exact_share: float | None = None
    shrink: np.ndarray | None = None
    cap: np.ndarray | None = None


def shrink_corrections(x: np.ndarray, result: np.ndarray,
                       repaired: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                       steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The smallest fraction of each correction from which the repair still frees the mesh.

    For inputs ``x`` (n, V, 3) and their free results ``result`` (n, V, 3), the correction ``D = result - x`` is
    scaled by s and ``repaired(x + s D)`` tried; bisection over ``steps`` steps (one batched repair per step) finds
    the smallest s in (0, 1] from which the repaired mesh comes out free. That mesh replaces the result where its
    largest vertex displacement from ``x`` is smaller.

    Args:
        repaired: meshes (m, V, 3) -> (repaired meshes (m, V, 3), exact PD (m,); NaN where the labeler failed).

    Returns:
        (meshes (n, V, 3): the kept ones, pd (n,): their exact PD where shrunk, NaN where the result was kept,
        s (n,): the kept scale, 1.0 where the result was kept).
    """
    x, result = np.asarray(x, np.float64), np.asarray(result, np.float64)
    d = result - x
    lo, hi = np.zeros(len(x)), np.ones(len(x))
    best, best_pd = result.copy(), np.full(len(x), np.nan)
    for _ in range(steps if len(x) else 0):
        s = 0.5 * (lo + hi)
        fixed, pd = repaired(x + s[:, None, None] * d)
        free = np.nan_to_num(pd, nan=np.inf) <= 0
        hi[free], best[free], best_pd[free] = s[free], fixed[free], pd[free]
        lo[~free] = s[~free]

    def largest(m: np.ndarray) -> np.ndarray:
        return np.linalg.norm(m - x, axis=-1).max(-1) if len(m) else np.zeros(0)

    keep = largest(best) < largest(result)
    return (np.where(keep[:, None, None], best, result), np.where(keep, best_pd, np.nan),
            np.where(keep, hi, 1.0))


def edge_strain(v_in: np.ndarray, v_out: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(B,) per mesh, the largest change of an edge's length in mean edge lengths of the input,
    ``max_e |len_out - len_in| / mean_e len_in`` (a ratio per edge is dominated by the shortest edges: the
    realistic cloth has edges near length 0, where any move is a huge relative change)."""
    from neuralcol.geometry.topology import edge_topology

    e = edge_topology(faces).edges
    v_in, v_out = np.asarray(v_in, np.float64), np.asarray(v_out, np.float64)
    before = np.linalg.norm(v_in[:, e[:, 0]] - v_in[:, e[:, 1]], axis=-1)
    after = np.linalg.norm(v_out[:, e[:, 0]] - v_out[:, e[:, 1]], axis=-1)
    return np.abs(after - before).max(-1) / np.maximum(before.mean(-1), 1e-300)


def resolve_meshes(net: torch.nn.Module | None, space, v_user: torch.Tensor,
                   label: Callable[[np.ndarray], np.ndarray], settings: ALMSettings, margins=(),
                   batch_size: int = 256, objective=None, anchor: str = "median",
                   z_user: torch.Tensor | None = None, pd_input: np.ndarray | None = None, repair=None, labeler=None,
                   progress: bool = False, certify=None, skip_freed: bool = False,
                   keep_free: bool = True) -> MeshResolution:
    """Resolve self-collisions of the user's meshes and return the user's meshes, corrected.

    The inputs are encoded; the augmented-Lagrangian handler moves each code to the nearest one the detector
    calls free; the displacement between the handled code's and the input code's decoded meshes is added to
    the input (:func:`transfer_displacement`), and the exact labeler judges that returned mesh. With
    ``margins``, the inputs whose returned mesh still self-penetrates are handled again with each larger margin
    (:func:`verified_escalation`, on the returned meshes' exact PD).

    Each input is labeled exactly first. With ``keep_free`` (the default) an input the exact labeler calls free
    (PD <= 0) comes back untouched: its own float64 values, ``stage`` :data:`UNTOUCHED`, PD after = PD of the input,
    and it skips the encoder, the handler and the repair (codes, ``decoded`` NaN unless ``z_user`` is given;
    :func:`_keep_free_inputs`). When every input is free, the cost is one exact label per input.

    Args:
        net: the detector (None only where every input is free and ``keep_free``: it is then never asked).
        space: the latent space.
        v_user: (N, V, 3) the input meshes.
        label: meshes (n, V, 3) float64 -> exact PD (n,) (NaN where the labeler failed).
        settings: ALM settings (``settings.margin`` is the first margin). margins: larger verification margins.
        batch_size: problems solved together.
        objective: ``(z, idx) -> (len(idx),)`` over the N problems (default ``|Z - Z_user|^2 / 2``).
        anchor: see :func:`transfer_displacement`.
        z_user: (N, D) the inputs' codes if already known (default: encoded here).
        pd_input: (N,) the inputs' exact PD if already known (default: labeled here).
        repair: :class:`~neuralcol.repair.settings.RepairSettings` or None: the returned meshes the exact
            labeler still finds self-penetrating after the margins get the contact repair (our addition), which
            is kept where it lowers the exact PD; with ``repair.first`` the colliding inputs are also repaired
            directly and that mesh is kept wherever it comes out free (``pd_after_detector`` and
            ``pd_after_escalation`` still describe the neural path); needs ``labeler`` (``intersecting_pairs``,
            ``eps``).
        progress: a progress bar over the repaired meshes.
        skip_freed: with ``repair.first``, the inputs the first repair frees skip the neural handler (what
            ``resolve`` does for a user: most of its time is the handler's; their ``pd_after_detector`` and
            ``pd_after_escalation`` are NaN, their codes the inputs', ``decoded`` NaN). False (the evaluations):
            every input also takes the neural path, so both are measured.
        keep_free: free inputs (exact PD <= 0) come back untouched and skip the encoder, handler and repair.
            False: every input takes the whole path (a free input is moved by whatever correction it implies).
        certify: a :class:`~neuralcol.metrics.cascade.Band` or None: verify through the certified cascade
            (:class:`CertifiedLabel`): a handled result is labeled exactly only where the latent detector's logit
            on its code lies in the band; below it the detector is trusted (free, kept), at or above it the result
            counts as still colliding (handled again with the next margin, then repaired).
    """
    if repair is not None and labeler is None:
        raise ValueError("resolve_meshes: repair needs the exact labeler (labeler=...)")
    v_user = torch.as_tensor(v_user).detach().to("cpu", torch.float64)
    n = len(v_user)
    pd_in = label(v_user.numpy()) if pd_input is None else np.asarray(pd_input, np.float64)
    if net is None and not (keep_free and n and (pd_in <= 0).all()):
        raise ValueError("resolve_meshes: net=None, but some inputs need the handler (colliding, or keep_free=False)")
    if keep_free and (pd_in <= 0).any():
        return _keep_free_inputs(net, space, v_user, label, settings, margins, batch_size, objective, anchor, z_user,
                                 pd_in, repair, labeler, progress, certify, skip_freed)
    z_user = (space.encode(v_user) if z_user is None else z_user).detach().float().cpu()
    dev = space.box_lo.device

    def decode(z: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            parts = [space.decode(c.to(dev).float()).cpu().double() for c in z.split(256)]
        return torch.cat(parts) if parts else v_user[:0]

    base = decode(z_user)

    def handle(rows: np.ndarray, margin: float) -> Resolution:
        idx_map = torch.as_tensor(rows, device=dev)

        def target(z: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
            return objective(z, idx_map[idx])

        return handle_codes(net, z_user[torch.as_tensor(rows)], space.box_lo, space.box_hi,
                            replace(settings, margin=margin), batch_size=batch_size,
                            objective=None if objective is None else target)

    def returned(z: torch.Tensor, rows: np.ndarray) -> torch.Tensor:
        r = torch.as_tensor(rows)
        return transfer_displacement(v_user[r], base[r], decode(z), anchor)

    def label_codes(z: torch.Tensor, rows: np.ndarray) -> np.ndarray:
        return label(returned(z, rows).numpy())

    if skip_freed and repair is not None and repair.first and (~(pd_in <= 0)).any():
        return _repair_first_then_rest(net, space, v_user, label, settings, margins, batch_size, objective, anchor,
                                       z_user, pd_in, repair, labeler, progress, certify)
    decide = label_codes if certify is None else CertifiedLabel(certify, lambda z: detector_logits(net, z), label_codes)
    res = handle(np.arange(n), settings.margin)
    finite = res.finite.numpy()
    pd_after = np.full(n, np.nan)
    if finite.any():
        pd_after[finite] = decide(res.z[res.finite], np.flatnonzero(finite))
    z, pd_v, stage = res.z.float(), pd_after.copy(), np.zeros(n, dtype=np.int64)
    if len(margins):
        z, pd_v, stage, _ = verified_escalation(handle, decide, z_user, z, pd_after, list(margins))
    ok = torch.isfinite(z).all(-1)
    decoded = torch.full((n, *v_user.shape[1:]), float("nan"), dtype=torch.float64)
    out = torch.full_like(decoded, float("nan"))
    if ok.any():
        rows = np.flatnonzero(ok.numpy())
        decoded[ok] = decode(z[ok])
        out[ok] = returned(z[ok], rows)
    out = out.numpy()
    pd_esc, repaired = pd_v.copy(), np.zeros(n, dtype=bool)
    if repair is not None:
        def repaired_meshes(meshes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return _repaired(space, meshes, label, repair, labeler, progress)

        # repair first: the input repaired, kept wherever it comes out free (so the neural result of those rows is
        # not repaired: that mesh would be replaced; the same outputs, less work)
        first, first_free = np.zeros(0, np.int64), np.zeros(0, bool)
        if repair.first:
            first, first_fixed, first_pd, first_free = _repaired_inputs(space, v_user, pd_in, label, repair, labeler,
                                                                        progress)
        todo = np.setdiff1d(np.flatnonzero(ok.numpy() & ~(pd_v <= 0)), first[first_free])
        if len(todo):  # the neural result still collides: repair it
            fixed, pd_fix = repaired_meshes(out[todo])
            better = np.nan_to_num(pd_fix, nan=np.inf) < np.nan_to_num(pd_v[todo], nan=np.inf)
            rows = todo[better]
            out[rows], pd_v[rows], stage[rows], repaired[rows] = fixed[better], pd_fix[better], len(margins) + 1, True
        if first_free.any():
            rows = first[first_free]
            out[rows], pd_v[rows], stage[rows], repaired[rows] = (first_fixed[first_free], first_pd[first_free],
                                                                  len(margins) + 1, True)
        shrink = np.full(n, np.nan)
        # the inputs the repair alone leaves and the neural path frees (by the exact label): the smallest share of
        # the correction from which the repair still frees them
        rows = np.setdiff1d(np.flatnonzero(~(pd_in <= 0) & (pd_v <= 0) & np.isfinite(pd_v)), first[first_free])
        if repair.shrink_steps and len(rows):
            kept, pd_s, shrink[rows] = shrink_corrections(v_user[torch.as_tensor(rows)].numpy(), out[rows],
                                                          repaired_meshes, repair.shrink_steps)
            moved = shrink[rows] < 1
            out[rows], pd_v[rows[moved]], repaired[rows[moved]] = kept, pd_s[moved], True
            stage[rows[moved]] = len(margins) + 1
        cap = cap_freed(v_user.numpy(), out, pd_in, pd_v, label, repair.cap_steps, labeler)
    else:
        shrink = cap = None
    if certify is None:
        return MeshResolution(out, decoded.numpy(), z, z_user, pd_in, pd_after, pd_v, stage,
                              res.feasible.numpy(), pd_esc, repaired, shrink=shrink, cap=cap)
    pd_v, exact, free = certified_outcome(pd_v)
    return MeshResolution(out, decoded.numpy(), z, z_user, pd_in, certified_outcome(pd_after)[0], pd_v, stage,
                          res.feasible.numpy(), certified_outcome(pd_esc)[0], repaired, exact, free,
                          decide.exact_share, shrink, cap)


def _repaired_inputs(space, v_user: torch.Tensor, pd_in: np.ndarray, label, repair, labeler, progress: bool):
    """Repair first: the colliding inputs' rows, their repaired meshes, exact PDs, and which came out free."""
    first = np.flatnonzero(~(pd_in <= 0))
    if not len(first):
        return first, None, np.zeros(0), np.zeros(0, bool)
    fixed, pd_fix = _repaired(space, v_user[torch.as_tensor(first)].numpy(), label, repair, labeler, progress)
    return first, fixed, pd_fix, np.nan_to_num(pd_fix, nan=np.inf) <= 0


def _repaired(space, meshes: np.ndarray, label, repair, labeler, progress: bool) -> tuple[np.ndarray, np.ndarray]:
    """The repair (``repair.method``) of meshes (n, V, 3) and their exact PD."""
    from neuralcol.repair.contact import outward_sign
    from neuralcol.repair.meshes import repair_meshes

    rest = space.rest_vertices.detach().cpu().numpy()
    faces = space.faces.detach().cpu().numpy()
    diag = float(np.linalg.norm(np.ptp(rest, axis=0)))
    fixed, _, _ = repair_meshes(meshes, faces, labeler, repair, float(labeler.eps), diag, outward_sign(faces, rest),
                                progress=progress)
    return fixed, label(fixed)


def _keep_free_inputs(net, space, v_user: torch.Tensor, label, settings, margins, batch_size, objective, anchor,
                      z_user, pd_in: np.ndarray, repair, labeler, progress, certify, skip_freed) -> MeshResolution:
    """:func:`resolve_meshes` with ``keep_free``: the free inputs (exact PD <= 0) returned as given, the colliding
    ones resolved by the whole path.

    A free row: ``vertices`` the input's float64 values, ``decoded`` NaN, ``codes`` and ``codes_before`` the given
    ``z_user`` (NaN when none was given: the encoder is not run for it), every PD the input's, ``stage``
    :data:`UNTOUCHED`, ``feasible`` and ``repaired`` False, ``shrink``/``cap`` NaN; with ``certify`` its verdict is
    exact and free, and ``exact_share`` is the colliding rows' (1.0 when every input is free: the only verdicts are
    the inputs' exact labels)."""
    n = len(v_user)
    free = pd_in <= 0
    rows = np.flatnonzero(~free)
    z_in = torch.full((n, space.dim), float("nan")) if z_user is None else z_user.detach().float().cpu().clone()
    out = v_user.numpy().copy()
    decoded = np.full(out.shape, np.nan)
    pd_det, pd_v, pd_esc = pd_in.copy(), pd_in.copy(), pd_in.copy()
    stage = np.full(n, UNTOUCHED, np.int64)
    feasible, repaired = np.zeros(n, bool), np.zeros(n, bool)
    shrink = None if repair is None else np.full(n, np.nan)
    cap = None if repair is None else np.full(n, np.nan)
    exact = None if certify is None else free.copy()
    free_c = None if certify is None else free.copy()
    share = None if certify is None else 1.0
    codes = z_in.clone()
    if len(rows):
        r = torch.as_tensor(rows)

        def sub_objective(z: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
            return objective(z, r.to(idx.device)[idx])

        sub = resolve_meshes(net, space, v_user[r], label, settings, margins, batch_size,
                             None if objective is None else sub_objective, anchor,
                             None if z_user is None else z_in[r], pd_in[rows], repair, labeler, progress, certify,
                             skip_freed, keep_free=False)
        out[rows], decoded[rows], codes[r], z_in[r] = sub.vertices, sub.decoded, sub.codes.float(), sub.codes_before
        pd_det[rows], pd_v[rows], pd_esc[rows] = sub.pd_after_detector, sub.pd_after, sub.pd_after_escalation
        stage[rows], feasible[rows], repaired[rows] = sub.stage, sub.feasible, sub.repaired
        if repair is not None:
            shrink[rows], cap[rows] = sub.shrink, sub.cap
        if certify is not None:
            exact[rows], free_c[rows], share = sub.exact, sub.free, sub.exact_share
    return MeshResolution(out, decoded, codes, z_in, pd_in, pd_det, pd_v, stage, feasible, pd_esc, repaired, exact,
                          free_c, share, shrink, cap)


def _repair_first_then_rest(net, space, v_user, label, settings, margins, batch_size, objective, anchor, z_user,
                            pd_in, repair, labeler, progress, certify) -> MeshResolution:
    """:func:`resolve_meshes` with ``skip_freed``: the colliding inputs repaired first; those it frees are done,
    the others (and the free inputs) take the whole path with ``repair.first`` off."""
    n = len(v_user)
    first, fixed, pd_fix, ok = _repaired_inputs(space, v_user, pd_in, label, repair, labeler, progress)
    freed, rows = first[ok], np.setdiff1d(np.arange(n), first[ok])

    def sub_objective(z: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        return objective(z, torch.as_tensor(rows, device=idx.device)[idx])

    sub = None
    if len(rows):
        sub = resolve_meshes(net, space, v_user[torch.as_tensor(rows)], label, settings, margins, batch_size,
                             None if objective is None else sub_objective, anchor, z_user[torch.as_tensor(rows)],
                             pd_in[rows], replace(repair, first=False), labeler, progress, certify, keep_free=False)
    nan = np.full(n, np.nan)
    out = np.full(tuple(v_user.shape), np.nan)
    decoded = np.full(tuple(v_user.shape), np.nan)
    codes = z_user.clone().float()
    pd_det, pd_v, pd_esc = nan.copy(), nan.copy(), nan.copy()
    stage, feasible, repaired = np.zeros(n, np.int64), np.zeros(n, bool), np.zeros(n, bool)
    out[freed], pd_v[freed], stage[freed], repaired[freed] = fixed[ok], pd_fix[ok], len(margins) + 1, True
    cap = np.full(n, np.nan)
    if len(freed):  # (fancy indexing copies: _capped updates these, then they go back)
        out_f, pd_f = out[freed], pd_v[freed]
        cap[freed] = cap_freed(v_user[torch.as_tensor(freed)].numpy(), out_f, pd_in[freed], pd_f, label,
                             repair.cap_steps, labeler)
        out[freed], pd_v[freed] = out_f, pd_f
    exact = free = share = None
    shrink = np.full(n, np.nan)
    if certify is not None:
        exact, free = np.zeros(n, bool), np.zeros(n, bool)
        exact[freed] = free[freed] = True
    if sub is not None:
        r = torch.as_tensor(rows)
        out[rows], decoded[rows], codes[r] = sub.vertices, sub.decoded, sub.codes.float()
        pd_det[rows], pd_v[rows], pd_esc[rows] = sub.pd_after_detector, sub.pd_after, sub.pd_after_escalation
        stage[rows], feasible[rows], repaired[rows] = sub.stage, sub.feasible, sub.repaired
        shrink[rows], cap[rows] = sub.shrink, sub.cap
        if certify is not None:
            exact[rows], free[rows], share = sub.exact, sub.free, sub.exact_share
    return MeshResolution(out, decoded, codes, z_user, pd_in, pd_det, pd_v, stage, feasible, pd_esc, repaired,
                          exact, free, share, shrink, cap)
