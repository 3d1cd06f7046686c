"""Paired differences between two detector variants of learning curves (`experiments.diagnose` outputs).

    python -m experiments.compare_curves BASE_DIR:VARIANT OTHER_DIR:VARIANT [--json OUT]

Each ``DIR`` holds a ``diagnosis.json`` written by ``python -m experiments.diagnose diagnose.parts=[curve]``
(``diagnose.out=DIR``); ``VARIANT`` names one of its ``diagnose.curve.variants``. The records of the two
variants are paired by (size, training seed), which the curve trains on the same rows of the same pool, and the
differences OTHER - BASE of test accuracy and FNR are printed per pair and as means (in points), with the
epochs each run trained: what the registered tests of docs/studies/training_schedule.md were decided on.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from neuralcol.errors import UserInputError
from neuralcol.utils.cli import report_user_errors


def curve_records(spec: str) -> tuple[str, dict]:
    """``DIR:VARIANT`` -> (variant, {(size, seed): record}) from ``DIR/diagnosis.json``."""
    if ":" not in spec:
        raise UserInputError(f"{spec!r}: expected DIR:VARIANT, e.g. outputs/lr_scape:constant")
    folder, variant = spec.rsplit(":", 1)
    path = Path(folder) / "diagnosis.json"
    if not path.exists():
        raise UserInputError(f"{path}: no such file; write it with `python -m experiments.diagnose "
                             f"diagnose.parts=[curve] diagnose.out={folder}`")
    curve = json.loads(path.read_text()).get("curve")
    if not curve:
        raise UserInputError(f"{path}: holds no learning curve (run the diagnosis with diagnose.parts=[curve])")
    recs = {(r["size"], r["seed"]): r for r in curve["records"] if r["model"] == variant}
    if not recs:
        names = sorted({r["model"] for r in curve["records"]})
        raise UserInputError(f"{path}: no variant {variant!r}; it has {names}")
    return variant, recs


def paired_differences(base: dict, other: dict) -> dict:
    """Per (size, seed) pair present in both: accuracy and FNR of each and their differences; and the means."""
    keys = sorted(set(base) & set(other))
    if not keys:
        raise UserInputError("the two variants share no (size, seed) pair")
    pairs = []
    for k in keys:
        b, o = base[k]["test"], other[k]["test"]
        pairs.append({"size": k[0], "seed": k[1], "base_accuracy": b["accuracy"], "accuracy": o["accuracy"],
                      "d_accuracy": o["accuracy"] - b["accuracy"], "base_fnr": b["fnr"], "fnr": o["fnr"],
                      "d_fnr": o["fnr"] - b["fnr"], "base_epochs": base[k].get("epochs_run"),
                      "epochs": other[k].get("epochs_run")})
    return {"pairs": pairs, "mean_d_accuracy": float(np.mean([p["d_accuracy"] for p in pairs])),
            "mean_d_fnr": float(np.mean([p["d_fnr"] for p in pairs]))}


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base", help="DIR:VARIANT of the reference")
    ap.add_argument("other", help="DIR:VARIANT compared with it")
    ap.add_argument("--json", type=Path, help="also write the pairs and means here")
    args = ap.parse_args(argv)
    (bname, base), (oname, other) = curve_records(args.base), curve_records(args.other)
    res = paired_differences(base, other)
    print(f"{oname} - {bname} (test accuracy and FNR in points):")
    print("  size    seed  accuracy                     FNR")
    for p in res["pairs"]:
        print(f"  {p['size']:>6}  {p['seed']:>4}  {p['base_accuracy']:.4f} -> {p['accuracy']:.4f} "
              f"({100 * p['d_accuracy']:+.2f})   {p['base_fnr']:.3f} -> {p['fnr']:.3f} ({100 * p['d_fnr']:+.2f})")
    print(f"  mean: accuracy {100 * res['mean_d_accuracy']:+.2f} points, FNR {100 * res['mean_d_fnr']:+.2f} points")
    if args.json:
        args.json.write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
