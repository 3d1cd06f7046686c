"""How ``python -m experiments.run`` reports a run while it goes and when it ends (the pipeline's
:class:`~neuralcol.pipeline.run.Reporter`): TensorBoard loggers for the trainings, a line per round of the detector,
the progress lines, and at the end the TensorBoard scalars and pictures of the results (:mod:`.tensorboard`) and the
speed-against-accuracy chart (``speed_accuracy.png``). The printed summary is :mod:`.summary`'s."""

from __future__ import annotations

from pathlib import Path

from experiments.reporting.speed_accuracy import plot_speed_accuracy
from experiments.reporting.summary import round_line
from experiments.reporting.tensorboard import log_cascade, log_handling, log_latent, log_realistic, log_subdomains
from neuralcol.metrics.tensorboard import stage_logger
from neuralcol.pipeline import Reporter, RunResults


class RunReport(Reporter):
    """TensorBoard under ``<run_dir>/tensorboard/`` (one run per stage) and the terminal's lines of a run."""

    def __init__(self, run_dir: str | Path):
        self.run_dir = Path(run_dir)
        self.loggers: dict[str, object] = {}

    def logger(self, stage: str):
        if stage not in self.loggers:
            self.loggers[stage] = stage_logger(self.run_dir, stage)
        return self.loggers[stage]

    def round_done(self, method: str, record: dict) -> None:
        print(round_line(method, record), flush=True)

    def finish(self, results: RunResults) -> None:
        cfg, rd, m = results.cfg, results.run_dir, results.metrics
        step = results.detector.rounds[-1]["dataset_size"]  # the final |D_c|
        ds = results.data.dataset
        log_subdomains(self.run_dir, ds.vertices[cfg.dataset.reference_index].numpy().astype("float64"),
                       ds.faces.numpy(), results.latent.space.partition.numpy())
        detector_logger = self.logger(f"detector_{cfg.method.name}")
        if results.realistic is not None:
            log_realistic(detector_logger, results.realistic.metrics, step, rd.realistic_renders)
        if results.cascade is not None:
            log_cascade(detector_logger, results.cascade, step)
        if results.handling is not None:
            log_handling(self.run_dir, results.handling.metrics, step)
        detector_logger.finalize("success")
        log_latent(self.run_dir, m)
        if results.speed is not None:
            plot_speed_accuracy(results.speed["points"], rd.speed_accuracy_png,
                                f"{cfg.dataset.name}, {cfg.method.name}, seed {cfg.seed}: speed against accuracy "
                                f"(torch threads: {results.speed['threads']})")
