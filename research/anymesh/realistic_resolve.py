"""``neuralcol.resolve`` without a trained model on each data set's realistic set, and ``resolve_sequence`` on motions
made from its poses: share freed, how far vertices move, seconds per mesh, bit-identical free meshes, smooth motions.

    .venv/bin/python -m research.anymesh.realistic_resolve [--datasets scape proc_hand proc_cloth anny_body]
        [--cache ~/neuralcol-cache] [--data ../shared/data] [--max-meshes 60] [--max-meshes-body 16]
        [--n-free 20] [--motions 2] [--frames 24] [--seed 0] [--out outputs/anymesh/realistic_resolve.json]
        [--exclude-from EARLIER.json] [--repair KEY=VALUE ...] [--runs NAME=RUN_DIR ...] [--meshes DIR]

``--datasets meshes --meshes DIR`` adds a folder of meshes nobody tuned for (the generic data set, its realistic
set built like the others'). ``--exclude-from`` draws held-out meshes (none an earlier output resolved),
``--repair`` changes ``handler.repair``, ``--runs`` resolves with a data set's trained run (the learned handler,
then its repairs) instead of the repairs alone (the motions stay without a run).

Per data set (its CPU preset, ``experiment=cpu_<name>``, composed with Hydra's compose API):

1. the realistic set (``neuralcol.samples.realistic.realistic_set``: held-out poses, ACAP and vertex interpolations,
   perturbations; exact PD) is built, or read from the cache, with only the latent space the pipeline fits for its
   held-out split (the PCA space, fit in seconds); no detector is trained;
2. its colliding meshes (PD > 0) are split into clear ones (``clear_mask``: PD >= ``realistic.clear_eps`` boundary
   widths) and near-boundary ones (colliding, not clear). The set keeps only clear meshes besides the held-out poses,
   so ``--near`` near-boundary ones are added, bisected on its own interpolation lines between the free end pose and
   the colliding ``t*`` (:func:`near_boundary_meshes`, kind ``near:<kind>``). At most ``--max-meshes`` are used
   (``--max-meshes-body`` for anny_body): the near-boundary ones first, up to a quarter, the rest a seeded draw of the
   clear ones;
3. each is resolved alone by ``neuralcol.api.anymesh.repair_batch`` with one labeler built on the data set's rest
   mesh (what ``neuralcol.resolve(mesh, faces, run=None, rest=rest)`` runs; the first mesh is also passed through
   ``neuralcol.resolve`` itself and must agree bit for bit), timed per mesh;
4. share freed (the exact PD after, and ``neuralcol.check`` on the returned meshes), the median over meshes of the
   per-mesh median vertex move and of the per-mesh largest move, the 95th percentile of the largest move (fractions of
   the rest mesh's bounding-box diagonal), seconds per mesh; ``--n-free`` free realistic meshes go through
   ``neuralcol.resolve`` and must come back bit-identical;
5. ``--motions`` motions of ``--frames`` frames: a pose pair (i, j) of a colliding vertex or ACAP interpolation of
   the set, swept from a free end pose (t = 0 or 1) to the colliding ``t*`` and back (``t(k) = t_free + (t* - t_free)
   sin(pi k / (T - 1))``), kept when its first and last frames are free and some middle frames collide;
   ``neuralcol.resolve_sequence``: every frame free (``neuralcol.check``), ``jump_ratio``, seconds per frame.

Writes ``--out`` (JSON) and prints a markdown table with the targets met or missed. Rerunnable: the data sets, ACAP
features, latent spaces and realistic sets come from the cache (``--cache``, outside the checkout).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
DATASETS = ("scape", "proc_hand", "proc_cloth", "anny_body")
FOLDER = "meshes"  # a folder of the user's own meshes (--meshes DIR): the generic data set, dataset=meshes
LARGE = ("anny_body",)  # ~13k vertices: its own mesh cap and time target
# the targets the study is read against (fractions of the rest mesh's bounding-box diagonal, seconds)
TARGETS = {"freed": 0.99, "median_move": 0.002, "p95_largest_move": 0.03, "seconds_small": 1.0,
           "seconds_large": 10.0, "jump_ratio": 1.0}
JUMP_ROUNDOFF = 1e-9  # relative slack of the jump-ratio target (round-off of a ratio that is 1 by construction)


# ----------------------------------------------------------------------------------------------------------- pure
def pick_colliding(pd: np.ndarray, clear: np.ndarray, max_meshes: int, seed: int) -> np.ndarray:
    """Indices of the colliding meshes to resolve: every colliding one if at most ``max_meshes``; else the
    near-boundary ones first (colliding, not ``clear``; up to a quarter of ``max_meshes``), then a seeded draw of
    the clear ones.

    Args:
        pd: (M,) float64 exact PD (NaN: unlabeled). clear: (M,) bool clear of the boundary.
        max_meshes: the most indices returned. seed: seeds the draw.

    Returns:
        (S,) sorted int64 indices, S <= max_meshes.
    """
    pd = np.asarray(pd, np.float64)
    hit = np.isfinite(pd) & (pd > 0)
    rows = np.flatnonzero(hit)
    if len(rows) <= max_meshes:
        return rows.astype(np.int64)
    rng = np.random.default_rng(seed)
    near, clr = np.flatnonzero(hit & ~clear), np.flatnonzero(hit & clear)
    n_near = min(len(near), max(max_meshes // 4, max_meshes - len(clr)))
    near = rng.choice(near, n_near, replace=False)
    clr = rng.choice(clr, min(len(clr), max_meshes - n_near), replace=False)
    return np.sort(np.concatenate([near, clr]).astype(np.int64))


def sweep(t_free: float, t_peak: float, n_frames: int) -> np.ndarray:
    """(T,) interpolation parameters of a there-and-back motion: ``t_free`` at both ends, ``t_peak`` in the middle,
    ``t(k) = t_free + (t_peak - t_free) sin(pi k / (T - 1))``."""
    k = np.arange(n_frames, dtype=np.float64)
    return t_free + (t_peak - t_free) * np.sin(np.pi * k / max(n_frames - 1, 1))


def _q(x: np.ndarray, q: float) -> float | None:
    x = np.asarray(x, np.float64)
    x = x[np.isfinite(x)]
    return float(np.percentile(x, q)) if len(x) else None


def summarize(rows: np.ndarray, per: dict) -> dict:
    """Metrics of the resolved meshes ``rows`` (indices into the per-mesh arrays of ``per``)."""
    if len(rows) == 0:
        return {"n": 0}
    freed, checked = per["freed"][rows], per["free_by_check"][rows]
    return {
        "n": int(len(rows)), "freed": float(freed.mean()), "freed_by_check": float(checked.mean()),
        "n_not_freed": int((~freed).sum()), "label_check_disagree": int((freed != checked).sum()),
        "median_move": _q(per["median_move"][rows], 50), "median_largest_move": _q(per["largest_move"][rows], 50),
        "p95_largest_move": _q(per["largest_move"][rows], 95), "max_largest_move": _q(per["largest_move"][rows], 100),
        "seconds_median": _q(per["seconds"][rows], 50), "seconds_mean": float(np.mean(per["seconds"][rows])),
        "seconds_max": _q(per["seconds"][rows], 100),
    }


def resolve_meshes_timed(vertices: np.ndarray, faces: np.ndarray, rest: np.ndarray,
                         progress: Callable[[int, int], None] | None = None, repair=None, run=None) -> dict:
    """Resolve colliding meshes one at a time without a run, with one labeler built on ``rest``.

    Args:
        vertices: (S, V, 3) float64 meshes. faces: (F, 3) int64. rest: (V, 3) float64 rest mesh (the scale).
        progress: called with (done, total) after each mesh.
        repair: RepairSettings (None: the defaults, ``handler.repair`` of conf/handler/default.yaml).
        run: a TrainedRun of this topology: ``neuralcol.resolve(mesh, faces, run=run)`` (its learned handler, then
            its own repairs) instead of the repairs alone.

    Returns:
        ``{"vertices": (S, V, 3), "pd_input", "pd_after", "median_move", "largest_move" (fractions of the diagonal),
        "seconds", "repaired", "cap" (S,), "diagonal", "labeler_seconds", "same_as_resolve"}`` where
        ``same_as_resolve`` says ``neuralcol.resolve`` of the first mesh returned the same vertices (None: no mesh).
    """
    import neuralcol
    from neuralcol.api.anymesh import labeler_for, repair_batch

    t0 = time.perf_counter()
    lab = labeler_for(faces, rest, clearance=False)
    t_lab = time.perf_counter() - t0
    n = len(vertices)
    out = np.empty_like(vertices)
    cols = {k: np.full(n, np.nan) for k in ("pd_input", "pd_after", "median_move", "largest_move", "seconds", "cap")}
    repaired = np.zeros(n, bool)
    for i in range(n):
        t = time.perf_counter()
        r = (repair_batch(lab, rest, vertices[i:i + 1], faces, repair, False) if run is None
             else neuralcol.resolve(vertices[i:i + 1], faces, run=run))
        cols["seconds"][i] = time.perf_counter() - t
        out[i] = r.vertices[0].numpy()
        cols["pd_input"][i], cols["pd_after"][i], cols["cap"][i] = r.pd_input[0], r.pd_after[0], r.cap[0]
        cols["median_move"][i] = r.displacement_median[0] / r.diagonal
        cols["largest_move"][i] = r.displacement_max[0] / r.diagonal
        repaired[i] = bool(r.repaired[0])
        if progress is not None:
            progress(i + 1, n)
    same = None
    if n and repair is None and run is None:
        same = bool(np.array_equal(neuralcol.resolve(vertices[:1], faces, run=None, rest=rest).vertices[0].numpy(),
                                   out[0]))
    return {"vertices": out, **cols, "repaired": repaired, "diagonal": float(lab.diag), "labeler_seconds": t_lab,
            "same_as_resolve": same}


def evaluate_resolve(vertices: np.ndarray, pd: np.ndarray, faces: np.ndarray, rest: np.ndarray, eps: float,
                     clear_eps: float, max_meshes: int, n_free: int, seed: int = 0, kind: np.ndarray | None = None,
                     kind_names: tuple = (), progress: Callable[[int, int], None] | None = None,
                     repair=None, exclude: np.ndarray | None = None, run=None) -> dict:
    """The core measurement: resolve the colliding meshes of a labeled set, check the free ones come back untouched.

    Args:
        vertices: (M, V, 3) float64 meshes. pd: (M,) their exact PD (NaN: unlabeled).
        faces: (F, 3) int64. rest: (V, 3) the rest mesh (the repairs' scale and the diagonal of the fractions).
        eps, clear_eps: clear cases have ``|PD| >= clear_eps * eps``.
        max_meshes: the most colliding meshes resolved (:func:`pick_colliding`). n_free: free meshes checked.
        seed: seeds both draws. kind: (M,) int index into ``kind_names`` (how each mesh was made), or None.
        progress: called with (done, total) after each colliding mesh.
        repair: RepairSettings of the repairs (None: the defaults).
        exclude: indices never drawn for resolving (a held-out draw: the meshes an earlier run resolved).
        run: a TrainedRun of this topology to resolve with (None: the repairs alone).

    Returns:
        A JSON-able dict: ``available`` / ``used`` counts, ``all`` / ``clear`` / ``near_boundary`` metrics
        (:func:`summarize`), ``by_kind``, ``by_collision``, ``free_identity``, ``per_mesh`` and ``not_freed`` rows.
    """
    import neuralcol
    from neuralcol.data.realistic import clear_mask

    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    pd = np.asarray(pd, np.float64)
    clear = clear_mask(pd, eps, clear_eps)
    hit = np.isfinite(pd) & (pd > 0)
    drawable = pd.copy()
    if exclude is not None and len(exclude):
        drawable[np.asarray(exclude, np.int64)] = np.nan
    pick = pick_colliding(drawable, clear, max_meshes, seed)
    res = resolve_meshes_timed(vertices[pick], faces, rest, progress, repair, run)
    check = neuralcol.check(res["vertices"], faces, rest=rest) if len(pick) else None
    per = {"freed": np.asarray(res["pd_after"] <= 0, bool),
           "free_by_check": ~check.collides if check is not None else np.zeros(0, bool),
           "median_move": res["median_move"], "largest_move": res["largest_move"], "seconds": res["seconds"]}
    is_clear = clear[pick]
    diag = res["diagonal"]
    out = {
        "available": {"colliding": int(hit.sum()), "clear": int((hit & clear).sum()),
                      "near_boundary": int((hit & ~clear).sum()), "free": int((np.isfinite(pd) & (pd <= 0)).sum()),
                      "meshes": int(len(pd))},
        "used": {"colliding": int(len(pick)), "clear": int(is_clear.sum()), "near_boundary": int((~is_clear).sum())},
        "all": summarize(np.arange(len(pick)), per),
        "clear": summarize(np.flatnonzero(is_clear), per),
        "near_boundary": summarize(np.flatnonzero(~is_clear), per),
        "labeler_seconds": res["labeler_seconds"], "same_as_resolve": res["same_as_resolve"],
        "colliding_by_resolve_labeler": int(np.sum(res["pd_input"] > 0)),  # of the used: resolve's own label agrees
    }
    if kind is not None and kind_names:
        k = np.asarray(kind)[pick]
        out["by_kind"] = {name: summarize(np.flatnonzero(k == i), per) for i, name in enumerate(kind_names)
                          if (k == i).any()}
    if len(pick):
        from neuralcol.api.anymesh import labeler_for
        from neuralcol.handler.collision_kinds import KINDS, kinds_of

        kinds = kinds_of(labeler_for(faces, rest), vertices[pick])
        out["by_collision"] = {c: summarize(np.flatnonzero([x == c for x in kinds]), per) for c in KINDS
                               if c in kinds}
        # deeper inputs move more: the metrics per third of input PD
        pd_frac = pd[pick] / diag
        edges = np.quantile(pd_frac, [0, 1 / 3, 2 / 3, 1])
        third = np.clip(np.searchsorted(edges, pd_frac, side="right") - 1, 0, 2)
        out["by_pd_third"] = {f"pd {edges[j]:.2e}..{edges[j + 1]:.2e}": summarize(np.flatnonzero(third == j), per)
                              for j in range(3) if (third == j).any()}
        out["per_mesh"] = [{"index": int(i), "kind": (kind_names[int(kind[i])] if kind is not None and kind_names
                                                       else None),
                            "collision": kinds[r], "clear": bool(is_clear[r]), "pd_input_frac": float(pd[i] / diag),
                            "pd_after_frac": float(res["pd_after"][r] / diag), "freed": bool(per["freed"][r]),
                            "free_by_check": bool(per["free_by_check"][r]), "repaired": bool(res["repaired"][r]),
                            "cap": None if not np.isfinite(res["cap"][r]) else float(res["cap"][r]),
                            "median_move": float(res["median_move"][r]), "largest_move": float(res["largest_move"][r]),
                            "seconds": float(res["seconds"][r])} for r, i in enumerate(pick)]
        out["not_freed"] = [m for m in out["per_mesh"] if not m["freed"] or not m["free_by_check"]]
    free = np.flatnonzero(np.isfinite(pd) & (pd <= 0))
    if len(free) > n_free:
        free = np.sort(np.random.default_rng(seed + 1).choice(free, n_free, replace=False))
    if len(free):
        t = time.perf_counter()
        r = neuralcol.resolve(vertices[free], faces, run=None, rest=rest)
        same = [bool(np.array_equal(r.vertices[k].numpy(), vertices[i])) for k, i in enumerate(free)]
        out["free_identity"] = {"n": int(len(free)), "bit_identical": int(sum(same)),
                                "all_untouched_flag": bool(np.all(r.untouched)),
                                "seconds_per_mesh": (time.perf_counter() - t) / len(free)}
    else:
        out["free_identity"] = {"n": 0, "bit_identical": 0}
    return out


def motion_metrics(frames: np.ndarray, faces: np.ndarray, rest: np.ndarray) -> dict:
    """``neuralcol.resolve_sequence`` of one motion (T, V, 3) without a run: every frame free by ``neuralcol.check``,
    ``jump_ratio``, seconds per frame, how far the frames moved (fractions of the rest mesh's diagonal)."""
    import neuralcol
    from neuralcol.handler.sequence import frame_jumps

    frames = np.asarray(frames, np.float64)
    faces = np.asarray(faces, np.int64)
    before = neuralcol.check(frames, faces, rest=rest)
    t = time.perf_counter()
    seq = neuralcol.resolve_sequence(frames, faces, run=None, rest=rest)
    seconds = time.perf_counter() - t
    after = neuralcol.check(seq.vertices, faces, rest=rest)
    diag = float(np.linalg.norm(rest.max(0) - rest.min(0)))
    move = np.linalg.norm(seq.vertices - frames, axis=-1) / diag  # (T, V)
    untouched = [bool(np.array_equal(seq.vertices[k], frames[k])) for k in range(len(frames))]
    return {"frames": int(len(frames)), "colliding_in": int(before.collides.sum()),
            "colliding_frames": np.flatnonzero(before.collides).tolist(),
            "every_frame_free": bool(not after.collides.any()), "colliding_after": int(after.collides.sum()),
            "sequence_says_free": bool(not seq.collides.any()), "jump_ratio": float(seq.jump_ratio),
            "input_jump_max_frac": float(frame_jumps(frames).max() / diag),
            "correction_jump_max_frac": float(seq.correction_jump.max(initial=0.0) / diag),
            "frames_untouched": int(sum(untouched)), "frames_resolved": int(seq.resolved.sum()),
            "largest_move": float(move.max()), "median_move_moved_frames": _q(np.median(move, 1)[~np.array(untouched)],
                                                                               50),
            "seconds": seconds, "seconds_per_frame": seconds / len(frames)}


# ----------------------------------------------------------------------------------------------------------- data
def compose(dataset: str, cache: Path, data: Path, workers: int, folder: Path | None = None):
    """The CPU preset of ``dataset`` (``experiment=cpu_<dataset>``; ``meshes``: ``dataset=meshes`` on ``folder``)
    with the cache, data folder and label workers."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    which = ([f"dataset={FOLDER}", f"dataset.source.path={folder}"] if dataset == FOLDER
             else [f"experiment=cpu_{dataset}"])
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return hydra_compose(config_name="config", overrides=[
            *which, f"paths.cache_dir={cache}", f"paths.data_dir={data}",
            f"labeling.pool.workers={workers}", "labeling.pool.progress=false"])


def realistic_data(cfg) -> dict:
    """The data set, rest mesh and realistic set of ``cfg`` (built once, then read from the cache): the latent space
    (the pipeline's, for its held-out split) and the exact labels; no detector."""
    from neuralcol.data.realistic import KINDS
    from neuralcol.pipeline import RunContext
    from neuralcol.samples.realistic import realistic_set

    t = time.perf_counter()
    ctx = RunContext(cfg)
    ds, feats = ctx.dataset, ctx.features
    stage = ctx.latent_space()
    labeler = ctx.sample_labeler()
    with ctx.pool(labeler) as pool:
        meshes, pd, cached = realistic_set(ds.vertices.numpy(), feats.features.numpy(), feats.acap,
                                           stage.report["val_index"], pool, cfg.realistic, ctx.samples_dir(labeler),
                                           float(labeler.eps))
    return {"meshes": meshes, "pd": np.asarray(pd, np.float64), "cached": bool(cached), "kinds": KINDS,
            "faces": ctx.faces.astype(np.int64), "rest": ctx.rest, "eps": float(labeler.eps), "labeler": labeler,
            "data_vertices": ds.vertices.numpy().astype(np.float64), "features": feats.features.double(),
            "acap": feats.acap, "latent": str(cfg.autoencoder.kind), "seconds": time.perf_counter() - t}


def make_motions(d: dict, n_motions: int, n_frames: int, seed: int, min_colliding: int = 2,
                 max_tries: int = 12) -> list[dict]:
    """Motions through the colliding interpolations of the realistic set: for a colliding vertex or ACAP
    interpolation ``(i, j, t*)`` (seeded order, alternating the two kinds), the sweep from the free end pose nearer
    ``t*`` to ``t*`` and back (:func:`sweep`). A sweep counts when its end frames are free and at least
    ``min_colliding`` frames collide; of ``max_tries`` candidates the first whose colliding stretch is at most half the
    frames are kept, then (if too few) those with the fewest colliding frames.

    Returns:
        ``[{"frames" (T, V, 3) float64, "kind", "pair", "t_free", "t_peak", "realistic_index"}]``.
    """
    from neuralcol.api.anymesh import labeler_for

    m, pd = d["meshes"], d["pd"]
    lab = labeler_for(d["faces"], d["rest"])
    rng = np.random.default_rng(seed)
    queues = []
    for name in ("vertex_interp", "acap_interp"):
        rows = np.flatnonzero((m.kind == d["kinds"].index(name)) & np.isfinite(pd) & (pd > 0))
        queues.append(list(rng.permutation(rows)))
    found, spare, tries, q = [], [], 0, 0
    while len(found) < n_motions and tries < max_tries and any(queues):
        queue = queues[q % 2] if queues[q % 2] else queues[(q + 1) % 2]
        q += 1
        r = int(queue.pop(0))
        i, j = (int(x) for x in m.source[r, :2])
        if any(x["pair"] == [i, j] for x in found + spare):
            continue
        tries += 1
        t_peak = float(m.t[r])
        t_free = 0.0 if t_peak < 0.5 else 1.0
        ts = sweep(t_free, t_peak, n_frames)
        kind = _kind_name(d, m.kind[r])
        frames = interpolate(d, kind, i, j, ts)
        hit = np.array([bool(lab.verdict(x)) for x in frames])
        if hit[0] or hit[-1] or hit.sum() < min_colliding:
            continue
        mo = {"frames": frames, "kind": kind, "pair": [i, j], "t_free": t_free, "t_peak": t_peak,
              "realistic_index": r, "n_colliding": int(hit.sum())}
        (found if hit.sum() <= n_frames // 2 else spare).append(mo)
    spare.sort(key=lambda x: x["n_colliding"])
    return found + spare[:n_motions - len(found)]


def interpolate(d: dict, kind: str, i: int, j: int, ts: np.ndarray) -> np.ndarray:
    """(T, V, 3) float64 meshes between data set poses ``i`` and ``j`` at parameters ``ts`` (T,): vertex
    interpolation, or ACAP-feature interpolation decoded (``kind`` "acap_interp")."""
    import torch

    ts = np.asarray(ts, np.float64)
    if kind == "vertex_interp":
        v = d["data_vertices"]
        return (1 - ts)[:, None, None] * v[i] + ts[:, None, None] * v[j]
    f = d["features"]
    tt = torch.as_tensor(ts)[:, None, None]
    with torch.no_grad():
        return d["acap"].decode((1 - tt) * f[i] + tt * f[j]).double().numpy()


def near_boundary_meshes(d: dict, labeler, n: int, clear_eps: float, seed: int, max_steps: int = 24) -> dict:
    """Colliding meshes near the boundary (``0 < PD < clear_eps * eps``) on the realistic set's own interpolation
    lines: for clear colliding vertex / ACAP interpolations ``(i, j, t*)`` (seeded order, alternating kinds) whose end
    pose ``t_free`` (0 or 1, the nearer) is free, bisect ``t`` between ``t_free`` and ``t*`` on the exact PD of
    ``labeler`` until the colliding end's PD is below the clear threshold. (The realistic set keeps only clear cases
    besides the held-out poses, so it has almost no near-boundary collisions of its own.)

    Returns:
        ``{"vertices" (S, V, 3), "pd" (S,), "kind" (S,) str, "source" (S, 2), "t" (S,), "tried"}``.
    """
    m, pd = d["meshes"], d["pd"]
    thr = float(clear_eps) * float(labeler.eps)
    rng = np.random.default_rng(seed + 2)
    queues = []
    for name in ("vertex_interp", "acap_interp"):
        rows = np.flatnonzero((m.kind == d["kinds"].index(name)) & np.isfinite(pd) & (pd >= thr))
        queues.append(list(rng.permutation(rows)))
    out = {"vertices": [], "pd": [], "kind": [], "source": [], "t": []}
    tried, q = 0, 0
    while len(out["pd"]) < n and any(queues) and tried < 3 * n:
        queue = queues[q % 2] if queues[q % 2] else queues[(q + 1) % 2]
        q += 1
        r = int(queue.pop(0))
        tried += 1
        kind = _kind_name(d, m.kind[r])
        i, j = (int(x) for x in m.source[r, :2])
        lo, hi = (0.0 if m.t[r] < 0.5 else 1.0), float(m.t[r])  # lo: free end, hi: colliding end
        if labeler.label(interpolate(d, kind, i, j, [lo])[0]).pd > 0:
            continue
        for _ in range(max_steps):
            mid = 0.5 * (lo + hi)
            x = interpolate(d, kind, i, j, [mid])[0]
            p = float(labeler.label(x).pd)
            if p > 0:
                hi = mid
                if p < thr:
                    out["vertices"].append(x)
                    out["pd"].append(p)
                    out["kind"].append(kind)
                    out["source"].append([i, j])
                    out["t"].append(mid)
                    break
            else:
                lo = mid
    v0 = d["data_vertices"][:0]
    return {"vertices": np.stack(out["vertices"]) if out["vertices"] else v0, "pd": np.asarray(out["pd"], np.float64),
            "kind": np.asarray(out["kind"], str), "source": np.asarray(out["source"], np.int64).reshape(-1, 2),
            "t": np.asarray(out["t"], np.float64), "tried": tried}


def _kind_name(d: dict, k) -> str:
    return d["kinds"][int(k)]


# ----------------------------------------------------------------------------------------------------------- report
def targets(name: str, r: dict) -> dict:
    """Each target of the study for data set ``name``: ``{key: {"value", "target", "met"}}`` (None values: not met;
    the motion targets only where motions were asked for)."""
    a = r["resolve"]["all"]
    sec_target = TARGETS["seconds_large"] if name in LARGE else TARGETS["seconds_small"]
    motions = r.get("motions", [])
    jr = max((m["jump_ratio"] for m in motions), default=None)
    rows = {
        "freed": (a.get("freed"), TARGETS["freed"], ">="),
        "median_move": (a.get("median_move"), TARGETS["median_move"], "<="),
        "p95_largest_move": (a.get("p95_largest_move"), TARGETS["p95_largest_move"], "<="),
        "seconds_median": (a.get("seconds_median"), sec_target, "<="),
        "motion_jump_ratio_max": (jr, TARGETS["jump_ratio"], "<="),
        "motion_every_frame_free": (float(all(m["every_frame_free"] for m in motions)) if motions else None, 1.0,
                                    ">="),
    }
    if not r.get("motions_wanted", 1):  # no motions asked for (--motions 0): their targets are not read
        rows = {k: v for k, v in rows.items() if not k.startswith("motion_")}
    out = {}
    for k, (v, tgt, op) in rows.items():
        # the sequence caps the correction's change at exactly the input's largest move: a ratio of 1 + 1 ulp is 1
        slack = JUMP_ROUNDOFF if k == "motion_jump_ratio_max" else 0.0
        met = v is not None and (v >= tgt if op == ">=" else v <= tgt * (1 + slack))
        out[k] = {"value": v, "target": f"{op} {tgt:g}", "met": bool(met)}
    return out


def _pct(x, digits: int = 2) -> str:
    return "-" if x is None else f"{100 * x:.{digits}f}%"


def table(results: dict) -> str:
    """The compact markdown table of the study."""
    head = ("| data set | V | colliding used (clear/near) of avail. | freed | median move | median largest | "
            "p95 largest | s/mesh med (max) | free bit-identical | motions: free frames, jump ratio, s/frame | "
            "targets missed |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for name, r in results.items():
        if "error" in r:
            lines.append(f"| {name} | error: {r['error']} |")
            continue
        a, u, av = r["resolve"]["all"], r["resolve"]["used"], r["resolve"]["available"]
        fi = r["resolve"]["free_identity"]
        mot = "; ".join(f"{m['frames'] - m['colliding_after']}/{m['frames']} (in {m['colliding_in']} coll.), "
                        f"{m['jump_ratio']:.2f}, {m['seconds_per_frame']:.2f}" for m in r.get("motions", [])) or "-"
        missed = [k for k, t in r["targets"].items() if not t["met"]]
        sec = "-" if a.get("seconds_median") is None else f"{a['seconds_median']:.2f} ({a['seconds_max']:.1f})"
        lines.append(f"| {name} | {r['n_vertices']} | {u['colliding']} ({u['clear']}/{u['near_boundary']}) of "
                     f"{av['colliding']} | {_pct(a.get('freed'), 1)} | {_pct(a.get('median_move'), 3)} | "
                     f"{_pct(a.get('median_largest_move'))} | {_pct(a.get('p95_largest_move'))} | {sec} | "
                     f"{fi['bit_identical']}/{fi['n']} | {mot} | {', '.join(missed) or 'none'} |")
    return "\n".join(lines)


def repair_of(overrides: list[str]):
    """RepairSettings: ``handler.repair`` of conf/handler/default.yaml with ``key=value`` overrides (None: none
    given, the defaults)."""
    if not overrides:
        return None
    from omegaconf import OmegaConf

    from neuralcol.repair.settings import repair_from_config

    handler = OmegaConf.load(ROOT / "conf" / "handler" / "default.yaml")
    return repair_from_config(OmegaConf.create({"handler": handler}), overrides=overrides)


def run_of(runs: list[str], name: str):
    """The TrainedRun given for data set ``name`` in ``--runs NAME=RUN_DIR ...`` (None: none given for it)."""
    dirs = dict(r.split("=", 1) for r in runs)
    unknown = set(dirs) - set(DATASETS)
    if unknown:
        raise SystemExit(f"--runs: unknown data set(s) {sorted(unknown)}; give NAME=RUN_DIR with NAME in {DATASETS}")
    if name not in dirs:
        return None
    from neuralcol.api import load_run

    return load_run(dirs[name])


def excluded_rows(path: Path | None, name: str, n_realistic: int) -> np.ndarray | None:
    """The realistic-set rows an earlier output (``--out`` JSON) resolved for data set ``name``: a held-out draw
    leaves them out. (Near-boundary meshes are made anew per seed and are not excluded.)"""
    if path is None:
        return None
    per = json.loads(Path(path).read_text())["results"].get(name, {}).get("resolve", {}).get("per_mesh", [])
    return np.array([m["index"] for m in per if m["index"] < n_realistic], np.int64)


def run_dataset(name: str, args) -> dict:
    """The whole study of one data set (module docstring), as a JSON-able dict."""
    t0 = time.perf_counter()
    cfg = compose(name, args.cache, args.data, args.workers, args.meshes)
    print(f"[{name}] building / loading the realistic set ...", flush=True)
    d = realistic_data(cfg)
    faces, rest = d["faces"], d["rest"]
    print(f"[{name}] realistic set: {len(d['pd'])} meshes ({'cache' if d['cached'] else 'built'}, "
          f"{d['seconds']:.0f} s), {int(np.sum(d['pd'] > 0))} colliding; V={rest.shape[0]}", flush=True)
    max_meshes = args.max_meshes_body if name in LARGE else args.max_meshes
    t_r = time.perf_counter()

    def progress(done: int, total: int) -> None:
        if done % 10 == 0 or done == total:
            print(f"[{name}] resolved {done}/{total} colliding meshes ({time.perf_counter() - t_r:.0f} s)", flush=True)

    clear_eps = float(cfg.realistic.clear_eps)
    t_n = time.perf_counter()
    near = near_boundary_meshes(d, d["labeler"], args.near, clear_eps, args.seed)
    print(f"[{name}] {len(near['pd'])} near-boundary colliding meshes bisected on {near['tried']} interpolation lines "
          f"({time.perf_counter() - t_n:.0f} s)", flush=True)
    names = (*d["kinds"], *(f"near:{k}" for k in ("vertex_interp", "acap_interp")))
    kind = np.concatenate([d["meshes"].kind.astype(np.int64),
                           np.array([names.index(f"near:{k}") for k in near["kind"]], np.int64)])
    res = evaluate_resolve(np.concatenate([d["meshes"].vertices, near["vertices"]]),
                           np.concatenate([d["pd"], near["pd"]]), faces, rest, d["eps"], clear_eps, max_meshes,
                           args.n_free, args.seed, kind, names, progress, repair_of(args.repair),
                           excluded_rows(args.exclude_from, name, len(d["pd"])), run_of(args.runs, name))
    res["near_boundary_made"] = {"n": int(len(near["pd"])), "tried": near["tried"], "kind": near["kind"].tolist(),
                                 "source": near["source"].tolist(), "t": near["t"].tolist(),
                                 "pd_frac": (near["pd"] / float(d["labeler"].diag)).tolist()}
    a = res["all"]
    print(f"[{name}] freed {_pct(a.get('freed'), 1)} of {a.get('n', 0)}, median move {_pct(a.get('median_move'), 3)}"
          f", p95 largest {_pct(a.get('p95_largest_move'))}, {a.get('seconds_median') or 0:.2f} s/mesh; free "
          f"bit-identical {res['free_identity']['bit_identical']}/{res['free_identity']['n']}", flush=True)
    motions = []
    for k, mo in enumerate(make_motions(d, args.motions, args.frames, args.seed)):
        m = motion_metrics(mo["frames"], faces, rest)
        m.update({kk: mo[kk] for kk in ("kind", "pair", "t_free", "t_peak", "realistic_index")})
        motions.append(m)
        print(f"[{name}] motion {k + 1} ({mo['kind']} {mo['pair']}, t {mo['t_free']:g} -> {mo['t_peak']:.2f} -> "
              f"{mo['t_free']:g}): {m['colliding_in']} colliding frames in, {m['colliding_after']} after, jump ratio "
              f"{m['jump_ratio']:.2f}, {m['seconds_per_frame']:.2f} s/frame", flush=True)
    if len(motions) < args.motions:
        print(f"[{name}] only {len(motions)} of {args.motions} motions found", flush=True)
    out = {"dataset": name, "n_vertices": int(rest.shape[0]), "n_faces": int(len(faces)),
           "diagonal": float(np.linalg.norm(rest.max(0) - rest.min(0))), "latent_space": d["latent"],
           "resolved_with": dict(r.split("=", 1) for r in args.runs).get(name, "repairs"),
           "realistic_set": {"n": int(len(d["pd"])), "from_cache": d["cached"], "seconds": d["seconds"],
                             "clear_eps": float(cfg.realistic.clear_eps), "eps": d["eps"]},
           "max_meshes": int(max_meshes), "resolve": res, "motions": motions, "motions_wanted": int(args.motions),
           "seconds": time.perf_counter() - t0}
    out["targets"] = targets(name, out)
    return out


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m research.anymesh.realistic_resolve",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", nargs="+", default=list(DATASETS), choices=(*DATASETS, FOLDER))
    ap.add_argument("--meshes", type=Path, default=None,
                    help=f"a folder of meshes of one topology: the data set '{FOLDER}' (dataset=meshes on it)")
    ap.add_argument("--cache", type=Path, default=Path(os.environ.get("NEURALCOL_CACHE",
                                                                      Path.home() / "neuralcol-cache")))
    ap.add_argument("--data", type=Path,
                    default=Path(os.environ.get("NEURALCOL_DATA", ROOT.parent / "shared" / "data")))
    ap.add_argument("--max-meshes", type=int, default=60, help="colliding meshes resolved per data set")
    ap.add_argument("--max-meshes-body", type=int, default=40, help="the same for anny_body (~13k vertices)")
    ap.add_argument("--near", type=int, default=10,
                    help="near-boundary colliding meshes bisected on the set's interpolation lines (0: none)")
    ap.add_argument("--n-free", type=int, default=20, help="free meshes checked to come back bit-identical")
    ap.add_argument("--motions", type=int, default=2)
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2, help="label workers building the realistic sets")
    ap.add_argument("--exclude-from", type=Path, default=None,
                    help="an earlier output JSON: the realistic meshes it resolved are not drawn (a held-out draw)")
    ap.add_argument("--repair", nargs="*", default=[], metavar="KEY=VALUE",
                    help="handler.repair overrides, e.g. retry.anchor=0.01 (default: conf/handler/default.yaml)")
    ap.add_argument("--runs", nargs="*", default=[], metavar="NAME=RUN_DIR",
                    help="resolve with these data sets' trained runs (the learned handler, then the repairs); the "
                         "data sets without one are resolved by the repairs alone")
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "anymesh" / "realistic_resolve.json")
    args = ap.parse_args(argv)
    args.cache, args.data = args.cache.expanduser().resolve(), args.data.expanduser().resolve()
    if (FOLDER in args.datasets) != (args.meshes is not None):
        ap.error(f"--datasets {FOLDER} and --meshes DIR go together")
    if args.meshes is not None:
        args.meshes = args.meshes.expanduser().resolve()
    from neuralcol.utils.threads import pin_threads

    pin_threads(1)
    t0 = time.perf_counter()
    results = {}
    for name in args.datasets:
        try:
            results[name] = run_dataset(name, args)
        except Exception as exc:  # noqa: BLE001 (one data set's failure is reported; the others still run)
            print(f"[{name}] failed: {type(exc).__name__}: {exc}", flush=True)
            results[name] = {"error": f"{type(exc).__name__}: {exc}"}
        doc = {"command": " ".join([Path(sys.executable).name, "-m", "research.anymesh.realistic_resolve",
                                    *(argv if argv is not None else sys.argv[1:])]),
               "targets": TARGETS, "settings": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
               "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
               "seconds": time.perf_counter() - t0, "results": results}
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(doc, indent=1))  # after each data set, so a stopped run keeps what it did
    print(table(results))
    print(f"wrote {args.out} ({time.perf_counter() - t0:.0f} s)")
    return doc


if __name__ == "__main__":
    main()
