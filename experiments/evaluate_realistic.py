"""Evaluate finished runs on the realistic set: ``python -m experiments.evaluate_realistic RUN_DIR [RUN_DIR ...]``.

The same evaluation every ``experiments.run`` now ends with (``neuralcol/stages/realistic.py``): meshes nobody
trained on (the autoencoder's held-out meshes, ACAP and vertex interpolations between data set meshes, perturbed
held-out meshes), labeled exactly; the run's detector on them, the autoencoder's round trip, and
``resolve`` on the colliding ones. For runs made before the stage existed, or with other realistic settings
(``--set key=value``, e.g. ``--set handler_inputs=0``). Writes ``realistic.json`` into each run directory
(``--out NAME`` another name) and prints one line per run.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import yaml
from omegaconf import OmegaConf

from neuralcol.api import load_run
from neuralcol.handler.resolve import alm_settings
from neuralcol.repair.settings import repair_from_config
from neuralcol.resources import conf_dir
from neuralcol.samples.realistic import evaluation_limit, realistic_set
from neuralcol.stages.realistic import evaluate_realistic


def realistic_config(cfg, overrides: list[str]):
    """The run's ``realistic`` settings (or the default group's for older runs) with ``key=value`` overrides."""
    base = OmegaConf.select(cfg, "realistic")
    if base is None:
        base = OmegaConf.create(yaml.safe_load((conf_dir() / "realistic" / "default.yaml").read_text()))
    return OmegaConf.merge(base, OmegaConf.from_dotlist(list(overrides)))


def repair_config(cfg, overrides: list[str]):
    """The run's ``handler.repair`` settings (off for runs older than it) with overrides, as
    :class:`~neuralcol.repair.settings.RepairSettings` (None when disabled)."""
    return repair_from_config(cfg, overrides=overrides)


def run_realistic_set(run, rcfg):
    """A loaded run's data set, ACAP features, label pool, samples cache folder and realistic set (built and
    labeled once, then read from the cache): ``(ds, feats, pool, folder, meshes, pd)``."""
    ctx = run.context()
    ds, feats = ctx.dataset, ctx.features
    pool = run.label_pool()
    folder = ctx.samples_dir(run.labeler)
    meshes, pd, _ = realistic_set(ds.vertices.numpy(), feats.features.numpy(), feats.acap,
                                  run.space.meta["val_index"], pool, rcfg, folder, float(run.labeler.eps),
                                  clearance_limit=evaluation_limit(rcfg, float(run.labeler.eps)))
    return ds, feats, pool, folder, meshes, pd


def evaluate_run(run_dir: Path, overrides: list[str], workers: int | None, repair_overrides=()) -> dict:
    with load_run(run_dir, workers=workers, progress=False) as run:
        cfg = run.cfg
        rcfg = realistic_config(cfg, overrides)
        _, _, pool, _, meshes, pd = run_realistic_set(run, rcfg)
        metrics, _ = evaluate_realistic(run.space, run.on_codes, meshes, pd, pool, float(run.labeler.eps), rcfg,
                                        alm_settings(cfg.handler.alm), list(cfg.handler.verify_margins),
                                        int(cfg.handler.batch_size), repair=repair_config(cfg, list(repair_overrides)))
    return metrics


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.evaluate_realistic",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+", help="finished run directories")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a realistic.* setting (repeatable)")
    parser.add_argument("--out", default="realistic.json", help="file written into each run directory")
    parser.add_argument("--workers", type=int, default=None, help="label workers (default: the run's)")
    parser.add_argument("--repair-set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a handler.repair.* setting (repeatable), e.g. enabled=true")
    args = parser.parse_args(argv)
    for run_dir in args.runs:
        m = evaluate_run(run_dir, args.set, args.workers, args.repair_set)
        (run_dir / args.out).write_text(json.dumps(m, indent=2))
        d, rt, h = m["detection"], m["round_trip"], m.get("handling") or {}
        print(f"{run_dir}: clear {m['n_clear']}/{m['n']} (collide {m['base_rate_clear']:.3f}); accuracy "
              f"{d.get('accuracy', float('nan')):.4f} FNR {d.get('fnr', float('nan')):.4f} skill "
              f"{d.get('skill', float('nan')):.3f}; round trip agreement {rt['agreement']:.3f}, out of box "
              f"{rt['out_of_box']:.3f}"
              + (f"; resolve {h['detector_only']['resolved_rate']:.3f} / {h['verified']['resolved_rate']:.3f}, "
                 f"median displacement {h['displacement_median_frac']:.4f}" if h else "")
              + (f" (margins only {h['verified_margins_only']['resolved_rate']:.3f}; contact repair alone "
                 f"{h['repair_only']['resolved_rate']:.3f}, median displacement "
                 f"{h['repair_only']['displacement_median_frac']:.4f})" if h.get("repair_only") else ""), flush=True)


if __name__ == "__main__":
    main()
