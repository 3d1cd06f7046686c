"""Probe: do per-sub-domain contact summaries over *all* close vertex pairs carry more than the run's fixed pairs?

Trees (HistGradientBoosting, defaults) on realistic meshes only: trained on the run's realistic training meshes,
the threshold set at FNR <= 0.10 on the realistic calibration set, scored on the realistic test set's clear meshes.
Feature sets: the code; the code with the run's fixed pair features (what the detector reads); the code with
per-sub-domain summaries of every close pair of the mesh (:mod:`neuralcol.geometry.contact_summary`, radius 0.02
of the diagonal), with and without the signed offset; the summaries alone; and all of them. The run's own
detector on the same test set beside.

    python -m research.detector_transfer.contact_probe RUN_DIR [--out OUT.json]
"""

from __future__ import annotations

import argparse
import glob
import json
import time
from pathlib import Path

import numpy as np
import torch

from neuralcol.geometry.contact_summary import ContactSummary
from neuralcol.operating import fnr_threshold, score


def main(argv: list[str] | None = None) -> None:
    from sklearn.ensemble import HistGradientBoostingClassifier

    from neuralcol.api.run import load_run

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir")
    ap.add_argument("--cache", default=str(Path.home() / "neuralcol-cache"))
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    run = load_run(a.run_dir)
    space, geo = run.space, run.detector.geometry
    key = run.metrics["latent"]["cache_key"] if "cache_key" in run.metrics.get("latent", {}) else None
    preds = np.load(Path(a.run_dir) / "realistic_predictions.npz")
    n_test = len(preds["logit"])
    folder = None
    for d in sorted(glob.glob(f"{a.cache}/collision/*/")):  # the latent space's samples folder: its test set's size
        for f in glob.glob(d + "realistic_[0-9a-f]*.npz"):
            with np.load(f) as z:
                if len(z["pd"]) == n_test and np.array_equal(z["pd"], preds["pd"]) \
                        and glob.glob(d + "realistic_train_*.npz"):
                    folder = Path(d)
    assert folder is not None, f"no realistic set of {n_test} meshes in {a.cache}/collision (key {key})"

    def load(pattern: str):
        (f,) = [f for f in glob.glob(str(folder / pattern)) if "full" not in f]
        with np.load(f) as z:
            return z["vertices"].astype(np.float64), z["pd"].astype(np.float64)

    test_v, test_pd = load("realistic_[0-9a-f]*.npz") if len(glob.glob(str(folder / "realistic_[0-9a-f]*.npz"))) == 1 \
        else (None, None)
    if test_v is None:  # several test sets in the folder: the one whose labels match the predictions
        for f in glob.glob(str(folder / "realistic_[0-9a-f]*.npz")):
            with np.load(f) as z:
                if len(z["pd"]) == n_test and np.allclose(z["pd"], preds["pd"]):
                    test_v, test_pd = z["vertices"].astype(np.float64), z["pd"].astype(np.float64)
    clear = preds["clear"]
    sets = {"train": load("realistic_train_[0-9a-f]*.npz"), "calibration": load("realistic_calibration_*.npz"),
            "test": (test_v[clear], test_pd[clear])}
    rest = space.rest_vertices.detach().cpu().numpy().astype(np.float64)
    faces = space.faces.detach().cpu().numpy()
    partition = space.partition.detach().cpu().numpy()
    diag = float(np.linalg.norm(rest.max(0) - rest.min(0)))
    summary = ContactSummary(rest, faces, partition, space.n_parts, 0.02 * diag)
    feats = {}
    for name, (v, pd) in sets.items():
        with torch.no_grad():
            z = torch.cat([space.encode(torch.as_tensor(b)) for b in np.array_split(v, max(1, len(v) // 512))])
            pair = torch.cat([geo.pair_features(torch.as_tensor(b, dtype=torch.float32))
                              for b in np.array_split(v, max(1, len(v) // 512))])
        t0 = time.perf_counter()
        summ = summary.summarize(v)
        ms = 1e3 * (time.perf_counter() - t0) / len(v)
        feats[name] = {"code": z.numpy().reshape(len(v), -1), "pairs": pair.numpy().reshape(len(v), -1),
                       "parts": summ.reshape(len(v), -1), "parts3": summ[:, :, :3].reshape(len(v), -1),
                       "y": pd > 0}
        print(f"{name}: {len(v)} meshes, {int((pd > 0).sum())} colliding; summaries {ms:.1f} ms/mesh", flush=True)
    variants = {"code": ["code"], "code + fixed pairs": ["code", "pairs"],
                "code + part summaries without the offset": ["code", "parts3"],
                "code + part summaries": ["code", "parts"], "part summaries": ["parts"],
                "code + fixed pairs + part summaries": ["code", "pairs", "parts"]}
    results = {}
    for name, keys in variants.items():
        x = {s: np.concatenate([feats[s][k] for k in keys], 1) for s in feats}
        clf = HistGradientBoostingClassifier(random_state=0).fit(x["train"], feats["train"]["y"])
        lg = {s: clf.decision_function(x[s]) for s in ("calibration", "test")}
        t = fnr_threshold(lg["calibration"], feats["calibration"]["y"], 0.1)
        results[name] = score(lg["test"], feats["test"]["y"], t)
        print(f"{name}: accuracy {results[name]['accuracy']:.4f}, FNR {results[name]['fnr']:.4f}", flush=True)
    y = preds["pd"][clear] > 0
    results["the run's detector"] = score(preds["logit"][clear], y, 0.0)
    own = results["the run's detector"]
    print(f"the run's detector: accuracy {own['accuracy']:.4f}, FNR {own['fnr']:.4f}")
    if a.out:
        Path(a.out).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
