"""What the benchmarks run on: the SCAPE config and data set, the repetition count, notes, and a finished run.

The data set is read where the config says (``paths.data_dir``, i.e. ``NEURALCOL_DATA``, conf/paths/default.yaml);
finished runs are looked for under ``paths.output_dir``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

from omegaconf import DictConfig

from neuralcol.rundir import RunDir

if TYPE_CHECKING:
    from neuralcol.pipeline import RunContext

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
# the SCAPE config of every benchmark (the autoencoder settings matter to `training` only): the paper's bilevel
# autoencoder, which `training` times (SCAPE's own default is a PCA latent space)
SCAPE_OVERRIDES = ("dataset=scape", "autoencoder=cpu", "autoencoder.progress_bar=false",
                   "autoencoder.val_every=1000000")


def compose_config(overrides: Sequence[str], config_name: str = "config") -> DictConfig:
    """``conf/<config_name>.yaml`` composed with ``overrides`` (as on the command line of ``experiments.run``)."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name=config_name, overrides=list(overrides))


def scape_config(extra: Sequence[str] = ()) -> DictConfig:
    """The benchmarks' SCAPE config, with ``extra`` overrides."""
    return compose_config([*SCAPE_OVERRIDES, *extra])


@dataclass
class BenchContext:
    """Shared by the benchmarks of one ``python -m bench.run``: the config, the SCAPE data set (loaded once),
    the repetition count, notes per benchmark (written to results.json / results.md) and a trained run."""

    cfg: DictConfig
    quick: bool = False
    run_dir: Path | None = None
    notes: dict = field(default_factory=dict)

    @property
    def reps(self) -> int:
        return 3 if self.quick else 7

    @cached_property
    def pipeline(self) -> RunContext:
        """The run context of ``cfg`` (data set, features)."""
        from neuralcol.pipeline import RunContext

        return RunContext(self.cfg)

    @property
    def scape(self):
        """The 71 SCAPE meshes."""
        return self.pipeline.dataset

    @property
    def data_dir(self) -> Path:
        return Path(str(self.cfg.paths.data_dir)).resolve()

    def trained_run(self) -> Path:
        """A finished SCAPE run to take the detector and latent space from: ``--run-dir``, else the newest one
        under ``paths.output_dir``, else a small one built now into ``bench/tmp/run`` (tiny autoencoder and data,
        but the CPU preset's detector size, so per-sample costs are representative; iteration counts less so)."""
        if self.run_dir:
            return Path(self.run_dir)
        runs = [RunDir(p.parent) for p in Path(str(self.cfg.paths.output_dir)).resolve().glob("**/detector.pt")]
        runs = [r for r in runs if r.metrics.is_file() and r.config.is_file()
                and json.loads(r.metrics.read_text()).get("dataset", {}).get("name") == "scape"]
        if runs:
            return max(runs, key=lambda r: r.detector.stat().st_mtime).path
        run_dir = RunDir(HERE / "tmp" / "run")
        if not run_dir.detector.is_file():
            print("[bench] no finished SCAPE run under outputs/: building a small one in bench/tmp/run", flush=True)
            subprocess.run([sys.executable, "-m", "experiments.run", "dataset=scape", "autoencoder=tiny",
                            "detector=tiny", "detector.net.state_dim=64", "detector.net.hidden=128",
                            "handler.n_inputs=0", f"paths.data_dir={self.data_dir}", f"hydra.run.dir={run_dir.path}"],
                           cwd=ROOT, check=True)
        return run_dir.path


def where(run_dir: Path) -> Path:
    """``run_dir`` relative to the repository when inside it (for the notes)."""
    return run_dir.relative_to(ROOT) if run_dir.is_relative_to(ROOT) else run_dir
