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

import json
import logging
import time
import warnings
from pathlib import Path

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
from neuralcol.stages.mesh_detector import mesh_detector_stage
from neuralcol.stages.model_size import search_model_size, validate_model_size
from neuralcol.stages.realistic import evaluate_realistic, realistic_set
from neuralcol.stages.speed import measure_speed_accuracy, speed_accuracy_table
from neuralcol.stages.validate import validate_run_config
from neuralcol.utils.cli import report_user_errors
from neuralcol.utils.resume import RunDirLock, find_interrupted_run
from neuralcol.utils.seeding import seed_everything
from neuralcol.utils.threads import pin_threads


def run(cfg: DictConfig, run_dir: Path) -> dict:
    """Run the pipeline for ``cfg`` and write results into ``run_dir``; returns the metrics dict."""
    validate_run_config(cfg)  # every settings error at once, before any work
    validate_model_size(cfg)
    pin_threads(cfg.get("threads", 1))  # before any work: the numbers must not depend on the core count
    seed_everything(cfg.seed if cfg.seed is not None else None)
    ctx = RunContext(cfg, run_dir)
    rd = ctx.run_dir
    t0 = time.perf_counter()
    ds = ctx.dataset
    t_load = time.perf_counter() - t0
    t0 = time.perf_counter()
    feats = ctx.features
    t_encode = time.perf_counter() - t0
    size_doc = None
    if cfg.get("model_size") is not None and cfg.model_size.mode == "auto":  # choose the sizes first (issue 17)
        cfg, size_doc = search_model_size(cfg, run_dir, ds, feats, run, train_or_load_latent_space)
        seed_everything(cfg.seed if cfg.seed is not None else None)  # as if the sizes had been given
        ctx = ctx.reconfigured(cfg)
    recon, acap_metrics = acap_round_trip(ds, feats)
    faces, rest = ctx.faces, ctx.rest
    # exact labels of the data set's own meshes (the paper assumes they are (nearly) collision-free)
    with ctx.pool(ctx.labeler(), desc="labeling data set") as pool:
        label_metrics = dataset_labels(ds, pool)
    # bilevel autoencoder (trained, or loaded from the cache) and its latent space; TensorBoard: one run per
    # stage under <run dir>/tensorboard/ (neuralcol/metrics/tensorboard.py)
    t0 = time.perf_counter()
    space, ae_report, ae_cached = ctx.latent_space(lambda stage: stage_logger(run_dir, stage))
    t_ae = time.perf_counter() - t0
    part = space.partition.numpy()
    render_mesh_png(rd.subdomains_png, rest, faces, partition_colors(part),
                    title=f"{cfg.dataset.name}: {space.n_parts} sub-domains")
    colors = (partition_colors(part)[:, :3] * 255).astype("uint8")
    data_logger = stage_logger(run_dir, "data")
    data_logger.experiment.add_mesh("subdomains", vertices=torch.as_tensor(rest[None]).float(),
                               colors=torch.as_tensor(colors[None]), faces=torch.as_tensor(faces[None]))
    data_logger.finalize("success")
    logger = stage_logger(run_dir, f"detector_{cfg.method.name}")
    # the neural collision detector, trained by the configured method on labeled decoded samples
    sample_labeler = ctx.sample_labeler()
    t0 = time.perf_counter()
    settings = alm_settings(cfg.handler.alm)
    ref_spaces, ref_errors = ctx.references  # PCA at the same |Z_all| (issue 40)
    with ctx.pool(sample_labeler) as pool:
        box_fit = ctx.fit_box(pool, sample_labeler)  # issue 40: the box scaled until U(Z) is worth sampling
        ae_report = ctx.latent_space().report  # a fitted box has its own cache key
        oracle = ctx.oracle(pool)
        box_probe = box_stage(space, ref_spaces, pool, cfg, box_fit)
        # inputs of the collision handler: the first colliding rows of the shared test set
        test, _, _ = shared_test_set(oracle, cfg.detector, ae_report["cache_key"], cfg.paths.cache_dir)
        pick = np.flatnonzero(test.pd > 0)[: int(cfg.handler.n_inputs)]
        z_user, pd_user, pd_sub_user = torch.as_tensor(test.z[pick]), test.pd[pick], test.pd_sub[pick]

        def handling(net):
            # per round the detector alone (paper Fig. 5); the verified variant is for the final detector
            return evaluate_handler(net, oracle, z_user, pd_user, settings, int(cfg.handler.batch_size))[0]

        # issue 41: the detector over code and mesh trains on realistic training meshes too (rows of D_c)
        samples_dir = ctx.samples_dir(sample_labeler)
        one_detector = detector_inputs(cfg.detector) == "code_and_mesh"
        real_rows = None
        if one_detector and cfg.detector.geometry.realistic_rows:
            real_rows = realistic_rows(space, ds.vertices.numpy(), feats.features.numpy(), feats.acap,
                                       ae_report["train_index"], pool, cfg.mesh_detector.train_set, samples_dir,
                                       float(sample_labeler.eps))
        det = train_detector(space, oracle, cfg.detector, cfg.method, ae_report["cache_key"], int(cfg.seed),
                             cfg.paths.cache_dir, run_dir, logger,
                             round_eval=handling if cfg.handler.eval_every_round and len(z_user) else None,
                             real_rows=real_rows)
        t_det = time.perf_counter() - t0

        def final_detector():  # the final detector as a function of codes (decoding what its features read)
            return DetectorOnCodes(load_detector(rd.detector)[0], space)

        # the certified cascade (issue 29): a band of doubt per target FNR, chosen on its calibration set
        bands, calib_collides = None, None
        if cfg.detector.get("cascade") is not None and cfg.detector.cascade.enabled:
            net = final_detector()
            bands, calib_collides = calibrate(net, oracle, cfg.detector, ae_report["cache_key"], cfg.paths.cache_dir,
                                              rd.cascade)
        # the collision handler with the final detector (handler.n_inputs = 0 skips it); verified exactly, and
        # through the cascade of each band
        handling_metrics, arrays = None, None
        if len(z_user):
            net = final_detector()
            handling_metrics, arrays = evaluate_handler(net, oracle, z_user, pd_user, settings,
                                                        int(cfg.handler.batch_size), list(cfg.handler.verify_margins),
                                                        certify=bands if cfg.detector.cascade.get("handler")
                                                        else None)
        # the detector that reads the mesh (issue 27): decoded D_c + realistic training meshes (not beside the
        # detector over code and mesh, which reads the mesh itself)
        mesh_net, mesh_report = None, None
        if cfg.mesh_detector.enabled and not one_detector:
            mesh_net, mesh_report = mesh_detector_stage(
                space, ds.vertices.numpy(), feats.features.numpy(), feats.acap, ae_report["train_index"], pool,
                cfg.mesh_detector, samples_dir, float(sample_labeler.eps), rd.dc, int(cfg.seed),
                run_dir, test=test, logger=stage_logger(run_dir, "mesh_detector"))
        # the realistic set (issue 27): meshes nobody trained on, labeled exactly, next to U(Z)
        realistic_metrics = None
        if cfg.realistic.enabled:
            t_r = time.perf_counter()
            meshes, pd_real, real_cached = realistic_set(
                ds.vertices.numpy(), feats.features.numpy(), feats.acap, ae_report["val_index"], pool,
                cfg.realistic, samples_dir, float(sample_labeler.eps))
            net = final_detector()
            realistic_metrics, real_arrays = evaluate_realistic(
                space, net, meshes, pd_real, pool, float(sample_labeler.eps), cfg.realistic, settings,
                list(cfg.handler.verify_margins), int(cfg.handler.batch_size), mesh_net=mesh_net,
                repair=repair_from_config(cfg), references=ref_spaces)
            realistic_metrics.update({"from_cache": real_cached, "stage_seconds": time.perf_counter() - t_r})
            np.savez_compressed(rd.realistic_predictions, **real_arrays)
            log_realistic(logger, realistic_metrics, det["rounds"][-1]["dataset_size"])
        # the cascade's bands on the U(Z) test set and the realistic set, its throughput against the exact labeler
        cascade_metrics = None
        if bands is not None:
            net = final_detector()
            detector_us = inference_us(net, test.z, batch_sizes=(4096,))["batch_4096"]
            cascade_metrics = cascade_stage(net, space, sample_labeler, test, bands, calib_collides, cfg.detector,
                                            detector_us, real_arrays if realistic_metrics is not None else None)
            log_cascade(logger, cascade_metrics, det["rounds"][-1]["dataset_size"])
    if handling_metrics is not None:
        export_handling(rd.handling, arrays, space, sample_labeler, int(cfg.handler.n_examples),
                        title=f"{cfg.dataset.name}, {cfg.method.name}", pd_sub_before=pd_sub_user)
        handling_logger = stage_logger(run_dir, "handling")
        for key in ("success_rate", "resolved_rate", "mean_pd_reduction", "mean_embedding_diff"):
            handling_logger.experiment.add_scalar(f"handling/{key}", handling_metrics[key],
                                                  global_step=det["rounds"][-1]["dataset_size"])
        handling_logger.finalize("success")
    logger.finalize("success")
    k = min(int(cfg.n_example_meshes), len(ds))
    if k > 0:
        write_meshes(rd.examples / "input", ds.vertices[:k], ds.faces, ds.names[:k])
        write_meshes(rd.examples / "acap_reconstruction", recon[:k], ds.faces, ds.names[:k])
    metrics = {
        "dataset": {"name": cfg.dataset.name, "source": ds.source, "n_meshes": len(ds),
                    "n_vertices": ds.n_vertices, "n_faces": int(ds.faces.shape[0]), "load_seconds": t_load},
        "acap": {**{k_: v for k_, v in acap_metrics.items() if k_ != "decode_ms_per_mesh"},
                 "features_seconds": t_encode, "features_from_cache": feats.from_cache,
                 "decode_ms_per_mesh": acap_metrics["decode_ms_per_mesh"]},
        "dataset_labels": label_metrics,
        "autoencoder": {**{k_: v for k_, v in ae_report.items() if k_ not in ("train_index", "val_index")},
                        "from_cache": ae_cached, "stage_seconds": t_ae, "references": ref_errors},
        "latent": {"dim": space.dim, "n_parts": space.n_parts,
                   "uniform_collision_fraction": det["detector"]["test_set"]["base_rate"], "box_probe": box_probe},
        "detector": {**det["detector"], "stage_seconds": t_det},
        "rounds": det["rounds"],
        "handling": handling_metrics,
        "mesh_detector": mesh_report,
        "realistic": realistic_metrics,
        "cascade": cascade_metrics,
    }
    if size_doc is not None:
        metrics["model_size"] = {k: size_doc[k] for k in ("chosen", "chosen_accuracy", "best_accuracy", "budget",
                                                            "default", "rule")}
    sa_cfg = cfg.get("speed_accuracy")
    if sa_cfg is not None and sa_cfg.enabled:  # issue 29: last, as it reads the other stages' metrics (cascade)
        sa = measure_speed_accuracy(space, DetectorOnCodes(load_detector(rd.detector)[0], space), test, sa_cfg,
                                    cfg.labeling, metrics, mesh_net, run_dir)
        metrics["speed_accuracy"] = sa
        plot_speed_accuracy(sa["points"], rd.speed_accuracy_png, f"{cfg.dataset.name}, {cfg.method.name}, seed "
                            f"{cfg.seed}: speed against accuracy (torch threads: {sa['threads']})")
    log_latent(run_dir, metrics)
    rd.metrics.write_text(json.dumps(metrics, indent=2))
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


def log_realistic(logger, m: dict, step: int) -> None:
    """TensorBoard scalars of the realistic set under ``realistic/`` (at the final |D_c|)."""
    scalars = {f"realistic/{k}": m["detection"].get(k) for k in ("accuracy", "fnr", "fpr", "skill")}
    scalars.update({f"realistic/mesh_{k}": m.get("detection_mesh", {}).get(k) for k in ("accuracy", "fnr", "skill")})
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


def print_realistic(r: dict | None) -> None:
    if not r:
        return
    d, rt = r["detection"], r["round_trip"]
    print(f"realistic meshes (nobody trained on them; {r['n_clear']} of {r['n']} clear, |PD| >= "
          f"{r['clear_eps']:g} eps; {r['base_rate_clear']:.1%} collide):")
    if d.get("n"):
        print(f"  detector: accuracy {d['accuracy']:.4f}, FNR {d['fnr']:.4f}, FPR {d['fpr']:.4f}, skill "
              f"{d['skill']:.3f} (majority {d['majority_accuracy']:.4f})")
    dm = r.get("detection_mesh")
    if dm and dm.get("n"):
        print(f"  mesh detector: accuracy {dm['accuracy']:.4f}, FNR {dm['fnr']:.4f}, FPR {dm['fpr']:.4f}, skill "
              f"{dm['skill']:.3f}")
    agree = "n/a" if rt["agreement"] is None else f"{rt['agreement']:.1%}"
    oob = "n/a" if rt["out_of_box"] is None else f"{rt['out_of_box']:.1%}"
    print(f"  round trip keeps the exact label of {agree}; codes outside the box {oob}")
    h = r.get("handling")
    if h:
        med = h["displacement_median_frac"]
        print(f"  resolve on {h['n']} colliding meshes: collision-free {h['detector_only']['resolved_rate']:.1%} "
              f"detector-guided, {h['verified']['resolved_rate']:.1%} verified; median vertex displacement "
              f"{'n/a' if med is None else f'{med:.2%}'} of the diagonal")
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
    print(f"detector ({dt['method']}), stopped by {dt['stopped_by']}:")
    print("  |D_c|    accuracy  FNR     FPR     balanced")
    for r in metrics["rounds"]:
        print(f"  {r['dataset_size']:<8d} {r['accuracy']:.4f}    {r['fnr']:.4f}  {r['fpr']:.4f}  "
              f"{r['balanced_accuracy']:.4f}")
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
    md = metrics.get("mesh_detector")
    if md:
        t = md["test"]
        print(f"mesh detector ({md['n_pairs']} contact pairs, {md['n_rows']} rows: D_c decoded + "
              f"{md['n_realistic']} realistic training meshes, {md['seconds']:.0f} s): U(Z) accuracy "
              f"{t['accuracy']:.4f}, FNR {t['fnr']:.4f}, FPR {t['fpr']:.4f}")
    print_realistic(metrics.get("realistic"))
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
    with RunDirLock(run_dir):
        metrics = run(cfg, run_dir)
    print_summary(metrics, run_dir)


if __name__ == "__main__":
    main()
