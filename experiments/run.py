"""Main entry point: ``python -m experiments.run [hydra overrides]``.

Runs the pipeline on the configured data set (default: the procedural hand): load and validate the meshes,
compute ACAP features, check the ACAP round trip, label the meshes exactly (self-intersection and PD), train
(or load from the cache) the bilevel autoencoder, picture its sub-domains, train the neural collision
detector with the configured method (``method=supv|supv_bd|active``) round by round, export example meshes,
and write ``metrics.json`` into the Hydra run directory. Re-running the same command (or with the same
``hydra.run.dir``) resumes an interrupted run after its last finished round (``resume=false`` starts afresh;
see ``neuralcol/utils/resume.py`` and ``docs/reliability.md``).
"""

from __future__ import annotations

import contextlib
import json
import logging
import sys
import time
import warnings
from pathlib import Path
from types import SimpleNamespace

import hydra
import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from experiments.reporting.speed_accuracy import plot_speed_accuracy
from neuralcol.geometry.mesh_io import write_meshes
from neuralcol.handler.contact_repair import repair_from_config
from neuralcol.handler.resolve import alm_settings
from neuralcol.metrics.plots import partition_colors, render_mesh_png
from neuralcol.metrics.tensorboard import stage_logger
from neuralcol.nn.detector import load_detector
from neuralcol.nn.part_geometry import DetectorOnCodes
from neuralcol.pipeline import RunContext
from neuralcol.rundir import RunDir
from neuralcol.samples.cache import shared_test_set
from neuralcol.stages.autoencoder import train_or_load_latent_space
from neuralcol.stages.box_check import check_box, probe_share
from neuralcol.stages.cascade import calibrate, cascade_stage, cascade_table, log_cascade
from neuralcol.stages.data import acap_round_trip, dataset_labels
from neuralcol.stages.detector import inference_us, train_detector
from neuralcol.stages.geometry import detector_inputs, realistic_rows
from neuralcol.stages.handler import evaluate_handler, export_handling
from neuralcol.stages.model_size import search_model_size, validate_model_size
from neuralcol.stages.realistic import calibration_meshes, evaluate_realistic, evaluation_limit, realistic_set
from neuralcol.stages.speed import measure_speed_accuracy, speed_accuracy_table
from neuralcol.stages.validate import validate_run_config
from neuralcol.utils import sitting
from neuralcol.utils.cli import report_user_errors
from neuralcol.utils.resume import RunDirLock, find_interrupted_run
from neuralcol.utils.seeding import seed_everything
from neuralcol.utils.sitting_record import SittingRecord
from neuralcol.utils.threads import pin_threads


class RunState(SimpleNamespace):
    """What the stages of :func:`run` share: ``cfg``, ``run_dir``, ``ctx`` (the :class:`~neuralcol.pipeline.
    RunContext`), ``rd`` (its files), ``metrics`` (filled stage by stage) and what each stage leaves for the next
    (the data set, the latent space, the label pool, the test set, the final detector, ...)."""

    def detector(self) -> DetectorOnCodes:
        """The final detector (``detector.pt``, read once) as a function of codes."""
        if self.net is None:
            self.net = DetectorOnCodes(load_detector(self.rd.detector)[0], self.space)
        return self.net


def stage_data(s: RunState) -> None:
    """The data set, its ACAP features (and, with ``model_size=auto``, the sizes), the ACAP round trip and the
    exact labels of the data set's own meshes (the paper assumes they are (nearly) collision-free)."""
    t0 = time.perf_counter()
    s.ds = s.ctx.dataset
    t_load = time.perf_counter() - t0
    t0 = time.perf_counter()
    s.feats = s.ctx.features
    t_encode = time.perf_counter() - t0
    if s.cfg.get("model_size") is not None and s.cfg.model_size.mode == "auto":  # choose the sizes first
        s.cfg, s.size_doc = search_model_size(s.cfg, s.run_dir, s.ds, s.feats, run, train_or_load_latent_space)
        seed_everything(s.cfg.seed if s.cfg.seed is not None else None)  # as if the sizes had been given
        s.ctx = s.ctx.reconfigured(s.cfg)
    s.recon, acap_metrics = acap_round_trip(s.ds, s.feats)
    with s.ctx.pool(s.ctx.labeler(), desc="labeling data set") as pool:
        label_metrics = dataset_labels(s.ds, pool)
    ds = s.ds
    s.metrics.update({
        "dataset": {"name": s.cfg.dataset.name, "source": ds.source, "n_meshes": len(ds),
                    "n_vertices": ds.n_vertices, "n_faces": int(ds.faces.shape[0]), "load_seconds": t_load},
        "acap": {**{k_: v for k_, v in acap_metrics.items() if k_ != "decode_ms_per_mesh"},
                 "features_seconds": t_encode, "features_from_cache": s.feats.from_cache,
                 "decode_ms_per_mesh": acap_metrics["decode_ms_per_mesh"]},
        "dataset_labels": label_metrics})


def stage_latent(s: RunState) -> None:
    """The latent space (trained, or loaded from the cache; TensorBoard: one run per stage under
    ``<run dir>/tensorboard/``) and a picture of its sub-domains."""
    t0 = time.perf_counter()
    s.space, s.ae_report, s.ae_cached = s.ctx.latent_space(lambda stage: stage_logger(s.run_dir, stage))
    s.t_ae = time.perf_counter() - t0
    part = s.space.partition.numpy()
    faces, rest = s.ctx.faces, s.ctx.rest
    render_mesh_png(s.rd.subdomains_png, rest, faces, partition_colors(part),
                    title=f"{s.cfg.dataset.name}: {s.space.n_parts} sub-domains")
    colors = (partition_colors(part)[:, :3] * 255).astype("uint8")
    data_logger = stage_logger(s.run_dir, "data")
    data_logger.experiment.add_mesh("subdomains", vertices=torch.as_tensor(rest[None]).float(),
                                    colors=torch.as_tensor(colors[None]), faces=torch.as_tensor(faces[None]))
    data_logger.finalize("success")


def stage_open_pool(s: RunState) -> None:
    """The sample labeler's pool (open until :func:`stage_close_pool`), the fitted box and its probe, the oracle,
    the shared U(Z) test set and the handler's inputs (its first colliding rows)."""
    s.sample_labeler = s.ctx.sample_labeler()
    s.t_det0 = time.perf_counter()  # (the detector's stage time counts the box fit and the test set too)
    s.settings = alm_settings(s.cfg.handler.alm)
    s.ref_spaces, s.ref_errors = s.ctx.references  # PCA at the same |Z_all|
    s.pool = s.pool_stack.enter_context(s.ctx.pool(s.sample_labeler))
    s.box_fit = s.ctx.fit_box(s.pool, s.sample_labeler)  # the box scaled until U(Z) is worth sampling
    s.ae_report = s.ctx.latent_space().report  # a fitted box has its own cache key
    s.oracle = s.ctx.oracle(s.pool)
    s.box_probe = box_stage(s.space, s.ref_spaces, s.pool, s.cfg, s.box_fit)
    s.test, _, _ = shared_test_set(s.oracle, s.cfg.detector, s.ae_report["cache_key"], s.cfg.paths.cache_dir)
    pick = np.flatnonzero(s.test.pd > 0)[: int(s.cfg.handler.n_inputs)]
    s.z_user, s.pd_user = torch.as_tensor(s.test.z[pick]), s.test.pd[pick]
    s.pd_sub_user = s.test.pd_sub[pick]
    s.samples_dir = s.ctx.samples_dir(s.sample_labeler)


def stage_detector(s: RunState) -> None:
    """The neural collision detector, trained by the configured method round by round (``detector.inputs``:
    on the codes, or on code and mesh with the realistic training meshes among its rows)."""
    cfg = s.cfg
    s.logger = stage_logger(s.run_dir, f"detector_{cfg.method.name}")

    def handling(net):  # per round the detector alone (paper Fig. 5); the verified variant is for the final one
        return evaluate_handler(net, s.oracle, s.z_user, s.pd_user, s.settings, int(cfg.handler.batch_size))[0]

    real_rows = None
    if detector_inputs(cfg.detector) == "code_and_mesh" and cfg.detector.geometry.realistic_rows:
        real_rows = realistic_rows(s.space, s.ds.vertices.numpy(), s.feats.features.numpy(), s.feats.acap,
                                   s.ae_report["train_index"], s.pool, cfg.detector.geometry.train_set,
                                   s.samples_dir, float(s.sample_labeler.eps))
    cal_meshes = None
    if cfg.detector.get("operating_fnr") is not None and cfg.detector.get("operating_set") == "realistic_calibration":
        cal_meshes = calibration_meshes(s.ds.vertices.numpy(), s.feats.features.numpy(), s.feats.acap,
                                        s.ae_report["val_index"], s.pool, cfg.realistic, s.samples_dir,
                                        float(s.sample_labeler.eps))
    s.det = train_detector(s.space, s.oracle, cfg.detector, cfg.method, s.ae_report["cache_key"], int(cfg.seed),
                           cfg.paths.cache_dir, s.run_dir, s.logger,
                           round_eval=handling if cfg.handler.eval_every_round and len(s.z_user) else None,
                           real_rows=real_rows, calibration_meshes=cal_meshes)
    s.t_det = time.perf_counter() - s.t_det0


def stage_calibration(s: RunState) -> None:
    """The certified cascade's bands, one per target FNR, chosen on its calibration set."""
    if s.cfg.detector.get("cascade") is not None and s.cfg.detector.cascade.enabled:
        s.bands, s.calib_collides = calibrate(s.detector(), s.oracle, s.cfg.detector, s.ae_report["cache_key"],
                                              s.cfg.paths.cache_dir, s.rd.cascade)


def stage_handler(s: RunState) -> None:
    """The collision handler with the final detector (``handler.n_inputs = 0`` skips it); verified exactly, and
    through the cascade of each band."""
    cfg = s.cfg
    if len(s.z_user):
        s.metrics["handling"], s.handling_arrays = evaluate_handler(
            s.detector(), s.oracle, s.z_user, s.pd_user, s.settings, int(cfg.handler.batch_size),
            list(cfg.handler.verify_margins), certify=s.bands if cfg.detector.cascade.get("handler") else None)


def stage_realistic(s: RunState) -> None:
    """The realistic set: meshes nobody trained on, labeled exactly, judged beside U(Z)."""
    cfg = s.cfg
    if not cfg.realistic.enabled:
        return
    t_r = time.perf_counter()
    meshes, pd_real, real_cached = realistic_set(
        s.ds.vertices.numpy(), s.feats.features.numpy(), s.feats.acap, s.ae_report["val_index"], s.pool,
        cfg.realistic, s.samples_dir, float(s.sample_labeler.eps),
        clearance_limit=evaluation_limit(cfg.realistic, float(s.sample_labeler.eps)))
    m, s.real_arrays = evaluate_realistic(
        s.space, s.detector(), meshes, pd_real, s.pool, float(s.sample_labeler.eps), cfg.realistic, s.settings,
        list(cfg.handler.verify_margins), int(cfg.handler.batch_size), repair=repair_from_config(cfg),
        references=s.ref_spaces, render_dir=s.rd.realistic_renders)
    m.update({"from_cache": real_cached, "stage_seconds": time.perf_counter() - t_r})
    np.savez_compressed(s.rd.realistic_predictions, **s.real_arrays)
    log_realistic(s.logger, m, s.det["rounds"][-1]["dataset_size"], s.rd.realistic_renders)
    s.metrics["realistic"] = m


def stage_cascade(s: RunState) -> None:
    """The cascade's bands on the U(Z) test set and the realistic set, its throughput against the exact labeler."""
    if s.bands is None:
        return
    net = s.detector()
    detector_us = inference_us(net, s.test.z, batch_sizes=(4096,))["batch_4096"]
    s.metrics["cascade"] = cascade_stage(net, s.space, s.sample_labeler, s.test, s.bands, s.calib_collides,
                                         s.cfg.detector, detector_us, s.real_arrays)
    log_cascade(s.logger, s.metrics["cascade"], s.det["rounds"][-1]["dataset_size"])


def stage_close_pool(s: RunState) -> None:
    s.pool_stack.close()
    s.pool = None


def stage_exports(s: RunState) -> None:
    """The handled examples and the data set's example meshes, the handler's TensorBoard scalars."""
    cfg, h = s.cfg, s.metrics.get("handling")
    step = s.det["rounds"][-1]["dataset_size"]
    if h is not None:
        export_handling(s.rd.handling, s.handling_arrays, s.space, s.sample_labeler, int(cfg.handler.n_examples),
                        title=f"{cfg.dataset.name}, {cfg.method.name}", pd_sub_before=s.pd_sub_user)
        handling_logger = stage_logger(s.run_dir, "handling")
        for key in ("success_rate", "resolved_rate", "mean_pd_reduction", "mean_embedding_diff"):
            handling_logger.experiment.add_scalar(f"handling/{key}", h[key], global_step=step)
        handling_logger.finalize("success")
    s.logger.finalize("success")
    k = min(int(cfg.n_example_meshes), len(s.ds))
    if k > 0:
        write_meshes(s.rd.examples / "input", s.ds.vertices[:k], s.ds.faces, s.ds.names[:k])
        write_meshes(s.rd.examples / "acap_reconstruction", s.recon[:k], s.ds.faces, s.ds.names[:k])


def stage_summary(s: RunState) -> None:
    """The latent space's and the detector's metrics (the model-size choice too)."""
    ae, det = s.ae_report, s.det
    s.metrics.update({
        "autoencoder": {**{k_: v for k_, v in ae.items() if k_ not in ("train_index", "val_index")},
                        "from_cache": s.ae_cached, "stage_seconds": s.t_ae, "references": s.ref_errors},
        "latent": {"dim": s.space.dim, "n_parts": s.space.n_parts,
                   "uniform_collision_fraction": det["detector"]["test_set"]["base_rate"],
                   "box_probe": s.box_probe},
        "detector": {**det["detector"], "stage_seconds": s.t_det},
        "rounds": det["rounds"]})
    if s.size_doc is not None:
        s.metrics["model_size"] = {k: s.size_doc[k] for k in ("chosen", "chosen_accuracy", "best_accuracy",
                                                              "budget", "default", "rule")}


def stage_speed(s: RunState) -> None:
    """Throughput against accuracy of every method; last, as it reads the other stages' metrics."""
    sa_cfg, cfg = s.cfg.get("speed_accuracy"), s.cfg
    if sa_cfg is None or not sa_cfg.enabled:
        return
    sa = measure_speed_accuracy(s.space, s.detector(), s.test, sa_cfg, cfg.labeling, s.metrics, s.run_dir)
    s.metrics["speed_accuracy"] = sa
    plot_speed_accuracy(sa["points"], s.rd.speed_accuracy_png, f"{cfg.dataset.name}, {cfg.method.name}, seed "
                        f"{cfg.seed}: speed against accuracy (torch threads: {sa['threads']})")


# the pipeline, in order; each stage reads what the earlier ones left in the RunState and adds its own
STAGES = (stage_data, stage_latent, stage_open_pool, stage_detector, stage_calibration, stage_handler,
          stage_realistic, stage_cascade, stage_close_pool, stage_exports, stage_summary, stage_speed)


def run(cfg: DictConfig, run_dir: Path) -> dict:
    """Run the pipeline (:data:`STAGES`) for ``cfg`` and write results into ``run_dir``; returns the metrics dict."""
    validate_run_config(cfg)  # every settings error at once, before any work
    validate_model_size(cfg)
    pin_threads(cfg.get("threads", 1))  # before any work: the numbers must not depend on the core count
    seed_everything(cfg.seed if cfg.seed is not None else None)
    ctx = RunContext(cfg, run_dir)
    metrics = {"handling": None, "realistic": None, "cascade": None}
    s = RunState(cfg=cfg, run_dir=run_dir, ctx=ctx, rd=ctx.run_dir, metrics=metrics, size_doc=None, net=None,
                 bands=None, calib_collides=None, real_arrays=None, handling_arrays=None,
                 pool=None, logger=None)
    sitting.start(cfg.get("max_minutes"))
    record = SittingRecord(s.rd.sittings)
    sitting.on_check(record.progress)
    try:
        with contextlib.ExitStack() as s.pool_stack:
            for stage in STAGES:
                name = stage.__name__.removeprefix("stage_")
                sitting.check(f"the start of stage {name}")
                t0 = time.perf_counter()
                record.begin(name)
                try:
                    stage(s)
                finally:  # a stage stopped inside (at a safe point) counts its time too
                    record.stage(name, time.perf_counter() - t0)
    except sitting.SittingOver as over:
        record.close(stopped_at=over.where)
        raise
    finally:
        sitting.stop()
    record.close()
    s.metrics["sittings"] = record.summary()
    order = ("dataset", "acap", "dataset_labels", "autoencoder", "latent", "detector", "rounds", "handling",
             "realistic", "cascade", "model_size", "speed_accuracy", "sittings")
    metrics = {k: s.metrics[k] for k in order if k in s.metrics}
    log_latent(run_dir, metrics)
    s.rd.metrics.write_text(json.dumps(metrics, indent=2))
    return metrics


def box_stage(space, ref_spaces: dict, pool, cfg: DictConfig, box_fit: dict | None = None) -> dict | None:
    """Label a probe of U(Z) and of the references' boxes; stop on a degenerate box (:mod:`~neuralcol.stages.
    box_check`). The fitted box's probe (``box_fit``, same size and seed) is reused, not labeled again.
    Returns ``{"space": probe, "references": {name: probe}}`` or None when ``box_check`` is off."""
    bc = cfg.get("box_check")
    if bc is None or not bc.enabled:
        return None
    n, seed = int(bc.n_probe), int(bc.seed)
    chosen = [t for t in (box_fit or {}).get("trials", []) if t["factor"] == box_fit["factor"]]
    probe = ({k: v for k, v in chosen[0].items() if k != "factor"} if chosen
             else probe_share(space, pool, n, seed, desc="probing the box Z"))
    refs = {name: probe_share(ref, pool, n, seed, desc=f"probing the box of {name}")
            for name, ref in ref_spaces.items()} if bc.references else {}
    check_box(probe, float(bc.min_class_share), str(cfg.dataset.name), refs)
    return {"space": probe, "references": refs, "min_class_share": float(bc.min_class_share)}


def log_latent(run_dir: Path, metrics: dict) -> None:
    """TensorBoard scalars of the latent space next to its PCA references (run ``latent``, step 0)."""
    ae, la = metrics["autoencoder"], metrics["latent"]
    scalars = {"latent/train_error": ae["train_mean_vertex_error"], "latent/val_error": ae["val_mean_vertex_error"],
               "latent/uz_collision_share": la["uniform_collision_fraction"]}
    for name, ref in (ae.get("references") or {}).items():
        scalars[f"latent/{name}_train_error"] = ref.get("train_mean_vertex_error")
        scalars[f"latent/{name}_val_error"] = ref.get("val_mean_vertex_error")
    for name, p in ((la.get("box_probe") or {}).get("references") or {}).items():
        scalars[f"latent/{name}_box_collision_share"] = p.get("collision_share")
    rt = ((metrics.get("realistic") or {}).get("round_trip") or {})
    scalars["latent/round_trip_agreement"] = rt.get("agreement")
    for name, agree in (rt.get("references") or {}).items():
        scalars[f"latent/{name}_round_trip_agreement"] = agree.get("agreement")
    logger = stage_logger(run_dir, "latent")
    for k, v in scalars.items():
        if v is not None and np.isfinite(v):
            logger.experiment.add_scalar(k, float(v), global_step=0)
    logger.finalize("success")


def log_realistic(logger, m: dict, step: int, render_dir=None) -> None:
    """TensorBoard scalars of the realistic set under ``realistic/`` (at the final |D_c|), and resolve's
    before/after pictures (``realistic/resolve_<kind>``) from ``render_dir``."""
    scalars = {f"realistic/{k}": m["detection"].get(k) for k in ("accuracy", "fnr", "fpr", "skill")}
    scalars["realistic/round_trip_agreement"] = m["round_trip"]["agreement"]
    scalars["realistic/out_of_box"] = m["round_trip"]["out_of_box"]
    h = m.get("handling")
    if h:
        scalars.update({"realistic/handler_resolved_detector_only": h["detector_only"]["resolved_rate"],
                        "realistic/handler_resolved_verified": h["verified"]["resolved_rate"],
                        "realistic/handler_resolved_repair_only": (h.get("repair_only") or {}).get("resolved_rate"),
                        "realistic/handler_displacement_median_frac": h["displacement_median_frac"]})
    for k, v in scalars.items():
        if v is not None and np.isfinite(v):
            logger.experiment.add_scalar(k, float(v), global_step=step)
    if h and render_dir is not None:
        import matplotlib.image as mpimg

        for kind, name in (h.get("renders") or {}).items():
            img = mpimg.imread(Path(render_dir) / name)[..., :3]
            logger.experiment.add_image(f"realistic/resolve_{kind.replace(' ', '_')}", img, global_step=step,
                                        dataformats="HWC")


OPERATING_SETS = {"realistic": "realistic calibration meshes", "calibration": "U(Z) calibration codes",
                  "both": "realistic calibration meshes and U(Z) calibration codes",
                  "realistic_calibration": "realistic calibration meshes apart from D_c"}


def _interval(ci) -> str:
    return "" if not ci else f" [{ci[0]:.3f}, {ci[1]:.3f}]"


def round_rows(rounds: list[dict]) -> list[dict]:
    """The detector's rounds on the U(Z) test set at logit 0: the last round's figures at logit 0 where the run
    set an operating point (its top-level figures are at that point; ``at_logit_0`` keeps the others)."""
    out = [dict(r) for r in rounds]
    if out and out[-1].get("at_logit_0"):
        out[-1].update(out[-1]["at_logit_0"])
        out[-1].setdefault("balanced_accuracy", float("nan"))
    return out


def operating_point_line(op: dict) -> str:
    """The summary's line on the detector's decision threshold, the point ``run.detect``, ``resolve``, the handler
    and the realistic figures decide at: where it was set, on how many rows, what it reached there (with the FNR's
    95 % interval)."""
    cal = op["calibration"]
    n_pos = cal.get("n_colliding")
    size = f"{cal['n']} {OPERATING_SETS.get(op['operating_set'], op['operating_set'])}" + (
        f" ({n_pos} colliding)" if n_pos is not None else "")
    return (f"  (the operating point, for meshes you bring: logit > {op['threshold']:.3f}, set to FNR <= "
            f"{op['operating_fnr']:g} on {size}: FNR {cal['fnr']:.3f}{_interval(cal.get('fnr_ci95'))} there)")


def operating_verdict(d: dict, target: float | None) -> str:
    """What the realistic FNR's 95 % interval says of the operating target: above it, below it, or consistent."""
    ci = d.get("fnr_ci95")
    if target is None or not ci:
        return ""
    if ci[0] > target:
        return f"; the operating target FNR <= {target:g} is missed"
    if ci[1] < target:
        return f"; under the operating target {target:g} (the threshold is more cautious than asked)"
    return f"; consistent with the operating target {target:g}"


def print_realistic(r: dict | None, target: float | None = None) -> None:
    if not r:
        return
    d, rt = r["detection"], r["round_trip"]
    print(f"realistic meshes (nobody trained on them; {r['n_clear']} of {r['n']} clear, |PD| >= "
          f"{r['clear_eps']:g} eps; {r['base_rate_clear']:.1%} collide):")
    if d.get("n"):
        print(f"  detector: accuracy {d['accuracy']:.4f}, FNR {d['fnr']:.4f}{_interval(d.get('fnr_ci95'))} "
              f"(of {d.get('n_colliding', '?')} colliding), FPR {d['fpr']:.4f}, skill {d['skill']:.3f} "
              f"(majority {d['majority_accuracy']:.4f}){operating_verdict(d, target)}")
    agree = "n/a" if rt["agreement"] is None else f"{rt['agreement']:.1%}"
    oob = "n/a" if rt["out_of_box"] is None else f"{rt['out_of_box']:.1%}"
    print(f"  round trip keeps the exact label of {agree}; codes outside the box {oob}")
    h = r.get("handling")
    if h:
        med = h["displacement_median_frac"]
        print(f"  resolve on {h['n']} colliding meshes: collision-free {h['detector_only']['resolved_rate']:.1%} "
              f"detector-guided, {h['verified']['resolved_rate']:.1%} verified; median vertex displacement "
              f"{'n/a' if med is None else f'{med:.2%}'} of the diagonal")
        kinds = h.get("verified_by_kind")
        if kinds:
            print("    by kind of collision: " + ", ".join(
                f"{k} {v['freed']}/{v['n']} freed" for k, v in kinds.items() if v["n"]))
        if h.get("repair"):
            print(f"    (verified with the handler's margins alone {h['verified_margins_only']['resolved_rate']:.1%}; "
                  f"{h['repair']['n_repaired']} of the returned meshes are the contact repair's)")
        ro = h.get("repair_only")
        if ro:
            med = ro["displacement_median_frac"]
            print(f"  contact repair alone on the inputs (reference): collision-free {ro['resolved_rate']:.1%}, "
                  f"median vertex displacement {'n/a' if med is None else f'{med:.2%}'}, max "
                  f"{ro['displacement_max_frac']:.2%} (median over meshes)")


def latent_reference_lines(metrics: dict) -> list[str]:
    """The latent space against its PCA references: held-out error, box share, round-trip label agreement."""
    ae, la = metrics["autoencoder"], metrics["latent"]
    refs = ae.get("references") or {}
    if not refs:
        return []
    probe = la.get("box_probe") or {}
    rt = (metrics.get("realistic") or {}).get("round_trip") or {}

    def pct(x):
        return "n/a" if x is None else f"{x:.2%}"

    def share(p):
        return "n/a" if not p or p.get("collision_share") is None else f"{p['collision_share']:.1%}"

    def agree(a):
        return "n/a" if not a or a.get("agreement") is None else f"{a['agreement']:.1%}"

    name = "pca" if ae.get("kind") == "pca" else "autoencoder"
    out = ["latent space against PCA at the same |Z_all| (fit on the same training meshes):",
           "                 train err  held-out err  U(Z) collides  round trip keeps label",
           f"  {name + ' (run)':<15} {pct(ae['train_mean_vertex_error']):>9}  {pct(ae['val_mean_vertex_error']):>12}"
           f"  {share(probe.get('space')):>13}  {agree(rt):>22}"]
    for ref, e in refs.items():
        if "reason" in e:
            out.append(f"  {ref:<15} n/a: {e['reason']}")
            continue
        out.append(f"  {ref:<15} {pct(e['train_mean_vertex_error']):>9}  {pct(e['val_mean_vertex_error']):>12}"
                   f"  {share((probe.get('references') or {}).get(ref)):>13}"
                   f"  {agree((rt.get('references') or {}).get(ref)):>22}")
    return out


def print_summary(metrics: dict, run_dir: Path) -> None:
    d, a = metrics["dataset"], metrics["acap"]
    print(f"\ndata set {d['name']}: {d['n_meshes']} meshes, {d['n_vertices']} vertices, {d['n_faces']} faces")
    print(f"ACAP round trip: mean error {a['mean_rel_error']:.2e}, max {a['max_rel_error']:.2e} "
          f"(fraction of bbox diagonal); features {a['features_seconds']:.2f} s"
          f"{' (cached)' if a['features_from_cache'] else ''}, decode {a['decode_ms_per_mesh']:.1f} ms/mesh")
    lb = metrics["dataset_labels"]
    print(f"exact labels: {lb['n_colliding']} of {d['n_meshes']} meshes self-collide {lb['colliding'][:8]}; "
          f"PD in [{lb['pd_min']:.3g}, {lb['pd_max']:.3g}] ({lb['seconds']:.1f} s)")
    ae, la = metrics["autoencoder"], metrics["latent"]
    val = ae["val_mean_vertex_error"]
    print(f"autoencoder{' (cached)' if ae['from_cache'] else ''}: |Z_all| = {la['dim']}, {la['n_parts']} sub-domains "
          f"(pieces {ae['pieces']}); mean vertex error train {ae['train_mean_vertex_error']:.2%}, "
          f"val {val:.2%} of the bbox diagonal" if val is not None else "")
    for line in latent_reference_lines(metrics):
        print(line)
    dt = metrics["detector"]
    print(f"U(Z): {la['uniform_collision_fraction']:.1%} of the {dt['test_set']['n']} test samples self-collide")
    op = dt.get("operating_point")
    print(f"detector ({dt['method']}), stopped by {dt['stopped_by']}; on the U(Z) test set, at logit 0 (the paper's "
          "protocol):")
    print("  |D_c|    accuracy  FNR     FPR     balanced")
    for r in round_rows(metrics["rounds"]):
        print(f"  {r['dataset_size']:<8d} {r['accuracy']:.4f}    {r['fnr']:.4f}  {r['fpr']:.4f}  "
              f"{r['balanced_accuracy']:.4f}")
    if op:
        r = metrics["rounds"][-1]
        print(f"  at the operating point: {r['accuracy']:.4f}    {r['fnr']:.4f}  {r['fpr']:.4f}  "
              f"{r['balanced_accuracy']:.4f}")
        print(operating_point_line(op))
    h = metrics["handling"]
    if h is not None:
        print(f"collision handler on {h['n']} self-penetrating inputs, exact PD after handling:")
        print("                    success  resolved  mean PD reduction  mean |Z - Z_user|  ms per mesh")
        rows = [("detector only", h)] + ([("verified", h["verified"])] if h.get("verified") else [])
        for name, m in rows:
            print(f"  {name:<17} {m['success_rate']:>7.1%}  {m['resolved_rate']:>8.1%}  {m['mean_pd_reduction']:>17.1%}"
                  f"  {m['mean_embedding_diff']:>17.1f}  {1e3 * m['seconds_per_mesh']:>11.1f}")
        print(f"  (detector only: {h['n_nonfinite']} non-finite, {h['n_detector_infeasible']} still predicted "
              f"colliding, {h['n_not_converged']} not converged; verified includes the exact labeling)")
        for c in h.get("certified") or []:
            print(f"  verified through the cascade, FNR <= {c['target_fnr']:g}: success {c['success_rate']:.1%}, "
                  f"resolved {c['resolved_rate']:.1%}; {c['exact_calls']} exact labels of {c['decisions']} decisions "
                  f"({c['exact_share']:.1%}; full verification {c['exact_calls_verified']}); "
                  f"{c['trusted_free_colliding']} trusted free but colliding")
    print_realistic(metrics.get("realistic"), (dt.get("operating_point") or {}).get("operating_fnr"))
    for line in cascade_table(metrics.get("cascade")):
        print(line)
    if metrics.get("speed_accuracy"):
        print("\n".join(speed_accuracy_table(metrics["speed_accuracy"])))
    print(f"results: {run_dir}   (tensorboard --logdir {run_dir / 'tensorboard'})")


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
@report_user_errors
def main(cfg: DictConfig) -> None:
    # keep the terminal readable: Lightning's hardware banner and tips, a third-party deprecation warning
    logging.getLogger("lightning.pytorch.utilities.rank_zero").setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*")
    hc = HydraConfig.get()
    run_dir = Path(hc.runtime.output_dir)
    explicit_dir = any(o.startswith(("hydra.run.dir=", "hydra.sweep.dir=")) for o in hc.overrides.hydra)
    if cfg.resume and not explicit_dir:  # (an explicit directory resumes in place)
        earlier = find_interrupted_run(run_dir, multirun=hc.mode == RunMode.MULTIRUN)
        if earlier is not None:
            print(f"resuming the interrupted run in {earlier} (same overrides, unfinished); resume=false starts "
                  "afresh", flush=True)
            RunDir(run_dir).resumed_in.write_text(f"{earlier}\n")
            run_dir = earlier
    try:
        with RunDirLock(run_dir):
            metrics = run(cfg, run_dir)
    except sitting.SittingOver as over:
        print(f"[sitting] {over}. Run directory: {run_dir} (exit code {sitting.EXIT_CODE})", flush=True)
        sys.exit(sitting.EXIT_CODE)
    print_summary(metrics, run_dir)


if __name__ == "__main__":
    main()
