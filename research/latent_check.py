"""The latent space of a preset without the detector: ``python -m research.latent_check OUT [overrides]``.

Trains (or loads from the cache) the run's latent space and its PCA references, fits its box (``box_fit``) and
writes what a run would report about them: train and held-out vertex error of the space and of each reference,
and every box-fit trial's colliding share. Minutes where a whole run of a large data set takes most of an hour
(anny_body: 45 min). Writes ``OUT/latent_check.json`` and prints one line per fact.

    NEURALCOL_DATA=../shared/data python -m research.latent_check docs/results/latent_check_anny_pca \\
        dataset=anny_body autoencoder=pca
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from hydra import compose, initialize_config_dir

from neuralcol.pipeline import RunContext
from neuralcol.utils.threads import pin_threads

CONF = Path(__file__).resolve().parents[1] / "conf"
ERRORS = ("train_mean_vertex_error", "val_mean_vertex_error")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="directory for latent_check.json")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of experiments.run, e.g. dataset=anny_body")
    args = ap.parse_args(argv)
    with initialize_config_dir(str(CONF), version_base="1.3"):
        cfg = compose("config", overrides=[*args.overrides, "box_fit.enabled=true"])
    pin_threads(cfg.get("threads", 1))
    t0 = time.perf_counter()
    ctx = RunContext(cfg)
    stage = ctx.latent_space()
    _, ref_errors = ctx.references
    labeler = ctx.sample_labeler()
    with ctx.pool(labeler) as pool:
        fitted = ctx.fit_box(pool, labeler)  # box_fit is on: a new space with the fitted box and its own key
    report, fit = fitted.report, fitted.report["box_fit"]
    out = {"overrides": list(args.overrides), "dataset": str(cfg.dataset.name), "kind": str(cfg.autoencoder.kind),
           "latent_dim": stage.space.dim, "cache_key": report["cache_key"],
           "space": {k: report.get(k) for k in ERRORS},
           "references": {name: {k: e.get(k) for k in ERRORS} for name, e in ref_errors.items()},
           "box_fit": fit, "seconds": time.perf_counter() - t0}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "latent_check.json").write_text(json.dumps(out, indent=2))
    print(f"{out['dataset']} {out['kind']} |Z_all|={out['latent_dim']} key {out['cache_key']}")
    for name, e in {"space": out["space"], **out["references"]}.items():
        tr, va = e.get("train_mean_vertex_error"), e.get("val_mean_vertex_error")
        print(f"  {name}: " + (f"train {tr:.3%}  held out {va:.3%}" if tr is not None and va is not None
                               else f"n/a ({ref_errors.get(name, {}).get('reason', 'no error')})"))
    print("  box fit: " + ", ".join(f"{t['factor']:g} -> {t['collision_share']:.1%}" for t in fit["trials"])
          + f"; chosen {fit['factor']:g} ({'in' if fit['in_band'] else 'outside'} the band)")


if __name__ == "__main__":
    main()
