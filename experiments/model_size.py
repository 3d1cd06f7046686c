"""Apply the model-size rule to a size sweep: ``python -m experiments.model_size SWEEP_DIR [--recon-tol 0.1]
[--accuracy-tol 0.005] [--latent-rule tolerance|knee]``.

A size sweep is a Hydra multirun over ``dataset.latent.n_components``, ``dataset.latent.level2_dim`` and
``detector.net.width`` (``experiment=size_<dataset>``). The rule of ``model_size=auto``
(:mod:`neuralcol.stages.model_size`) picks the smallest latent space within ``recon-tol`` of the best held-out
reconstruction (``--latent-rule knee``: the knee of the held-out error against the latent size), then the
smallest detector within ``accuracy-tol`` of the best accuracy at that latent space. It writes
``SWEEP_DIR/model_size.json`` (read by ``experiments.report`` to mark the chosen point on the Pareto chart)
and prints every run's sizes and scores.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from neuralcol.errors import UserInputError
from neuralcol.stages.model_size import LATENT_RULES, choose_from_records, size_record
from neuralcol.utils.cli import report_user_errors


def sweep_records(sweep: Path) -> list[dict]:
    """Records (:func:`~neuralcol.stages.model_size.size_record`) of the finished runs under ``sweep``."""
    runs = sorted(p.parent for p in sweep.glob("*/metrics.json"))
    if not runs:
        raise UserInputError(f"{sweep}: no finished run (no <run>/metrics.json); give the sweep directory of a "
                             "size sweep (python -m experiments.run -m experiment=size_<dataset>)")
    return [size_record(json.loads((r / "metrics.json").read_text()), r.name) for r in runs]


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", type=Path)
    ap.add_argument("--recon-tol", type=float, default=0.1, help="relative tolerance on held-out mesh error")
    ap.add_argument("--accuracy-tol", type=float, default=0.005, help="absolute tolerance on test accuracy")
    ap.add_argument("--latent-rule", choices=LATENT_RULES, default="tolerance",
                    help="tolerance: smallest latent space within --recon-tol of the best held-out error; knee: the "
                         "knee of the held-out error against log2 of the latent size")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    records = sweep_records(args.sweep)
    doc = choose_from_records(records, args.recon_tol, args.accuracy_tol, args.latent_rule)
    (args.sweep / "model_size.json").write_text(json.dumps(doc, indent=2))
    print(f"{'run':>14} {'|Z_0|':>5} {'L2':>3} {'width':>5} {'held-out err':>12} {'params':>8} {'accuracy':>8} "
          f"{'majority':>8} {'skill':>6} {'FNR':>6}")
    for r in doc["detector"]:
        mark = "  <- chosen" if r["run"] == doc["chosen_run"] else ""
        err = "n/a" if r["val_error"] is None else f"{r['val_error']:.4f}"
        maj = "n/a" if r.get("majority_accuracy") is None else f"{r['majority_accuracy']:.4f}"
        skill = "n/a" if r.get("skill") is None else f"{r['skill']:.3f}"
        print(f"{r['run']:>14} {r['n_components']:>5} {r['level2_dim']:>3} {r['detector_width']:>5g} {err:>12} "
              f"{r['n_parameters']:>8} {r['accuracy']:>8.4f} {maj:>8} {skill:>6} {r['fnr']:>6.3f}{mark}")
    print("(accuracy compares only within one latent space: each has its own U(Z), test set and collision rate; "
          "skill = (accuracy - majority) / (1 - majority))")
    c = doc["chosen"]
    print(f"chosen: |Z_0| = {c['n_components']}, level 2 = {c['level2_dim']}, detector width x{c['detector_width']:g} "
          f"(accuracy {doc['chosen_accuracy']:.4f}; best at this latent space {doc['best_accuracy']:.4f} in "
          f"{doc['best_run']}) -> "
          f"{args.sweep / 'model_size.json'}")


if __name__ == "__main__":
    main()
