"""The pipeline of one run: its stages in order, each result handed on explicitly, ``metrics.json`` at the end.

data -> latent -> open_pool -> detector -> calibration -> handler -> realistic -> cascade -> close_pool -> exports
-> summary -> speed (:data:`STAGES`; the functions and their typed results: :mod:`neuralcol.pipeline.steps`). Every
stage starts at a safe point of the sitting (:mod:`neuralcol.utils.sitting`) and its wall time goes into
``sittings.json`` (:mod:`neuralcol.utils.sitting_record`) under its name, summed in ``metrics["sittings"]``.

What the outside sees of a run goes through a :class:`Reporter`: the Lightning loggers of the trainings, progress
lines, each finished round of the detector and, before ``metrics.json`` is written, every result
(:class:`RunResults`). ``experiments.reporting.run_report.RunReport`` prints and logs them to TensorBoard.
"""

from __future__ import annotations

import contextlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

from omegaconf import DictConfig

from neuralcol.pipeline import steps
from neuralcol.pipeline.context import RunContext
from neuralcol.pipeline.validate import validate_run_config
from neuralcol.rundir import RunDir
from neuralcol.utils import sitting
from neuralcol.utils.seeding import seed_everything
from neuralcol.utils.sitting_record import SittingRecord
from neuralcol.utils.threads import pin_threads

STAGES = ("data", "latent", "open_pool", "detector", "calibration", "handler", "realistic", "cascade", "close_pool",
          "exports", "summary", "speed")
METRICS_ORDER = ("dataset", "acap", "dataset_labels", "autoencoder", "latent", "detector", "rounds", "handling",
                 "realistic", "cascade", "model_size", "speed_accuracy", "sittings")  # metrics.json's keys, in order


@dataclass(frozen=True)
class RunResults:
    """Every stage's result of a finished run (:mod:`neuralcol.pipeline.steps`) and ``metrics.json``'s content
    (``metrics``, keys in :data:`METRICS_ORDER`)."""

    cfg: DictConfig
    run_dir: RunDir
    data: steps.DataResult
    latent: steps.LatentResult
    sampling: steps.Sampling
    detector: steps.DetectorResult
    calibration: steps.Calibration | None
    handling: steps.Handling | None
    realistic: steps.Realistic | None
    cascade: dict | None
    speed: dict | None
    metrics: dict


class Reporter:
    """What a run tells the outside. This one gives no loggers, prints progress lines and nothing else; subclass it
    (``experiments.reporting.run_report.RunReport``) for the terminal's lines and TensorBoard."""

    def logger(self, stage: str):
        """The Lightning logger of ``stage``'s training (``autoencoder_level1``, ``detector_<method>``, ...), or
        None."""
        return None

    def progress(self, line: str) -> None:
        """A line on what a stage is doing or found (e.g. the speed stage's timings)."""
        print(line, flush=True)

    def round_done(self, method: str, record: dict) -> None:
        """The detector's round ``record`` (``metrics.json``'s ``rounds`` entry) of ``method`` is finished."""

    def finish(self, results: RunResults) -> None:
        """Every stage is done; called just before ``metrics.json`` is written."""


class _StageClock:
    """Runs a stage at a safe point of the sitting and records its wall time under its name (also when the sitting
    stops inside it)."""

    def __init__(self, record: SittingRecord):
        self.record = record

    def __call__(self, name: str, fn, *args, **kwargs):
        sitting.check(f"the start of stage {name}")
        t0 = time.perf_counter()
        self.record.begin(name)
        try:
            return fn(*args, **kwargs)
        finally:
            self.record.stage(name, time.perf_counter() - t0)


def run_pipeline(cfg: DictConfig, run_dir: str | Path, reporter: Reporter | None = None) -> RunResults:
    """Run the pipeline for ``cfg`` into ``run_dir`` (resuming what an earlier sitting left there) and write
    ``metrics.json``.

    Raises:
        UserInputError: a bad setting (all of them at once, before any work) or a degenerate box.
        SittingOver: the sitting's time budget (``max_minutes``) is spent; everything so far is saved.
    """
    validate_run_config(cfg)  # every settings error at once, before any work
    pin_threads(cfg.get("threads", 1))  # before any work: the numbers must not depend on the core count
    seed_everything(cfg.seed if cfg.seed is not None else None)
    reporter = reporter or Reporter()
    ctx = RunContext(cfg, run_dir)
    rd = ctx.run_dir
    sitting.start(cfg.get("max_minutes"))
    record = SittingRecord(rd.sittings)
    sitting.on_check(record.progress)
    stage = _StageClock(record)
    try:
        with contextlib.ExitStack() as pools:
            data = stage("data", steps.data, ctx)
            latent = stage("latent", steps.latent, ctx, rd, reporter.logger)
            sampling = stage("open_pool", steps.open_pool, ctx, pools)
            detector = stage("detector", steps.detector, cfg, data, sampling, rd.path,
                             reporter.logger(f"detector_{cfg.method.name}"), round_done=reporter.round_done)
            cal = stage("calibration", steps.calibration, cfg, detector.net, sampling, rd, reporter.progress)
            handling = stage("handler", steps.handler, cfg, detector.net, sampling, None if cal is None else cal.bands)
            real = stage("realistic", steps.realistic, cfg, data, sampling, detector.net, rd)
            casc = stage("cascade", steps.cascade, cfg, detector.net, sampling, cal, real)
            stage("close_pool", pools.close)
            stage("exports", steps.exports, cfg, rd, data, sampling, handling)
            summary = stage("summary", steps.summary, cfg, latent, sampling, detector)
            metrics = {**data.metrics, **{k: v for k, v in summary._asdict().items() if v is not None},
                       "handling": None if handling is None else handling.metrics,
                       "realistic": None if real is None else real.metrics, "cascade": casc}
            speed = stage("speed", steps.speed, cfg, sampling, detector.net, metrics, rd.path, reporter.progress)
    except sitting.SittingOver as over:
        record.close(stopped_at=over.where)
        raise
    finally:
        sitting.stop()
    record.close()
    if speed is not None:
        metrics["speed_accuracy"] = speed
    metrics["sittings"] = record.summary()
    metrics = {k: metrics[k] for k in METRICS_ORDER if k in metrics}
    results = RunResults(cfg, rd, data, latent, sampling, detector, cal, handling, real, casc, speed, metrics)
    reporter.finish(results)
    rd.metrics.write_text(json.dumps(metrics, indent=2))
    return results
