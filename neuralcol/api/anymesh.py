"""Checking and resolving any triangle mesh, with or without a trained run: ``neuralcol.check``,
``neuralcol.resolve`` and ``neuralcol.resolve_sequence``.

Without a run these need only the faces: the exact labeler (:mod:`neuralcol.collision.labeler`) gives the verdict,
and the exact repairs (:mod:`neuralcol.repair.contact`: the contact push, the untangle where the push fails,
a wider untangle where both fail, then the displacement cap) move a colliding mesh until the exact labeler calls
it free, as little as they can. With a run trained on the mesh's topology, ``resolve`` is
:meth:`~neuralcol.api.TrainedRun.resolve` (the learned handler, then the same repairs). A free input comes back
untouched either way, at the cost of one exact check.

    import neuralcol
    checked = neuralcol.check(vertices, faces)            # Checked: collides (B,), pairs (B,), pd (B,)
    out = neuralcol.resolve(vertices, faces)              # Resolved: vertices, pd_input, pd_after, moves, ...
    motion = neuralcol.resolve_sequence(frames, faces)    # SequenceResolution: every frame freed, smooth in time

Symbols: B meshes, T frames, V vertices, F faces.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from neuralcol.errors import UserInputError


class Checked(NamedTuple):
    """:func:`check` of B meshes: collides (B,) bool (the exact verdict), pairs (B,) int64 (intersecting triangle
    pairs), pd (B,) float64 (signed penetration depth in mesh units: > 0 iff the mesh collides; docs/labels.md)."""

    collides: np.ndarray
    pairs: np.ndarray
    pd: np.ndarray


def as_meshes(vertices, faces, name: str = "vertices") -> tuple[np.ndarray, np.ndarray]:
    """Meshes (B, V, 3) or one (V, 3) as float64 (B, V, 3), and faces (F, 3) int64; UserInputError when the shapes,
    the face indices or the coordinates are wrong."""
    v = np.asarray(vertices.detach().cpu() if hasattr(vertices, "detach") else vertices, dtype=np.float64)
    if v.ndim == 2:
        v = v[None]
    if v.ndim != 3 or v.shape[-1] != 3 or v.shape[1] < 3:
        raise UserInputError(f"{name} have shape {v.shape}; give one mesh (V, 3) or meshes (B, V, 3)")
    f = np.asarray(faces.detach().cpu() if hasattr(faces, "detach") else faces)
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise UserInputError(f"faces have shape {f.shape}; give triangles (F, 3) of vertex indices")
    if not np.issubdtype(f.dtype, np.integer):
        raise UserInputError(f"faces have dtype {f.dtype}; give integer vertex indices")
    f = f.astype(np.int64)
    if f.min() < 0 or f.max() >= v.shape[1]:
        raise UserInputError(f"faces index vertices {f.min()}..{f.max()}, but the meshes have {v.shape[1]} vertices "
                             f"(0..{v.shape[1] - 1}); faces and vertices do not belong together")
    if not np.isfinite(v).all():
        bad = np.flatnonzero(~np.isfinite(v).all(axis=(1, 2)))
        raise UserInputError(f"{name}: mesh(es) {bad[:5].tolist()} hold NaN or inf coordinates; cannot check them")
    return v, f


def labeler_for(faces: np.ndarray, rest: np.ndarray, settings: dict | None = None, clearance: bool = True):
    """The exact labeler of a topology, built on ``rest`` (V, 3): the mesh that sets the clearance scale (its
    bounding-box diagonal) and the near-pair table of the free PD (the verdict does not depend on it).
    ``settings``: the labeler's keyword arguments (``touch_tol``, ``clearance_cap``, ``boundary_eps``, ...).
    ``clearance`` False: a free mesh's PD is not measured but reported as ``-cap``; the verdict, the pairs and a
    colliding mesh's PD are the full label's, and set-up and label stay linear in the faces
    (:class:`~neuralcol.collision.labeler.ExactLabeler`'s ``clearance``)."""
    from neuralcol.collision.labeler import ExactLabeler

    return ExactLabeler(faces, rest, **{**(settings or {}), "clearance": clearance})


def check(vertices, faces, rest=None) -> Checked:
    """The exact self-collision verdict of meshes of one topology.

    Args:
        vertices: (B, V, 3) meshes or one (V, 3), numpy or torch.
        faces: (F, 3) triangles.
        rest: (V, 3) the mesh the labeler measures clearances against (None: the first mesh).

    Returns:
        :class:`Checked`.
    """
    v, f = as_meshes(vertices, faces)
    base = v[0] if rest is None else as_meshes(rest, f, "rest")[0][0]
    # A mesh at its rest has every clearance term at its rest value, the cap: its full label is the one without
    # clearances (to the last bit of the free PD, -cap), which never builds the near table. So checking a mesh
    # against itself (one file, no --rest) stays linear in the faces; other meshes get the full label.
    same = np.array([np.array_equal(x, base) for x in v], bool)
    collides, pairs, pd = np.zeros(len(v), bool), np.zeros(len(v), np.int64), np.zeros(len(v))
    for mask, clearance in ((same, False), (~same, True)):
        if mask.any():
            labels = labeler_for(f, base, clearance=clearance).label_batch(v[mask])
            collides[mask], pairs[mask], pd[mask] = labels.collides, labels.n_pairs, labels.pd
    return Checked(collides, pairs, pd)


def _check_run_topology(run, faces: np.ndarray, n_vertices: int) -> None:
    """UserInputError unless ``run`` was trained on meshes of these faces."""
    run_faces = np.asarray(run.faces, np.int64)
    if run.n_vertices != n_vertices or run_faces.shape != faces.shape or not np.array_equal(run_faces, faces):
        raise UserInputError(
            f"run {run.run_dir}: trained on meshes of {run.n_vertices} vertices and {len(run_faces)} faces; these "
            f"have {n_vertices} vertices and {len(faces)} faces"
            f"{' (other faces)' if run_faces.shape == faces.shape else ''}"
            "; resolve them without a run (run=None, the exact repairs) or train a run on their topology")


def resolve(vertices, faces, run=None, rest=None, repair=None, progress: bool = False):
    """Resolve self-collisions of meshes of one topology: each colliding mesh comes back free by the exact label,
    moved as little as the repairs can; each free mesh comes back untouched (bit for bit).

    Args:
        vertices: (B, V, 3) meshes or one (V, 3), numpy or torch.
        faces: (F, 3) triangles.
        run: None (the exact repairs alone: contact push, untangles, displacement cap) or a
            :class:`~neuralcol.api.TrainedRun` of this topology (its learned handler, then the same repairs); with a
            run the colliding inputs also take the path without it (the repairs alone, at the scale of the run's
            rest mesh) and each gets whichever result frees it with the smaller largest move
            (:func:`least_move`; ``without_run`` of the result says which).
        rest: (V, 3) the mesh that sets the scale of the repairs (their separation and largest step are fractions
            of its bounding-box diagonal); None: the first mesh. Without a run only.
        repair: :class:`~neuralcol.repair.settings.RepairSettings` (None: the defaults, which are
            ``handler.repair`` of ``conf/handler/default.yaml``). Without a run only.
        progress: a progress bar over the colliding meshes.

    Returns:
        :class:`~neuralcol.api.Resolved`. Without a run: ``codes``, ``codes_before`` are (B, 0), ``decoded`` and
        ``pd_before`` NaN (no latent space), ``margin`` NaN, ``repaired`` True where the repairs moved the mesh,
        ``cap`` the displacement cap kept, ``untouched`` the free inputs.
    """
    v, f = as_meshes(vertices, faces)
    if run is not None:
        _check_run_topology(run, f, v.shape[1])
        with_run = run.resolve(v)
        hit = ~(np.asarray(with_run.pd_input) <= 0)
        if not hit.any():
            return with_run
        base = np.asarray(run.space.rest_vertices.detach().cpu(), np.float64)
        rows = np.flatnonzero(hit)
        alone = repair_batch(labeler_for(f, base, clearance=False), base, v[rows], f, repair, progress)
        return least_move(with_run, alone, rows)
    base = v[0] if rest is None else as_meshes(rest, f, "rest")[0][0]
    return repair_batch(labeler_for(f, base, clearance=False), base, v, f, repair, progress)


def least_move(with_run, alone, rows: np.ndarray):
    """Of two paths' results, per colliding input the one that moves least among those that free it: ``with_run``
    (a :class:`~neuralcol.api.Resolved` of every input, the run's path) and ``alone`` (the path without the run, the
    exact repairs, on the inputs ``rows``). The path without the run replaces the run's where it frees the mesh and
    the run's does not, or both free it and its largest vertex move is smaller; ``without_run`` says where. Free
    inputs are the run's (untouched either way)."""
    def freed(pd):
        return np.nan_to_num(np.asarray(pd, np.float64), nan=np.inf) <= 0

    ok_run, ok_alone = freed(with_run.pd_after)[rows], freed(alone.pd_after)
    smaller = np.asarray(alone.displacement_max) < np.asarray(with_run.displacement_max)[rows]
    take = ok_alone & (~ok_run | smaller)
    pick = rows[take]
    import torch

    vertices = with_run.vertices.clone()
    vertices[torch.as_tensor(pick)] = alone.vertices[torch.as_tensor(np.flatnonzero(take))].to(vertices)
    out = {}
    for key in ("pd_after", "displacement_mean", "displacement_max", "displacement_median", "repaired", "cap",
                "margin"):
        mine = getattr(with_run, key)
        if mine is None:
            continue
        mine = np.array(mine, dtype=np.float64 if key != "repaired" else bool, copy=True)
        theirs = getattr(alone, key)
        mine[pick] = np.asarray(theirs)[take] if theirs is not None else np.nan
        out[key] = mine
    without = np.zeros(len(vertices), bool)
    without[pick] = True
    return with_run._replace(vertices=vertices, without_run=without, **out)


def repair_batch(lab, base: np.ndarray, v: np.ndarray, f: np.ndarray, repair, progress: bool):
    """:func:`resolve` without a run of meshes (B, V, 3) with faces (F, 3), given the exact labeler ``lab`` of their
    topology built on ``base`` (V, 3) (so a caller resolving many batches builds it once); ``repair`` a
    RepairSettings or None (the defaults). The repairs are :func:`neuralcol.repair.repair`'s; this wraps its numpy
    result as a :class:`~neuralcol.api.Resolved`."""
    import torch

    from neuralcol.api.results import Resolved
    from neuralcol.repair import repair as exact_repair

    r = exact_repair(v, f, lab, repair, rest=base, progress=progress)
    n = len(v)
    nan = np.full(n, np.nan)
    return Resolved(vertices=torch.as_tensor(r.vertices), codes=torch.zeros(n, 0), codes_before=torch.zeros(n, 0),
                    pd_input=r.pd_input, pd_before=nan, pd_after=r.pd_after, margin=nan.copy(),
                    displacement_mean=r.mean_move, displacement_max=r.largest_move,
                    displacement_median=r.median_move, diagonal=r.diagonal,
                    decoded=torch.full(v.shape, float("nan"), dtype=torch.float32), repaired=r.repaired, cap=r.cap,
                    untouched=r.untouched)


def resolve_sequence(frames, faces, run=None, rate: float = 1.0, rest=None, repair=None, progress: bool = False):
    """Resolve a motion: every frame freed, the corrections varying smoothly in time
    (:mod:`neuralcol.handler.sequence`); frames that are free and away from any correction come back untouched.

    Args:
        frames: (T, V, 3) the frames in order (T >= 2).
        faces: (F, 3) triangles.
        run: None (the exact repairs) or a :class:`~neuralcol.api.TrainedRun` of this topology.
        rate: the largest change of the correction between frames, as a multiple of the input's own largest
            frame-to-frame vertex move.
        rest, repair: as :func:`resolve` (without a run; ``rest`` None: the first frame).
        progress: a progress bar over the frames.

    Returns:
        :class:`~neuralcol.handler.sequence.SequenceResolution`.
    """
    from neuralcol.handler.sequence import frame_jumps
    from neuralcol.handler.sequence import resolve_sequence as sequence
    from neuralcol.utils.progress import progress_bar

    v, f = as_meshes(frames, faces, "frames")
    if len(v) < 2:
        raise UserInputError(f"frames: {len(v)} frame; a motion needs at least 2 (use resolve for one mesh)")
    if not rate > 0:
        raise UserInputError(f"rate={rate}: must be > 0 (a multiple of the input's largest frame-to-frame move)")
    if run is not None:
        _check_run_topology(run, f, v.shape[1])
        return run.resolve_sequence(v, rate=rate, progress=progress)
    base = v[0] if rest is None else as_meshes(rest, f, "rest")[0][0]
    lab = labeler_for(f, base, clearance=False)
    top = float(frame_jumps(v).max())
    step = rate * (top if top > 0 else 1e-3 * lab.diag)  # a still input: 0.1 % of the diagonal

    def resolve_one(mesh: np.ndarray) -> np.ndarray:
        return repair_batch(lab, base, mesh[None], f, repair, False).vertices[0].numpy()

    bar = progress_bar(total=len(v), desc="resolving frames", disable=not progress)
    try:
        return sequence(v, resolve_one, lambda m: bool(lab.verdict(m)), step, progress=lambda t: bar.update(1))
    finally:
        bar.close()
