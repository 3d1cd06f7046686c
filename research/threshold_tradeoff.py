"""Accuracy against FNR when the detector's decision threshold moves:
``python -m research.threshold_tradeoff SWEEP TEST``.

The target is SCAPE accuracy >= 0.80 *and* FNR <= 0.25. FN outnumber FP among the detector's errors, so a
lower threshold on the collision probability lowers the FNR; this study measures what it costs in accuracy, for
every finished run of a sweep directory (``SWEEP/<n>/detector.pt`` and ``metrics.json``), on one labeled test
store (an ``.h5`` of uniform samples, e.g. the 10^5-row SCAPE test set of ``experiments.scale_curve``). It writes
``SWEEP/threshold_tradeoff.{json,md}`` (``--out`` to put them elsewhere) and prints the table.

    python -m research.threshold_tradeoff outputs/final/scape .cache/collision/<key>/test_s1000003.h5 \
        --out docs/diagnosis/threshold_tradeoff
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import h5py
import numpy as np
import torch

from neuralcol.errors import UserInputError
from neuralcol.metrics.threshold import THRESHOLDS, tradeoff
from neuralcol.nn.detector import load_detector
from neuralcol.rundir import RunDir


def probabilities(net: torch.nn.Module, z: np.ndarray, batch: int = 8192) -> np.ndarray:
    """Collision probability of each code (N, D) under ``net`` (a CollisionDetector)."""
    net.eval()
    with torch.no_grad():
        return torch.cat([net(torch.as_tensor(z[i:i + batch])).prob for i in range(0, len(z), batch)]).numpy()


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", type=Path,
                    help="sweep directory with one finished run per subdirectory, or one run directory")
    ap.add_argument("test", type=Path, help="labeled test store (.h5 with z and collides) of the runs' latent space")
    ap.add_argument("--out", type=Path, default=None, help="directory for threshold_tradeoff.{json,md}")
    args = ap.parse_args(argv)
    if not args.test.is_file():
        raise UserInputError(f"{args.test}: no such test store; give the .h5 of labeled uniform samples")
    with h5py.File(args.test, "r") as h5:
        z, collides = h5["z"][:], h5["collides"][:].astype(bool)
    if RunDir(args.sweep).detector.is_file():  # one run directory
        runs = [args.sweep]
    else:
        runs = sorted((p for p in args.sweep.iterdir() if RunDir(p).detector.is_file()), key=lambda p: p.name)
    if not runs:
        raise UserInputError(f"{args.sweep}: no finished run (no <run>/detector.pt); point it at a sweep directory")
    rows = []
    for run in runs:
        net, _ = load_detector(RunDir(run).detector)
        if net.latent_dim != z.shape[1]:
            raise UserInputError(f"{run}: detector takes {net.latent_dim}-d codes, {args.test} has {z.shape[1]}-d "
                                 "codes; give the test store of this run's latent space")
        meta = json.loads(RunDir(run).metrics.read_text())["detector"]
        rows.append({"run": run.name, "method": meta["method"],
                     "points": tradeoff(probabilities(net, z), collides)})
    out = args.out or args.sweep
    out.mkdir(parents=True, exist_ok=True)
    doc = {"test": str(args.test), "n_test": int(len(z)), "base_rate": float(collides.mean()), "runs": rows}
    (out / "threshold_tradeoff.json").write_text(json.dumps(doc, indent=1))
    head = "| run | method | " + " | ".join(f"t={t:g}: acc / FNR" for t in THRESHOLDS) + " |"
    lines = [head, "| " + " | ".join(["---"] * (len(THRESHOLDS) + 2)) + " |"]
    for r in rows:
        cells = [f"{p['accuracy']:.4f} / {p['fnr']:.3f}" for p in r["points"]]
        lines.append(f"| {r['run']} | {r['method']} | " + " | ".join(cells) + " |")
    (out / "threshold_tradeoff.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
