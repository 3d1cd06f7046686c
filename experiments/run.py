"""Main entry point: ``python -m experiments.run [hydra overrides]``.

Runs the pipeline (:mod:`neuralcol.pipeline`) on the configured data set (default: the procedural hand): load and
validate the meshes, compute ACAP features, check the ACAP round trip, label the meshes exactly (self-intersection and
PD), train (or load from the cache) the latent space and fit its box, train the neural collision detector with the
configured method (``method=supv|supv_bd|active``) round by round, evaluate the handler, the realistic set and the
certified cascade, export example meshes, and write ``metrics.json`` into the Hydra run directory; then print the
summary (:mod:`experiments.reporting.summary`). TensorBoard: ``<run dir>/tensorboard/``
(:mod:`experiments.reporting.run_report`). Re-running the same command (or with the same ``hydra.run.dir``) resumes an
interrupted run after its last finished round (``resume=false`` starts afresh; ``neuralcol/utils/resume.py``,
``docs/reliability.md``). The model-size search is its own command: ``python -m experiments.model_size search``.
"""

from __future__ import annotations

import logging
import sys
import warnings
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from experiments.reporting.run_report import RunReport
from experiments.reporting.summary import print_summary
from neuralcol.errors import UserInputError
from neuralcol.pipeline import run_pipeline
from neuralcol.pipeline.validate import SEARCH_COMMAND
from neuralcol.resources import conf_dir
from neuralcol.utils import sitting
from neuralcol.utils.cli import report_user_errors
from neuralcol.utils.resume import RunDirLock, run_to_resume


def run(cfg: DictConfig, run_dir: Path) -> dict:
    """Run the pipeline for ``cfg`` into ``run_dir``, reported as the command reports it (a line per round,
    TensorBoard, the speed chart); returns ``metrics.json``'s content."""
    return run_pipeline(cfg, run_dir, RunReport(run_dir)).metrics


def refuse_size_search(cfg: DictConfig, task_overrides) -> None:
    """``model_size=auto`` is not a run's setting: say which command searches the sizes, with this run's overrides."""
    if cfg.get("model_size") is not None and cfg.model_size.get("mode") == "auto":
        rest = " ".join(o for o in task_overrides if o != "model_size=auto")
        raise UserInputError(f"model_size=auto: the size search is a command of its own; run {SEARCH_COMMAND} "
                             f"{rest} (it writes a preset of the chosen sizes), then this command with "
                             "model_size=<that preset> (docs/model_size.md)")


@hydra.main(version_base="1.3", config_path=str(conf_dir()), config_name="config")
@report_user_errors
def main(cfg: DictConfig) -> None:
    # keep the terminal readable: Lightning's hardware banner and tips, a third-party deprecation warning
    logging.getLogger("lightning.pytorch.utilities.rank_zero").setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*")
    hc = HydraConfig.get()
    refuse_size_search(cfg, hc.overrides.task)
    run_dir = Path(hc.runtime.output_dir)
    earlier = run_to_resume(run_dir, hc.overrides.hydra, bool(cfg.resume), multirun=hc.mode == RunMode.MULTIRUN)
    if earlier is not None:
        print(f"resuming the interrupted run in {earlier} (same overrides, unfinished); resume=false starts afresh",
              flush=True)
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
