"""Test accuracy of FastDetector (compiled float32 and bfloat16) against the eager float32 detector, per run.

    python -m research.detector_precision RUN_DIR [RUN_DIR ...] [--out FILE] [--threads 2]

For each finished run: its cached test set (the rows ``test_predictions.npz`` was computed on; the eager logits
are checked against that file, so the rows are the right ones), accuracy and FNR of each form, their changes
against eager in points, and the share of test rows whose predicted label flips. Prints a table; ``--out``
writes JSON.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import h5py
import numpy as np
import torch

from bench.neural import FAST_KEYS
from neuralcol.rundir import RunDir


def test_rows(run) -> tuple[np.ndarray, np.ndarray]:
    """(z (N, D) float32, collides (N,) bool) of the run's cached test set."""
    cfg = run.cfg
    folder = run.context().samples_dir(run.labeler)
    path = folder / f"test_s{int(cfg.detector.test_seed)}.h5"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: the run's test set is not in the cache; run the run's command again")
    n = int(cfg.detector.test_size)
    with h5py.File(path, "r") as f:
        return np.asarray(f["z"][:n], np.float32), np.asarray(f["collides"][:n], bool)


def evaluate(run_dir: Path) -> dict:
    from neuralcol import load_run
    from neuralcol.metrics.detection import detection_metrics
    from neuralcol.nn.fast_inference import FastDetector

    run = load_run(run_dir)
    net = run.detector.eval()
    z, collides = test_rows(run)
    run.close()  # its label pool (opened for the labeler): the detector is all that is needed below
    stored = np.load(RunDir(run_dir).test_predictions)
    zt = torch.as_tensor(z)
    row: dict = {"run": str(run_dir), "n": len(z)}
    preds = {}
    for name, form in {"eager": None, **FAST_KEYS}.items():
        with torch.no_grad():
            logit = (net(zt).logit if form is None else FastDetector.from_form(net, form)(zt).logit).numpy()
        if name == "eager":
            err = float(np.abs(logit - stored["logit"]).max())
            if err > 1e-4 or not np.array_equal(collides, stored["collides"]):
                raise RuntimeError(f"{run_dir}: the cached test rows do not reproduce test_predictions.npz "
                                   f"(largest logit difference {err:.2e})")
        preds[name] = logit > 0
        m = detection_metrics(preds[name], collides)
        row[f"{name}_accuracy"], row[f"{name}_fnr"] = m["accuracy"], m["fnr"]
        if name != "eager":
            row[f"{name}_accuracy_change_points"] = 100 * (m["accuracy"] - row["eager_accuracy"])
            row[f"{name}_fnr_change_points"] = 100 * (m["fnr"] - row["eager_fnr"])
            row[f"{name}_label_flips"] = float(np.mean(preds[name] != preds["eager"]))
    return row


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path, nargs="+", help="finished run directories")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    rows = [evaluate(r) for r in args.runs]
    forms = list(FAST_KEYS)
    print("| run | eager accuracy / FNR | " + " | ".join(f"{k}: Δacc, ΔFNR (points), flips" for k in forms) + " |")
    print("|---|---:|" + "---:|" * len(forms))
    for r in rows:
        cells = [f"{r[f'{k}_accuracy_change_points']:+.3f}, {r[f'{k}_fnr_change_points']:+.3f}, "
                 f"{100 * r[f'{k}_label_flips']:.3f} %" for k in forms]
        print(f"| {r['run']} | {r['eager_accuracy']:.4f} / {r['eager_fnr']:.4f} | " + " | ".join(cells) + " |")
    worst = {k: max(abs(r[k]) for r in rows) for k in rows[0] if k.endswith("change_points")}
    print("largest |change| over the runs (points): " + ", ".join(f"{k} {v:.3f}" for k, v in worst.items()))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"rows": rows, "largest_abs_change_points": worst}, indent=1))


if __name__ == "__main__":
    main()
