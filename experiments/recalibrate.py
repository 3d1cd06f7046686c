"""Set a finished run's (or a package's) operating point again, on a realistic calibration set drawn with today's
settings, and see what it gives on the realistic test set:

    python -m experiments.recalibrate RUN_DIR [realistic.KEY=VALUE ...] [--target 0.1] [--write] [--fresh N]
        [--handler N] [--cache DIR] [--data DIR] [--out FILE]

Without ``--write`` it only measures: the run's threshold and the rule's (FNR <= target on the calibration set's
clear colliding meshes), each on the calibration and the test set (FNR with its exact 95 % interval, accuracy).
``--write`` moves the run's threshold to the rule's and rewrites what depends on it (``detector.pt``,
``cascade.npz``, ``metrics.json``, a package's ``package.json``; :mod:`neuralcol.api.recalibrate`); U(Z) at the new
threshold is scored on the run's test set, or for a package on ``--fresh`` codes labeled exactly, and the handler
(whose constraint is the detector's decision) on ``--handler`` colliding ones among them. The sets are
labeled once and cached like a run's (``paths.cache_dir``: ``--cache``). docs/detector.md, "The operating point".
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from omegaconf import OmegaConf

from neuralcol.api import load_run
from neuralcol.api.recalibrate import current_realistic, measure, rule_sets, write_recalibration
from neuralcol.errors import UserInputError
from neuralcol.rundir import RunDir
from neuralcol.utils.cli import report_user_errors


def _line(name: str, block: dict) -> str:
    return f"{name:<20} logit {block['threshold']:+.3f}  " + "  ".join(
        f"{k}: FNR {block[k]['fnr']:.3f} [{block[k]['fnr_ci95'][0]:.3f}, {block[k]['fnr_ci95'][1]:.3f}] of "
        f"{block[k]['n_colliding']}, accuracy {block[k]['accuracy']:.3f}" for k in ("calibration", "test"))


def folder_for(given: Path | None, env: str, recorded: str | None, fallback: str) -> tuple[Path, str]:
    """The folder a recalibration reads, and where that choice came from: ``given`` on the command line, else the
    environment variable ``env``, else the run's ``recorded`` folder (its ``paths.*`` setting) where that folder exists,
    else ``fallback``. Reading the run's own cache spares labeling its realistic sets a second time."""
    if given is not None:
        return Path(given), "command line"
    if os.environ.get(env):
        return Path(os.environ[env]), env
    if recorded and "${" not in str(recorded) and Path(recorded).is_dir():
        return Path(recorded), "the run's own setting"
    return Path(fallback), "default"


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.recalibrate", description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path, help="a finished run directory or a package (e.g. pretrained/scape)")
    parser.add_argument("overrides", nargs="*", help="realistic.KEY=VALUE on top of today's realistic settings")
    parser.add_argument("--target", type=float, default=None,
                        help="the FNR to hold (default: the run's detector.operating_fnr)")
    parser.add_argument("--write", action="store_true", help="move the run's threshold to the rule's")
    parser.add_argument("--fresh", type=int, default=10000,
                        help="fresh U(Z) codes that score a package's new threshold (it has no test set); a run "
                             "with its own test set labels only as many as --handler needs")
    parser.add_argument("--handler", type=int, default=500,
                        help="colliding fresh codes the handler is measured on again at the new threshold (0: skip)")
    parser.add_argument("--cache", type=Path, default=None,
                        help="label cache (default: $NEURALCOL_CACHE, else the run's own paths.cache_dir where that "
                             "folder exists, else .cache)")
    parser.add_argument("--data", type=Path, default=None,
                        help="folder of the data sets (default: $NEURALCOL_DATA, else the run's own paths.data_dir "
                             "where that folder exists, else data)")
    parser.add_argument("--out", type=Path, default=None, help="also write the measurement here (JSON)")
    a = parser.parse_args(argv)
    rd = RunDir(a.run_dir)
    if not rd.metrics.is_file() or not rd.config.is_file():
        raise UserInputError(f"{a.run_dir}: not a finished run or a package (no metrics.json or .hydra/config.yaml); "
                             "give the directory of a finished `python -m experiments.run`")
    cfg = OmegaConf.load(rd.config)
    recorded = {k: OmegaConf.select(cfg, f"paths.{k}", throw_on_resolution_failure=False)
                for k in ("cache_dir", "data_dir")}
    a.cache, cache_from = folder_for(a.cache, "NEURALCOL_CACHE", recorded["cache_dir"], ".cache")
    a.data, data_from = folder_for(a.data, "NEURALCOL_DATA", recorded["data_dir"], "data")
    if not a.data.is_dir():
        raise UserInputError(f"--data {a.data}: no such folder; give the folder that holds the data sets "
                             "(or set NEURALCOL_DATA)")
    print(f"labels cached in {a.cache.resolve()} ({cache_from}); data sets from {a.data.resolve()} ({data_from})")
    os.environ["NEURALCOL_CACHE"], os.environ["NEURALCOL_DATA"] = str(a.cache.resolve()), str(a.data.resolve())
    cfg.paths.cache_dir, cfg.paths.data_dir = str(a.cache.resolve()), str(a.data.resolve())
    realistic = current_realistic(a.run_dir, a.overrides)
    sets = rule_sets(a.run_dir, cfg, realistic)
    with load_run(a.run_dir) as run:
        target = a.target if a.target is not None else OmegaConf.select(run.cfg, "detector.operating_fnr")
        if target is None:
            raise UserInputError(f"{a.run_dir}: the run has no operating point (detector.operating_fnr=null); give "
                                 "--target 0.1")
        result = measure(run, sets, float(target))
        print(_line("the run's threshold", result["current"]))
        print(_line("the rule's", result["rule"]))
        if a.out:
            a.out.write_text(json.dumps({"run": str(a.run_dir), "realistic": realistic, **result}, indent=1))
        if a.write:
            op = write_recalibration(run, result, sets, a.fresh, a.handler)
            print(f"wrote {a.run_dir}: threshold {(op['previous'] or {}).get('threshold', 0.0):+.3f} -> "
                  f"{op['threshold']:+.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
