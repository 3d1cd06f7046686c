"""The pipeline's stages: each a function of exactly what it needs, returning a typed result.

:func:`neuralcol.pipeline.run.run_pipeline` calls them in order and hands each result on to the stages that read it;
the stage logic itself lives in ``neuralcol/stages/`` (one module per concern, none importing another), the pieces
every run is built from in :class:`~neuralcol.pipeline.context.RunContext`. Nothing here prints or logs to
TensorBoard: the run's :class:`~neuralcol.pipeline.run.Reporter` gets the Lightning loggers' factory, the progress
lines and, at the end, every result.

Symbols: N data set meshes, V vertices, F faces, K sub-domains, D = |Z_all|, T test codes, M handler inputs.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from neuralcol.data.datasets import MeshDataset
from neuralcol.data.features import DatasetFeatures
from neuralcol.geometry.mesh_io import write_meshes
from neuralcol.handler.alm import ALMSettings
from neuralcol.handler.resolve import alm_settings
from neuralcol.metrics.cascade import Band
from neuralcol.metrics.plots import partition_colors, render_mesh_png
from neuralcol.nn.part_geometry import DetectorOnCodes, detector_inputs
from neuralcol.operating import needs_calibration_meshes
from neuralcol.pipeline.context import LatentStage, RunContext
from neuralcol.repair.settings import repair_from_config
from neuralcol.rundir import RunDir
from neuralcol.samples.cache import shared_test_set
from neuralcol.samples.oracle import LatentOracle
from neuralcol.samples.realistic import calibration_meshes, evaluation_limit, realistic_rows, realistic_set
from neuralcol.samples.store import CollisionRows
from neuralcol.stages.box_check import box_stage
from neuralcol.stages.cascade import calibrate, cascade_stage
from neuralcol.stages.data import acap_round_trip, dataset_labels
from neuralcol.stages.detector import inference_us, train_detector
from neuralcol.stages.handler import evaluate_handler, export_handling
from neuralcol.stages.realistic import evaluate_realistic
from neuralcol.stages.speed import measure_speed_accuracy

MODEL_SIZE_KEYS = ("chosen", "chosen_accuracy", "best_accuracy", "budget", "default", "rule")  # metrics["model_size"]


# ----------------------------------------------------------------------------------------------------------- data
class DataResult(NamedTuple):
    """Stage ``data``: the data set and what is measured on its own meshes.

    Attributes:
        dataset: the N meshes (``vertices`` (N, V, 3), ``faces`` (F, 3), ``names``).
        features: their raw ACAP features (N, V, 9) float32, the ACAP transform and the normaliser.
        reconstruction: (N, V, 3) the ACAP round trip of the meshes, in the data set's dtype.
        metrics: ``metrics.json``'s ``dataset``, ``acap`` and ``dataset_labels`` (seconds in s, errors as fractions
            of the bounding-box diagonal).
    """

    dataset: MeshDataset
    features: DatasetFeatures
    reconstruction: torch.Tensor
    metrics: dict


def data(ctx: RunContext) -> DataResult:
    """Load the data set and its ACAP features, check the ACAP round trip, label the data set's own meshes exactly
    (the paper assumes they are (nearly) collision-free)."""
    cfg = ctx.cfg
    t0 = time.perf_counter()
    ds = ctx.dataset
    t_load = time.perf_counter() - t0
    t0 = time.perf_counter()
    feats = ctx.features
    t_encode = time.perf_counter() - t0
    recon, acap_metrics = acap_round_trip(ds, feats)
    # a small data set is labeled here: the worker processes would take longer to start than the labels
    here = len(ds) <= int(cfg.labeling.get("data_in_process", 0))
    local = {"workers": 0, "executor": "local", "scheduler": None} if here else {}
    with ctx.pool(ctx.labeler(), desc="labeling data set", **local) as pool:
        label_metrics = dataset_labels(ds, pool)
    metrics = {
        "dataset": {"name": cfg.dataset.name, "source": ds.source, "n_meshes": len(ds),
                    "n_vertices": ds.n_vertices, "n_faces": int(ds.faces.shape[0]), "load_seconds": t_load},
        "acap": {**{k: v for k, v in acap_metrics.items() if k != "decode_ms_per_mesh"},
                 "features_seconds": t_encode, "features_from_cache": feats.from_cache,
                 "decode_ms_per_mesh": acap_metrics["decode_ms_per_mesh"]},
        "dataset_labels": label_metrics}
    return DataResult(ds, feats, recon, metrics)


# --------------------------------------------------------------------------------------------------------- latent
class LatentResult(NamedTuple):
    """Stage ``latent``: the latent space with the paper's box, trained or read from the cache.

    Attributes:
        space: the latent space (D entries, K sub-domains).
        report: the autoencoder's report (errors as fractions of the diagonal, sizes, ``cache_key``,
            ``train_index`` / ``val_index`` of its training and held-out meshes).
        from_cache: the autoencoder was read from the cache.
        seconds: wall time of training or loading it.
    """

    space: torch.nn.Module
    report: dict
    from_cache: bool
    seconds: float


def latent(ctx: RunContext, rd: RunDir, logger_factory: Callable[[str], object]) -> LatentResult:
    """The latent space (``logger_factory``: stage name -> Lightning logger of the autoencoder's training) and a
    picture of its sub-domains (``subdomains.png``)."""
    t0 = time.perf_counter()
    space, report, cached = ctx.latent_space(logger_factory)
    seconds = time.perf_counter() - t0
    render_mesh_png(rd.subdomains_png, ctx.rest, ctx.faces, partition_colors(space.partition.numpy()),
                    title=f"{ctx.cfg.dataset.name}: {space.n_parts} sub-domains")
    return LatentResult(space, report, cached, seconds)


# ------------------------------------------------------------------------------------------------------ open_pool
class HandlerInputs(NamedTuple):
    """The handler's inputs: the first ``handler.n_inputs`` colliding codes of the U(Z) test set, z (M, D) float32
    tensor, their exact PD (M,) and PD per sub-domain (M, K)."""

    z: torch.Tensor
    pd: np.ndarray
    pd_sub: np.ndarray


class Sampling(NamedTuple):
    """Stage ``open_pool``: what every later stage samples and labels with (the pool is open until ``close_pool``).

    Attributes:
        labeler: the exact labeler of decoded samples (PD_i over the K sub-domains; ``eps`` its boundary width).
        pool: its label pool.
        latent: the latent space the run samples: the box fitted (``box_fit``; a new space, its own ``cache_key``,
            ``report["box_fit"]``) or the paper's; its ``report`` is ``metrics.json``'s ``autoencoder``.
        oracle: codes of ``latent.space`` -> decoded meshes -> exact labels, through ``pool``.
        samples_dir: ``<cache>/collision/<key>`` of ``latent`` and ``labeler`` (the cached labeled sets).
        references: ``{name: PCA latent space}`` at the same |Z_all| (vertex and ACAP PCA).
        reference_errors: ``{name: their reconstruction errors, or why there are none}``.
        box_probe: ``box_check``'s probe of U(Z) and of the references' boxes (``latent.box_probe``), or None.
        test: the shared U(Z) test set (T rows: z (T, D), pd (T,), pd_sub (T, K), collides (T,), ...).
        handler_inputs: the handler's inputs, taken from ``test``.
        settings: the handler's augmented-Lagrangian settings (``handler.alm``).
        started: ``time.perf_counter()`` at the stage's start (the detector's stage time counts this stage too).
    """

    labeler: object
    pool: object
    latent: LatentStage
    oracle: LatentOracle
    samples_dir: object
    references: dict
    reference_errors: dict
    box_probe: dict | None
    test: CollisionRows
    handler_inputs: HandlerInputs
    settings: ALMSettings
    started: float


def open_pool(ctx: RunContext, pools: contextlib.ExitStack) -> Sampling:
    """Open the sample labeler's pool (on ``pools``), fit the box Z, probe it, label (or read) the shared U(Z) test
    set and take the handler's inputs from it."""
    cfg = ctx.cfg
    labeler = ctx.sample_labeler()
    started = time.perf_counter()
    settings = alm_settings(cfg.handler.alm)
    references, reference_errors = ctx.references  # PCA at the same |Z_all|
    pool = pools.enter_context(ctx.pool(labeler))
    paper_box = ctx.latent_space()
    fitted = ctx.fit_box(pool, labeler)  # a new space, its box scaled until U(Z) is worth sampling
    fit = None if fitted is paper_box else fitted.report["box_fit"]
    oracle = ctx.oracle(pool, fitted)
    box_probe = box_stage(fitted.space, references, pool, cfg, fit)
    test, _, _ = shared_test_set(oracle, cfg.detector, fitted.report["cache_key"], cfg.paths.cache_dir)
    pick = np.flatnonzero(test.pd > 0)[: int(cfg.handler.n_inputs)]
    inputs = HandlerInputs(torch.as_tensor(test.z[pick]), test.pd[pick], test.pd_sub[pick])
    return Sampling(labeler, pool, fitted, oracle, ctx.samples_dir(labeler, fitted), references, reference_errors,
                    box_probe, test, inputs, settings, started)


# ------------------------------------------------------------------------------------------------------- detector
class DetectorResult(NamedTuple):
    """Stage ``detector``: the trained neural collision detector.

    Attributes:
        rounds: ``metrics.json``'s ``rounds`` (one record per round; fractions on the U(Z) test set, |D_c|).
        summary: ``metrics.json``'s ``detector`` without ``stage_seconds``.
        net: the final detector on codes (operating threshold folded in; what ``detector.pt`` holds).
        seconds: the stage's wall time, counted from the start of ``open_pool`` (box fit and test set included).
    """

    rounds: list[dict]
    summary: dict
    net: DetectorOnCodes
    seconds: float


def detector(cfg: DictConfig, data: DataResult, sampling: Sampling, run_dir, logger,
             round_done: Callable[[str, dict], None] | None = None) -> DetectorResult:
    """Train the detector by the configured method round by round (``detector.inputs``: on the codes, or on code and
    mesh with the realistic training meshes among its rows). ``logger``: its Lightning logger; ``round_done(method,
    record)``: after every finished round."""
    s, det = sampling, cfg.detector
    ds, feats, report = data.dataset, data.features, s.latent.report
    eps = float(s.labeler.eps)
    inputs = s.handler_inputs

    def handling(net):  # per round the detector alone (paper Fig. 5); the verified variant is for the final one
        return evaluate_handler(net, s.oracle, inputs.z, inputs.pd, s.settings, int(cfg.handler.batch_size))[0]

    real_rows = None
    if detector_inputs(det) == "code_and_mesh" and det.geometry.realistic_rows:
        # D_c's realistic training meshes: from the autoencoder's training meshes (not the realistic test set's)
        real_rows = realistic_rows(s.latent.space, ds.vertices.numpy(), feats.features.numpy(), feats.acap,
                                   report["train_index"], s.pool, det.geometry.train_set, s.samples_dir, eps)
    cal_meshes = None
    if needs_calibration_meshes(det, cfg.realistic.enabled):
        # the realistic calibration set: drawn like the test set with its own seed, its held-out meshes left out
        cal_meshes = calibration_meshes(ds.vertices.numpy(), feats.features.numpy(), feats.acap, report["val_index"],
                                        s.pool, cfg.realistic, s.samples_dir, eps)
    trained = train_detector(s.latent.space, s.oracle, det, cfg.method, report["cache_key"], int(cfg.seed),
                             cfg.paths.cache_dir, run_dir, logger,
                             round_eval=handling if cfg.handler.eval_every_round and len(inputs.z) else None,
                             real_rows=real_rows, calibration_meshes=cal_meshes, round_done=round_done)
    return DetectorResult(trained.rounds, trained.summary, trained.net, time.perf_counter() - s.started)


# ---------------------------------------------------------------------------------------------------- calibration
class Calibration(NamedTuple):
    """Stage ``calibration``: the certified cascade's bands, ``{target FNR: Band}`` (None: no calibration sample
    collides), and the calibration set's exact labels (C,) bool."""

    bands: dict[float, Band] | None
    collides: np.ndarray


def calibration(cfg: DictConfig, net: DetectorOnCodes, sampling: Sampling, rd: RunDir,
                log: Callable[[str], None]) -> Calibration | None:
    """The certified cascade's bands, one per target FNR, chosen on its calibration set (``cascade.npz``); None
    when ``detector.cascade`` is off."""
    c = cfg.detector.get("cascade")
    if c is None or not c.enabled:
        return None
    bands, collides = calibrate(net, sampling.oracle, cfg.detector, sampling.latent.report["cache_key"],
                                cfg.paths.cache_dir, rd.cascade, log=log)
    return Calibration(bands, collides)


# -------------------------------------------------------------------------------------------------------- handler
class Handling(NamedTuple):
    """Stage ``handler``: ``metrics.json``'s ``handling`` (rates as fractions, seconds per mesh) and the per-input
    arrays (M rows: z, pd_before, pd_after, reduction, ...; ``handling/handling.npz``)."""

    metrics: dict
    arrays: dict


def handler(cfg: DictConfig, net: DetectorOnCodes, sampling: Sampling,
            bands: dict[float, Band] | None) -> Handling | None:
    """The collision handler with the final detector on the handler's inputs, verified exactly and, with
    ``detector.cascade.handler``, through the cascade of each band; None without inputs (``handler.n_inputs=0``)."""
    s, inputs = sampling, sampling.handler_inputs
    if not len(inputs.z):
        return None
    m, arrays = evaluate_handler(net, s.oracle, inputs.z, inputs.pd, s.settings, int(cfg.handler.batch_size),
                                 list(cfg.handler.verify_margins),
                                 certify=bands if cfg.detector.cascade.get("handler") else None)
    return Handling(m, arrays)


# ------------------------------------------------------------------------------------------------------ realistic
class Realistic(NamedTuple):
    """Stage ``realistic``: ``metrics.json``'s ``realistic`` (fractions, counts, seconds) and the per-mesh arrays
    (codes, logits, exact and round-trip PD, clear mask, kinds, the handler's results; ``realistic_predictions.npz``).
    """

    metrics: dict
    arrays: dict


def realistic(cfg: DictConfig, data: DataResult, sampling: Sampling, net: DetectorOnCodes,
              rd: RunDir) -> Realistic | None:
    """The realistic test set (meshes nobody trained on, labeled exactly) judged beside U(Z); None when
    ``realistic.enabled`` is false."""
    if not cfg.realistic.enabled:
        return None
    s, ds, feats = sampling, data.dataset, data.features
    eps = float(s.labeler.eps)
    t0 = time.perf_counter()
    # the realistic test set: from every data set mesh, the autoencoder's held-out ones among the candidates (not
    # the detector stage's realistic training meshes nor its calibration set, which are other draws)
    meshes, pd, cached = realistic_set(ds.vertices.numpy(), feats.features.numpy(), feats.acap,
                                       s.latent.report["val_index"], s.pool, cfg.realistic, s.samples_dir, eps,
                                       clearance_limit=evaluation_limit(cfg.realistic, eps))
    m, arrays = evaluate_realistic(s.latent.space, net, meshes, pd, s.pool, eps, cfg.realistic, s.settings,
                                   list(cfg.handler.verify_margins), int(cfg.handler.batch_size),
                                   repair=repair_from_config(cfg), references=s.references,
                                   render_dir=rd.realistic_renders)
    m.update({"from_cache": cached, "stage_seconds": time.perf_counter() - t0})
    np.savez_compressed(rd.realistic_predictions, **arrays)
    return Realistic(m, arrays)


# -------------------------------------------------------------------------------------------------------- cascade
def cascade(cfg: DictConfig, net: DetectorOnCodes, sampling: Sampling, cal: Calibration | None,
            real: Realistic | None) -> dict | None:
    """``metrics.json``'s ``cascade``: the bands on the U(Z) test set and the realistic set, the throughput against
    the exact labeler (µs and ms per sample); None without bands."""
    if cal is None or cal.bands is None:
        return None
    timed = inference_us(net, sampling.test.z, batch_sizes=(4096,))  # (fewer rows for a detector with summaries)
    detector_us = next(v for k, v in timed.items() if k.startswith("batch_"))
    return cascade_stage(net, sampling.latent.space, sampling.labeler, sampling.test, cal.bands, cal.collides,
                         cfg.detector, detector_us, None if real is None else real.arrays)


# -------------------------------------------------------------------------------------------------------- exports
def exports(cfg: DictConfig, rd: RunDir, data: DataResult, sampling: Sampling, handling: Handling | None) -> None:
    """The handled examples (``handling/``) and the data set's example meshes with their ACAP reconstruction
    (``examples/``)."""
    if handling is not None:
        export_handling(rd.handling, handling.arrays, sampling.latent.space, sampling.labeler,
                        int(cfg.handler.n_examples), title=f"{cfg.dataset.name}, {cfg.method.name}",
                        pd_sub_before=sampling.handler_inputs.pd_sub)
    ds = data.dataset
    k = min(int(cfg.n_example_meshes), len(ds))
    if k > 0:
        write_meshes(rd.examples / "input", ds.vertices[:k], ds.faces, ds.names[:k])
        write_meshes(rd.examples / "acap_reconstruction", data.reconstruction[:k], ds.faces, ds.names[:k])


# -------------------------------------------------------------------------------------------------------- summary
class Summary(NamedTuple):
    """Stage ``summary``: ``metrics.json``'s sections on the models.

    Attributes:
        autoencoder: the latent space's report (errors as fractions of the diagonal, sizes, ``cache_key``, the box
            fit), whether it came from the cache, its stage time (s) and the PCA references' errors.
        latent: |Z_all| (``dim``), K (``n_parts``), the U(Z) test set's collision fraction, the box probe.
        detector: the detector's summary and its stage time (s).
        rounds: the rounds' records.
        model_size: the choice of the searched preset the run took its sizes from (``chosen``, accuracies,
            ``budget``, ``default``, ``rule``), or None.
    """

    autoencoder: dict
    latent: dict
    detector: dict
    rounds: list[dict]
    model_size: dict | None


def summary(cfg: DictConfig, latent: LatentResult, sampling: Sampling, detector: DetectorResult) -> Summary:
    """The models' sections of ``metrics.json`` from the latent space, the sampling and the detector."""
    ae = sampling.latent.report
    ms = cfg.get("model_size")
    chosen = None
    if ms is not None and ms.get("chosen") is not None:
        chosen = {k: OmegaConf.to_container(ms[k]) if OmegaConf.is_config(ms[k]) else ms[k] for k in MODEL_SIZE_KEYS}
    return Summary(
        autoencoder={**{k: v for k, v in ae.items() if k not in ("train_index", "val_index")},
                     "from_cache": latent.from_cache, "stage_seconds": latent.seconds,
                     "references": sampling.reference_errors},
        latent={"dim": sampling.latent.space.dim, "n_parts": sampling.latent.space.n_parts,
                "uniform_collision_fraction": detector.summary["test_set"]["base_rate"],
                "box_probe": sampling.box_probe},
        detector={**detector.summary, "stage_seconds": detector.seconds},
        rounds=detector.rounds,
        model_size=chosen)


# ---------------------------------------------------------------------------------------------------------- speed
def speed(cfg: DictConfig, sampling: Sampling, net: DetectorOnCodes, metrics: dict, run_dir,
          log: Callable[[str], None]) -> dict | None:
    """``metrics.json``'s ``speed_accuracy``: throughput (samples/s) against accuracy and FNR of every method on the
    U(Z) test set; last, as it reads the cascade's metrics (``metrics``); None when ``speed_accuracy`` is off."""
    sa_cfg = cfg.get("speed_accuracy")
    if sa_cfg is None or not sa_cfg.enabled:
        return None
    return measure_speed_accuracy(sampling.latent.space, net, sampling.test, sa_cfg, cfg.labeling, metrics, run_dir,
                                  log=log)
