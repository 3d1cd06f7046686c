"""Gradient-boosted trees on a finished run's own D_c rows, against the run's detector, on its U(Z) test set:
``python -m research.gbt_reference RUN_DIR [--cache-dir DIR] [--out FILE]``.

The reference the guide asks for beside every detector: ``sklearn``'s ``HistGradientBoostingClassifier`` (defaults,
nothing tuned, ``random_state=0``) fit on the rows the run trained on (``dc.h5``: codes, and for a detector over code
and mesh the same pair features it read), twice: on the codes alone and on codes + pair features. Scored on the run's
U(Z) test set (its codes' pair features computed as the detector computes them on codes) next to the run's own test
predictions (``test_predictions.npz``): accuracy at the trees' 0.5 and at the detector's logit 0, FNR, AUC. Where the
trees on the same inputs score like the network, the inputs (the features, the labels' budget) limit it, not the
network or its training.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import h5py
import numpy as np
import torch
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.metrics import roc_auc_score

from neuralcol.api.run import load_run
from neuralcol.nn.part_geometry import geometry_of_codes
from research.speed_rerun import find_test_set


def scores(y: np.ndarray, p: np.ndarray, threshold: float) -> dict:
    pred = p > threshold
    return {"accuracy": float(np.mean(pred == y)), "fnr": float(np.mean(~pred[y])) if y.any() else None,
            "auc": float(roc_auc_score(y, p))}


def training_rows(f: h5py.File, n: int, chunk: int = 50_000) -> np.ndarray:
    """The first ``n`` rows of a ``dc.h5``'s codes, and its pair features where it has them, side by side as one
    float64 array filled in chunks. The trees take float64: before, np.hstack of the float32 parts and sklearn's own
    float64 copy of it sat beside the parts (a peak near 19 GB for 4.5e5 rows x 1452 pair features); now sklearn
    takes this array as it is. The values are the same (float32 to float64 is exact), so are the trees."""
    dz = f["z"].shape[1]
    dg = int(np.prod(f["geometry"].shape[1:])) if "geometry" in f else 0
    x = np.empty((n, dz + dg), np.float64)
    for i in range(0, n, chunk):
        j = min(i + chunk, n)
        x[i:j, :dz] = f["z"][i:j]
        if dg:
            x[i:j, dz:] = f["geometry"][i:j].reshape(j - i, dg)
    return x


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.gbt_reference", description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--cache-dir", type=Path, default=Path("~/neuralcol-cache").expanduser())
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    metrics = json.loads((a.run_dir / "metrics.json").read_text())
    with h5py.File(a.run_dir / "dc.h5", "r") as f:
        n = int(f.attrs.get("committed", len(f["z"])))
        y = f["collides"][:n].astype(bool)
        x = training_rows(f, n)
    from omegaconf import OmegaConf

    cfg = OmegaConf.load(a.run_dir / ".hydra" / "config.yaml")
    test_path = find_test_set(a.cache_dir, metrics["autoencoder"]["cache_key"], int(cfg.detector.test_seed))
    with h5py.File(test_path, "r") as f:
        zt, yt = f["z"][:], f["collides"][:].astype(bool)
    dz = zt.shape[1]
    preds = np.load(a.run_dir / "test_predictions.npz")
    out = {"run": str(a.run_dir), "n_rows": n, "n_test": len(zt), "base_rate_test": float(yt.mean()),
           "detector": scores(yt, preds["logit"], 0.0)}
    inputs = {"codes": (np.ascontiguousarray(x[:, :dz]), zt.astype(np.float64))}
    if x.shape[1] > dz:
        run = load_run(a.run_dir)
        xt = np.empty((len(zt), x.shape[1]), np.float64)
        xt[:, :dz] = zt
        with torch.no_grad():
            for i in range(0, len(zt), 1024):
                xt[i:i + 1024, dz:] = geometry_of_codes(run.detector.geometry, run.space, torch.as_tensor(
                    zt[i:i + 1024])).float().reshape(-1, x.shape[1] - dz).numpy()
        inputs["codes + pair features"] = (x, xt)
    for name, (x, xt) in inputs.items():
        gbt = HistGradientBoostingClassifier(random_state=0).fit(x, y)
        out[f"gbt on {name}"] = scores(yt, gbt.predict_proba(xt)[:, 1], 0.5)
        print(name, out[f"gbt on {name}"], flush=True)
    print(json.dumps(out, indent=1))
    if a.out:
        a.out.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
