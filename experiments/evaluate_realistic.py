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
from neuralcol.handler.contact_repair import repair_from_config
from neuralcol.handler.resolve import alm_settings
from neuralcol.rundir import RunDir
from neuralcol.stages.realistic import evaluate_realistic, realistic_set

ROOT = Path(__file__).resolve().parents[1]


def realistic_config(cfg, overrides: list[str]):
    """The run's ``realistic`` settings (or the default group's for older runs) with ``key=value`` overrides."""
    base = OmegaConf.select(cfg, "realistic")
    if base is None:
        base = OmegaConf.create(yaml.safe_load((ROOT / "conf" / "realistic" / "default.yaml").read_text()))
    return OmegaConf.merge(base, OmegaConf.from_dotlist(list(overrides)))


def mesh_detector_config(cfg, overrides: list[str]):
    """The run's ``mesh_detector`` settings (or the default group's for older runs) with overrides."""
    base = OmegaConf.select(cfg, "mesh_detector")
    if base is None:
        base = OmegaConf.create(yaml.safe_load((ROOT / "conf" / "mesh_detector" / "default.yaml").read_text()))
    return OmegaConf.merge(base, OmegaConf.from_dotlist(list(overrides)))


def repair_config(cfg, overrides: list[str]):
    """The run's ``handler.repair`` settings (off for runs older than it) with overrides, as
    :class:`~neuralcol.handler.contact_repair.RepairSettings` (None when disabled)."""
    return repair_from_config(cfg, overrides=overrides)


def run_realistic_set(run, rcfg):
    """A loaded run's data set, ACAP features, label pool, samples cache folder and realistic set (built and
    labeled once, then read from the cache): ``(ds, feats, pool, folder, meshes, pd)``."""
    ctx = run.context()
    ds, feats = ctx.dataset, ctx.features
    pool = run.label_pool()
    folder = ctx.samples_dir(run.labeler)
    meshes, pd, _ = realistic_set(ds.vertices.numpy(), feats.features.numpy(), feats.acap,
                                  run.space.meta["val_index"], pool, rcfg, folder, float(run.labeler.eps))
    return ds, feats, pool, folder, meshes, pd


def evaluate_run(run_dir: Path, overrides: list[str], workers: int | None, train_mesh: bool = False,
                 mesh_overrides=(), repair_overrides=()) -> dict:
    with load_run(run_dir, workers=workers, progress=False) as run:
        cfg = run.cfg
        rcfg = realistic_config(cfg, overrides)
        ds, feats, pool, folder, meshes, pd = run_realistic_set(run, rcfg)
        mesh_net, mesh_report = None, None
        if not train_mesh and RunDir(run_dir).mesh_detector.is_file():
            from neuralcol.nn.mesh_detector import load_mesh_detector

            mesh_net = load_mesh_detector(RunDir(run_dir).mesh_detector)
        if train_mesh:  # train the mesh-reading detector on this run's D_c (as experiments.run does)
            from neuralcol.samples.cache import shared_test_set
            from neuralcol.stages.mesh_detector import mesh_detector_stage

            test, _, _ = shared_test_set(run.context().oracle(pool), cfg.detector,
                                         run.metrics["autoencoder"]["cache_key"], cfg.paths.cache_dir)
            mesh_net, mesh_report = mesh_detector_stage(
                run.space, ds.vertices.numpy(), feats.features.numpy(), feats.acap, run.space.meta["train_index"],
                pool, mesh_detector_config(cfg, list(mesh_overrides)), folder, float(run.labeler.eps),
                RunDir(run_dir).dc, int(cfg.seed), run_dir, test=test)
        metrics, _ = evaluate_realistic(run.space, run.detector, meshes, pd, pool, float(run.labeler.eps), rcfg,
                                        alm_settings(cfg.handler.alm), list(cfg.handler.verify_margins),
                                        int(cfg.handler.batch_size), mesh_net=mesh_net,
                                        repair=repair_config(cfg, list(repair_overrides)))
        if mesh_report is not None:
            metrics["mesh_detector"] = mesh_report
    return metrics


def run_metrics_line(run_dir: Path) -> str:
    r = json.loads(RunDir(run_dir).metrics.read_text())["rounds"][-1]
    return f"accuracy {r['accuracy']:.4f} FNR {r['fnr']:.4f}"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.evaluate_realistic",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+", help="finished run directories")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a realistic.* setting (repeatable)")
    parser.add_argument("--out", default="realistic.json", help="file written into each run directory")
    parser.add_argument("--workers", type=int, default=None, help="label workers (default: the run's)")
    parser.add_argument("--train-mesh-detector", action="store_true",
                        help="train the mesh-reading detector on the run's D_c first (writes mesh_detector.pt)")
    parser.add_argument("--mesh-set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a mesh_detector.* setting (repeatable)")
    parser.add_argument("--repair-set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a handler.repair.* setting (repeatable), e.g. enabled=true")
    args = parser.parse_args(argv)
    for run_dir in args.runs:
        m = evaluate_run(run_dir, args.set, args.workers, args.train_mesh_detector, args.mesh_set, args.repair_set)
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
        if "detection_mesh" in m:
            dm, t = m["detection_mesh"], (m.get("mesh_detector") or {}).get("test", {})
            print(f"  mesh detector: realistic accuracy {dm['accuracy']:.4f} FNR {dm['fnr']:.4f} "
                  f"skill {dm['skill']:.3f}"
                  f"; U(Z) accuracy {t.get('accuracy', float('nan')):.4f} FNR {t.get('fnr', float('nan')):.4f} "
                  f"(latent detector U(Z): {run_metrics_line(run_dir)})", flush=True)


if __name__ == "__main__":
    main()
