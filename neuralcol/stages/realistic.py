"""Stage: the realistic evaluation set: meshes a user brings, nobody trained on, labeled exactly.

The set is built once per latent space and labeler (:func:`~neuralcol.samples.realistic.realistic_set`, cached
beside the U(Z) test set) from the data set's meshes. Every run evaluates its final detector on it next to U(Z):

* ``detection``: accuracy, FNR, FPR, skill ``(acc - majority) / (1 - majority)`` on the clear cases
  (``|PD| >= clear_eps * eps``), overall and per kind; ``detection_all`` on every labeled mesh;
* ``round_trip``: how often encode -> decode keeps the exact label (``agreement``), how many codes leave the box
  (``out_of_box``), and how the detector does on the round trip's own label (what the latent detector can see);
* ``handling``: ``resolve_meshes`` on the colliding clear cases: the returned mesh (the input plus the
  handler's decoded correction) judged exactly, detector-guided and verified, and how far it moved.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from neuralcol.data.realistic import KINDS, RealisticMeshes, clear_mask, out_of_box
from neuralcol.handler.alm import ALMSettings
from neuralcol.handler.resolve import detector_logits, edge_strain, resolve_meshes
from neuralcol.metrics.detection import detection_report
from neuralcol.nn.part_geometry import code_mesh_logits
from neuralcol.repair.cap import displacement_stats
from neuralcol.samples.realistic import evaluation_limit, pool_pd
from neuralcol.utils.config import as_dict


def round_trip_pd(space, v: torch.Tensor, pool, desc: str = "labeling round trips",
                  rows: np.ndarray | None = None,
                  clearance_limit: float | None = None) -> tuple[torch.Tensor, np.ndarray]:
    """Encode the meshes ``v (N, V, 3)`` into ``space``, decode them and label the result: ``(codes (N, D) float32,
    exact PD of the round trips (N,))``. ``rows``: label only these round trips (the others' PD is NaN); None: all.
    ``clearance_limit``: as :func:`pool_pd`."""
    with torch.no_grad():
        z = torch.cat([space.encode(b) for b in v.split(256)]).float().cpu() if len(v) else torch.zeros(0, space.dim)
        pick = z if rows is None else z[torch.as_tensor(np.asarray(rows, np.int64))]
        rt = torch.cat([space.decode(b.to(space.box_lo.device)).cpu() for b in pick.split(256)]).double().numpy() \
            if len(pick) else np.zeros((0, *v.shape[1:]))
    pd = pool_pd(pool, rt, desc=desc, clearance_limit=clearance_limit) if len(rt) else np.zeros(0)
    if rows is None:
        return z, pd
    full = np.full(len(v), np.nan)
    full[np.asarray(rows, np.int64)] = pd
    return z, full


def round_trip_rows(n: int, limit, seed: int) -> np.ndarray | None:
    """The meshes whose round trips are labeled: all (None) when ``limit`` is None or at least ``n``, else a seeded
    sorted draw of ``limit`` of them (the round-trip figures are then on that draw)."""
    if limit is None or int(limit) >= n:
        return None
    return np.sort(np.random.default_rng(seed).choice(n, int(limit), replace=False))


def round_trip_agreement(pd_round_trip: np.ndarray, truth: np.ndarray, clear: np.ndarray) -> dict:
    """How often the round trips' exact labels (``pd_round_trip`` (M,), NaN: not labeled) keep ``truth`` (M,) bool on
    the ``clear`` meshes: ``{"agreement", "collides_lost", "collides_added"}`` (None where no mesh counts)."""
    ok = clear & np.isfinite(pd_round_trip)
    rt = np.nan_to_num(pd_round_trip, nan=0.0) > 0
    return {"agreement": float((rt[ok] == truth[ok]).mean()) if ok.any() else None,
            "collides_lost": float((~rt[ok & truth]).mean()) if (ok & truth).any() else None,
            "collides_added": float(rt[ok & ~truth].mean()) if (ok & ~truth).any() else None}


def evaluate_realistic(space, net: torch.nn.Module, meshes: RealisticMeshes, pd: np.ndarray, pool, eps: float,
                       cfg, settings: ALMSettings, margins=(), batch_size: int = 256, repair=None,
                       references: dict | None = None, render_dir: str | Path | None = None) -> tuple[dict, dict]:
    """The detector, the autoencoder's round trip and the handler on the realistic meshes.

    Args:
        space: the latent space. net: the final detector.
        meshes, pd: :func:`~neuralcol.samples.realistic.realistic_set`'s meshes and exact PD.
        pool: label pool for the round trips and the handler's results.
        eps: the labeler's boundary width (``clear_eps`` is in these units).
        cfg: the ``realistic`` config (``clear_eps``, ``handler_inputs``, ``anchor``).
        settings, margins, batch_size: the handler's settings, verification margins and batch.
        repair: :class:`~neuralcol.repair.settings.RepairSettings` or None: the contact repair as the
            handler's last verified stage (the pool's labeler runs it, in this process); with
            ``repair_reference`` in ``cfg`` the repair alone on the inputs is measured beside it
            (``handling.repair_only``).
        references: ``{name: latent space}`` whose round trips are judged beside the run's
            (``round_trip.references``: the PCA references); None: none.
        render_dir: where to render resolve's before and after for one handled input of each kind of collision
            (:func:`render_resolutions`; ``handling.renders`` lists the files); None: no pictures.

    Returns:
        (metrics, arrays: per-mesh codes, logits, labels, round-trip PD and the handler's results).
    """
    c = as_dict(cfg)
    t0 = time.perf_counter()
    v = torch.as_tensor(meshes.vertices, dtype=torch.float64)
    rt_rows = round_trip_rows(len(v), c.get("round_trip_max"), int(c.get("seed", 0)))
    limit = evaluation_limit(c, eps)
    z, pd_rt = round_trip_pd(space, v, pool, rows=rt_rows, clearance_limit=limit)
    logit = detector_logits(net, z.numpy())
    core = getattr(net, "detector", None)  # DetectorOnCodes around a detector that reads the mesh too
    logit_decoded = None
    if core is not None and core.geometry is not None:  # it judges each mesh by its own geometry, as detect(mesh)
        logit_decoded = logit
        logit = code_mesh_logits(core, z.numpy(), meshes.vertices)
    pred = logit > 0
    clear = clear_mask(pd, eps, float(c["clear_eps"]))
    labeled = np.isfinite(pd)
    truth = np.nan_to_num(pd, nan=0.0) > 0
    truth_rt = np.nan_to_num(pd_rt, nan=0.0) > 0
    oob = out_of_box(z.numpy(), space.box_lo.cpu().numpy(), space.box_hi.cpu().numpy())
    both = clear & np.isfinite(pd_rt)
    rt_clear = both & clear_mask(pd_rt, eps, float(c["clear_eps"]))
    metrics = {
        "n": int(len(pd)), "n_labeled": int(labeled.sum()), "n_clear": int(clear.sum()),
        "clear_eps": float(c["clear_eps"]), "base_rate_clear": float(truth[clear].mean()) if clear.any() else None,
        "kinds": {k: int((meshes.kind == i).sum()) for i, k in enumerate(KINDS)},
        "detection": detection_report(pred[clear], truth[clear]),
        "detection_all": detection_report(pred[labeled], truth[labeled]),
        "per_kind": {k: detection_report(pred[clear & (meshes.kind == i)], truth[clear & (meshes.kind == i)])
                     for i, k in enumerate(KINDS)},
        "round_trip": {
            "agreement": float((truth_rt[both] == truth[both]).mean()) if both.any() else None,
            "collides_lost": float((~truth_rt[both & truth]).mean()) if (both & truth).any() else None,
            "collides_added": float(truth_rt[both & ~truth].mean()) if (both & ~truth).any() else None,
            "out_of_box": float(oob[clear].mean()) if clear.any() else None,
            "detector_vs_round_trip": detection_report(pred[rt_clear], truth_rt[rt_clear]),
            "detection_in_box": detection_report(pred[clear & ~oob], truth[clear & ~oob]),
            "detection_out_of_box": detection_report(pred[clear & oob], truth[clear & oob]),
        },
    }
    if logit_decoded is not None:  # the same detector on the round trip's decoded geometry, for comparison
        metrics["detection_decoded"] = detection_report(logit_decoded[clear] > 0, truth[clear])
    if references:
        metrics["round_trip"]["references"] = {}
        for name, ref in references.items():
            _, pd_ref = round_trip_pd(ref, v, pool, desc=f"labeling round trips of {name}", rows=rt_rows,
                                      clearance_limit=limit)
            metrics["round_trip"]["references"][name] = round_trip_agreement(pd_ref, truth, clear)
    arrays = {"z": z.numpy(), "logit": logit, "pd": pd, "pd_round_trip": pd_rt, "clear": clear,
              "kind": meshes.kind, "out_of_box": oob}
    n_h = int(c.get("handler_inputs", 0))
    pick = np.flatnonzero(clear & truth)[:n_h]
    if len(pick):
        diag = float(np.linalg.norm(np.ptp(space.rest_vertices.cpu().numpy(), axis=0)))
        t_h = time.perf_counter()
        res = resolve_meshes(net, space, v[torch.as_tensor(pick)],
                             lambda x: pool_pd(pool, x, desc="labeling resolved meshes"), settings, margins,
                             batch_size, anchor=str(c.get("anchor", "median")), z_user=z[torch.as_tensor(pick)],
                             pd_input=pd[pick], repair=repair, labeler=pool.labeler if repair is not None else None)
        moved = displacement_stats(meshes.vertices[pick], res.vertices, diag)
        ok = np.isfinite(res.pd_after)
        t_handle = time.perf_counter() - t_h

        def rates(pd_after: np.ndarray) -> dict:
            return {"resolved_rate": float(np.mean(np.nan_to_num(pd_after, nan=np.inf) <= 0)),
                    "success_rate": float(np.mean(np.nan_to_num(pd_after, nan=np.inf) < pd[pick]))}

        def moved_summary(m: dict, ok: np.ndarray) -> dict:
            return {"displacement_median_frac": float(np.nanmedian(m["median_frac"][ok])) if ok.any() else None,
                    "displacement_mean_frac": float(np.nanmedian(m["mean_frac"][ok])) if ok.any() else None,
                    "displacement_max_frac": float(np.nanmedian(m["max_frac"][ok])) if ok.any() else None,
                    "displacement_max_frac_p95": float(np.nanpercentile(m["max_frac"][ok], 95)) if ok.any() else None}

        metrics["handling"] = {
            "n": int(len(pick)), "anchor": str(c.get("anchor", "median")),
            "detector_only": rates(res.pd_after_detector), "verified": rates(res.pd_after),
            "verified_margins_only": rates(res.pd_after_escalation),
            "repair": None if repair is None else {**repair.__dict__, "n_repaired": int(res.repaired.sum()),
                                                   "n_shrunk": int(np.sum(res.shrink < 1)),
                                                   "n_capped": int(np.sum(res.cap < 1))},
            "detector_called_free_before": float(np.mean(logit[pick] <= 0)),
            **moved_summary(moved, ok),
            "edge_strain_p95": float(np.percentile(edge_strain(meshes.vertices[pick][ok], res.vertices[ok],
                                                               space.faces.cpu().numpy()), 95)) if ok.any() else None,
            "displacement_median": float(np.nanmedian(moved["median"][ok])) if ok.any() else None,
            "diagonal": diag, "seconds": t_handle,
        }
        # the inputs' kinds of collision (deep, local fold, distant contact) and how many of each came out free
        from neuralcol.handler.collision_kinds import kinds_of, outcome_by_kind

        kinds = kinds_of(pool.labeler, meshes.vertices[pick])
        freed = np.nan_to_num(res.pd_after, nan=np.inf) <= 0
        metrics["handling"]["verified_by_kind"] = outcome_by_kind(kinds, freed)
        if render_dir is not None:
            metrics["handling"]["renders"] = render_resolutions(render_dir, meshes.vertices[pick], res.vertices, kinds,
                                                                freed, pool.labeler, diag)
        arrays.update({"handled": pick, "handled_pd_after_detector": res.pd_after_detector,
                       "handled_pd_after": res.pd_after, "handled_displacement_median_frac": moved["median_frac"],
                       "handled_displacement_max_frac": moved["max_frac"], "handled_repaired": res.repaired})
        if repair is not None and c.get("repair_reference", False):
            from neuralcol.repair.contact import outward_sign
            from neuralcol.repair.meshes import repair_meshes

            t_r = time.perf_counter()
            rest = space.rest_vertices.cpu().numpy()
            faces = space.faces.cpu().numpy()
            fixed, _, _ = repair_meshes(meshes.vertices[pick], faces, pool.labeler, repair, float(eps), diag,
                                        outward_sign(faces, rest))
            pd_fix = pool_pd(pool, fixed, desc="labeling repaired inputs")
            m_fix = displacement_stats(meshes.vertices[pick], fixed, diag)
            metrics["handling"]["repair_only"] = {**rates(pd_fix), **moved_summary(m_fix, np.isfinite(pd_fix)),
                                                  "seconds": time.perf_counter() - t_r}
            arrays["handled_pd_after_repair_only"] = pd_fix
    metrics["seconds"] = time.perf_counter() - t0
    return metrics, arrays


def render_resolutions(out_dir: str | Path, inputs: np.ndarray, outputs: np.ndarray, kinds: list, freed: np.ndarray,
                       labeler, diag: float) -> dict[str, str]:
    """For one input of each kind of collision (the first freed one, else the first), a PNG of the input (top,
    penetrating vertices red, darker deeper) over resolve's result (bottom, what still penetrates red):
    ``<out_dir>/resolve_<kind>.png``. Returns ``{kind: file name}``."""
    from neuralcol.handler.collision_kinds import KINDS
    from neuralcol.metrics.plots import depth_colors, render_mesh_png, stack_pngs

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    faces = labeler.faces
    written = {}
    for kind in KINDS:
        rows = [i for i, k in enumerate(kinds) if k == kind]
        if not rows:
            continue
        i = next((r for r in rows if freed[r]), rows[0])
        if not np.isfinite(outputs[i]).all():
            continue
        moved = np.linalg.norm(outputs[i] - inputs[i], axis=1) / diag
        name = kind.replace(" ", "_")
        parts = []
        for tag, v, title in (
                ("in", inputs[i], f"{kind}: input, PD {labeler.label(inputs[i]).pd / diag:.2%} of the diagonal"),
                ("out", outputs[i], f"resolved: {'free' if freed[i] else 'still colliding'}; vertices moved median "
                                    f"{np.median(moved):.3%}, largest {moved.max():.2%}")):
            parts.append(render_mesh_png(out_dir / f"_{name}_{tag}.png", v, faces,
                                         depth_colors(labeler.vertex_depths(v)), views=((15, -90), (15, 0)),
                                         title=title, size=3.0))
        written[kind] = stack_pngs(parts, out_dir / f"resolve_{name}.png").name
        for p in parts:
            p.unlink()
    return written
