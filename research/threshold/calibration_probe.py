"""How a finished run's decision threshold would land if it were set on a large calibration set of realistic meshes
drawn like its realistic test set, offline (before a rule for the operating point is chosen):

    .venv/bin/python -m research.threshold.calibration_probe RUN_DIR [RUN_DIR ...] [--scale 4]
        [--cache ~/neuralcol-cache] [--data ../shared/data] [--target 0.1] [--out FILE]

Per run (its own config, latent space and final detector):

1. two realistic sets built like the run's realistic test set (``neuralcol.samples.realistic.realistic_set``: ACAP
   and vertex interpolations, perturbations of the held-out meshes; exact PD) with other seeds and ``--scale`` times
   the candidates, every clear case kept (``per_class`` unbounded): ``cal`` (seed 101) and ``eval`` (seed 202);
2. the run's detector on each (``run.detect``: code and mesh; logits relative to the run's folded threshold);
3. the threshold each way puts at FNR <= target: the run's own (its realistic validation rows: 0 here), ``cal``
   (the clear colliding meshes of the big set), and what each gives on the run's realistic test set and on
   ``eval``: FNR (with its 95 % Clopper-Pearson interval) and accuracy.

Thresholds are also given absolute (the run's recorded threshold added), to compare across seeds.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def score(logit: np.ndarray, y: np.ndarray, t: float) -> dict:
    """FNR (with its exact 95 % interval), FPR, accuracy, majority and skill of ``logit > t`` against ``y``."""
    from neuralcol.metrics.detection import proportion_interval

    pred = logit > t
    pos = y.sum()
    miss = int((~pred & y).sum())
    acc = float((pred == y).mean())
    maj = float(max(y.mean(), 1 - y.mean()))
    return {"n": int(len(y)), "n_colliding": int(pos), "fnr": miss / max(pos, 1),
            "fnr_ci95": proportion_interval(miss, int(pos)), "fpr": float((pred & ~y).sum() / max((~y).sum(), 1)),
            "accuracy": acc, "majority": maj, "skill": (acc - maj) / (1 - maj) if maj < 1 else float("nan")}


def big_set(ctx, stage, labeler, seed: int, scale: float, tag: str):
    """A realistic set drawn like the run's test set: ``scale`` x the candidates, seed ``seed``, every clear case."""
    from omegaconf import OmegaConf

    from neuralcol.samples.realistic import realistic_set

    cfg = OmegaConf.to_container(ctx.cfg.realistic, resolve=True)
    cfg.update(seed=int(seed), per_class=None, n_acap_interp=int(scale * cfg["n_acap_interp"]),
               n_vertex_interp=int(scale * cfg["n_vertex_interp"]), n_perturbed=int(scale * cfg["n_perturbed"]))
    ds, feats = ctx.dataset, ctx.features
    with ctx.pool(labeler) as pool:
        meshes, pd, _ = realistic_set(ds.vertices.numpy(), feats.features.numpy(), feats.acap,
                                      stage.report["val_index"], pool, OmegaConf.create(cfg),
                                      ctx.samples_dir(labeler), float(labeler.eps), tag=tag)
    from neuralcol.data.realistic import clear_mask

    keep = np.isfinite(pd) & clear_mask(pd, float(labeler.eps), float(cfg["clear_eps"]))
    return meshes.vertices[keep], pd[keep] > 0


def probe(run_dir: Path, cache: Path, data: Path, scale: float, target: float) -> dict:
    from omegaconf import OmegaConf

    from neuralcol.api import load_run
    from neuralcol.operating import fnr_threshold
    from neuralcol.pipeline import RunContext

    t0 = time.perf_counter()
    cfg = OmegaConf.load(run_dir / ".hydra" / "config.yaml")
    cfg.paths.cache_dir, cfg.paths.data_dir = str(cache), str(data)
    ctx = RunContext(cfg)
    stage = ctx.latent_space()
    labeler = ctx.sample_labeler()
    sets = {name: big_set(ctx, stage, labeler, seed, scale, f"opprobe_{name}")
            for name, seed in (("cal", 101), ("eval", 202))}
    run = load_run(run_dir)
    logits = {}
    for name, (v, y) in sets.items():
        logits[name] = (run.detect(v).logit.double().numpy(), y)
    with np.load(run_dir / "realistic_predictions.npz") as z:
        clear = z["clear"].astype(bool) & np.isfinite(z["pd"])
        logits["test"] = (z["logit"][clear].astype(np.float64), z["pd"][clear] > 0)
    recorded = json.loads((run_dir / "metrics.json").read_text())["detector"].get("operating_point", {})
    t_run = float(recorded.get("threshold", 0.0))
    rules = {"run": 0.0, "cal": fnr_threshold(*logits["cal"], target)}
    out = {"run": str(run_dir), "recorded": recorded, "scale": scale, "target": target,
           "sizes": {k: {"n": int(len(y)), "colliding": int(y.sum())} for k, (_, y) in logits.items()},
           "rules": {}}
    for rule, t in rules.items():
        out["rules"][rule] = {"threshold_relative": t, "threshold_absolute": t_run + t,
                              **{k: score(lg, y, t) for k, (lg, y) in logits.items()}}
    out["seconds"] = time.perf_counter() - t0
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.threshold.calibration_probe")
    ap.add_argument("run_dirs", type=Path, nargs="+")
    ap.add_argument("--cache", type=Path, default=Path(os.environ.get("NEURALCOL_CACHE", "~/neuralcol-cache")))
    ap.add_argument("--data", type=Path, help="the folder that holds the data sets",
                    default=Path(os.environ.get("NEURALCOL_DATA", ROOT.parent / "shared" / "data")))
    ap.add_argument("--scale", type=float, default=4.0, help="candidates, as a multiple of the realistic test set's")
    ap.add_argument("--target", type=float, default=0.1)
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "threshold" / "calibration_probe.json")
    a = ap.parse_args(argv)
    blocks = []
    for rd in a.run_dirs:
        b = probe(rd, a.cache.expanduser(), a.data.expanduser().resolve(), a.scale, a.target)
        blocks.append(b)
        for rule, r in b["rules"].items():
            print(f"{rd.name} | {rule} | t {r['threshold_absolute']:+.3f} (rel {r['threshold_relative']:+.3f}) | "
                  + " | ".join(f"{k}: FNR {r[k]['fnr']:.3f} [{r[k]['fnr_ci95'][0]:.3f}, {r[k]['fnr_ci95'][1]:.3f}]"
                               f" of {r[k]['n_colliding']}, acc {r[k]['accuracy']:.3f}"
                               for k in ("cal", "eval", "test")), flush=True)
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(blocks, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
