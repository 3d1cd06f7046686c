"""Probe: do per-sub-domain contact summaries over *all* close vertex pairs carry more than the run's fixed pairs?

Trees (HistGradientBoosting, defaults) on realistic meshes only: trained on the run's realistic training meshes,
the threshold set at FNR <= 0.10 on the realistic calibration set, scored on the realistic test set's clear meshes.
Feature sets: the code; the code with the run's fixed pair features (what the detector reads); the code with
per-sub-domain summaries of every close pair of the mesh (:mod:`neuralcol.geometry.contact_summary`, radius 0.02
of the diagonal), with and without the signed offset; the summaries alone; and all of them. The run's own
detector on the same test set beside.

    python -m research.detector_transfer.contact_probe RUN_DIR [--rows realistic|dc] [--out OUT.json]
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
    ap.add_argument("--rows", choices=("realistic", "dc"), default="realistic",
                    help="train on the realistic training meshes only, or on every row of the run's D_c (its "
                         "decoded codes and its realistic training meshes); dc also scores U(Z)'s test set")
    a = ap.parse_args(argv)
    run = load_run(a.run_dir)
    space, geo = run.space, run.detector.geometry
    preds = np.load(Path(a.run_dir) / "realistic_predictions.npz")
    n_test = len(preds["logit"])
    folder = None
    for d in sorted(glob.glob(f"{a.cache}/collision/*/")):  # the latent space's samples folder: its test set's size
        for f in glob.glob(d + "realistic_[0-9a-f]*.npz"):
            with np.load(f) as z:
                if len(z["pd"]) == n_test and np.array_equal(z["pd"], preds["pd"]) \
                        and glob.glob(d + "realistic_train_*.npz"):
                    folder = Path(d)
    if folder is None:
        raise SystemExit(f"no realistic test set matching {a.run_dir}'s predictions under {a.cache}/collision: run it "
                         "with that cache (--cache)")

    def load(pattern: str, n: int | None = None):
        """The set of ``pattern`` in the folder (the one of ``n`` meshes where several are)."""
        found = []
        for f in glob.glob(str(folder / pattern)):
            if "full" in f:
                continue
            with np.load(f) as z:
                if n is None or len(z["pd"]) == n:
                    found.append((z["vertices"].astype(np.float64), z["pd"].astype(np.float64)))
        assert len(found) == 1, f"{len(found)} sets {pattern} of {n} meshes in {folder}"
        return found[0]

    test_v = test_pd = None
    for f in glob.glob(str(folder / "realistic_[0-9a-f]*.npz")):  # the test set whose labels match the predictions
        with np.load(f) as z:
            if len(z["pd"]) == n_test and np.array_equal(z["pd"], preds["pd"]):
                test_v, test_pd = z["vertices"].astype(np.float64), z["pd"].astype(np.float64)
    clear = preds["clear"]
    n_rows = run.metrics["detector"].get("n_realistic_rows")
    sets = {"train": load("realistic_train_[0-9a-f]*.npz", n_rows), "calibration": load("realistic_calibration_*.npz"),
            "test": (test_v[clear], test_pd[clear])}
    rest = space.rest_vertices.detach().cpu().numpy().astype(np.float64)
    faces = space.faces.detach().cpu().numpy()
    partition = space.partition.detach().cpu().numpy()
    diag = float(np.linalg.norm(rest.max(0) - rest.min(0)))
    summary = ContactSummary(rest, faces, partition, space.n_parts, 0.02 * diag)
    feats = {}
    if a.rows == "dc":  # the run's D_c and the U(Z) test set: codes, decoded (the realistic rows: their meshes)
        import h5py

        with h5py.File(Path(a.run_dir) / "dc.h5", "r") as f:
            keep = f["origin"][:] != 2
            dc_z, dc_y = f["z"][:][keep], f["pd"][:][keep] > 0
        with h5py.File(folder / f"test_s{run.metrics['detector']['test_set']['seed']}.h5", "r") as f:
            uz_z, uz_y = f["z"][:], f["pd"][:] > 0
        for name, (z, y) in {"dc": (dc_z, dc_y), "uz": (uz_z, uz_y)}.items():
            parts = {"code": [], "pairs": [], "parts": []}
            t0 = time.perf_counter()
            for b in np.array_split(np.arange(len(z)), max(1, len(z) // 512)):
                with torch.no_grad():
                    v = space.decode(torch.as_tensor(z[b])).double()
                    parts["pairs"].append(geo.pair_features(v.float()).numpy().reshape(len(b), -1))
                parts["code"].append(z[b])
                parts["parts"].append(summary.summarize(v.numpy()).reshape(len(b), -1))
            feats[name] = {k: np.concatenate(x) for k, x in parts.items()}
            feats[name]["parts3"] = feats[name]["parts"].reshape(len(z), space.n_parts, -1)[:, :, :3].reshape(
                len(z), -1)
            feats[name]["y"] = y
            print(f"{name}: {len(z)} codes, {int(y.sum())} colliding; decoded and summarized in "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)
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
    train = ["train", "dc"] if a.rows == "dc" else ["train"]
    for name, keys in variants.items():
        x = {s: np.concatenate([feats[s][k] for k in keys], 1) for s in feats}
        clf = HistGradientBoostingClassifier(random_state=0).fit(np.concatenate([x[s] for s in train]),
                                                                 np.concatenate([feats[s]["y"] for s in train]))
        lg = {s: clf.decision_function(x[s]) for s in ("calibration", "test", "uz") if s in x}
        t = fnr_threshold(lg["calibration"], feats["calibration"]["y"], 0.1)
        results[name] = score(lg["test"], feats["test"]["y"], t)
        line = f"{name}: accuracy {results[name]['accuracy']:.4f}, FNR {results[name]['fnr']:.4f}"
        if "uz" in lg:
            results[name]["uz_at_0"] = score(lg["uz"], feats["uz"]["y"], 0.0)
            line += (f"; U(Z) at 0: accuracy {results[name]['uz_at_0']['accuracy']:.4f}, FNR "
                     f"{results[name]['uz_at_0']['fnr']:.4f}")
        print(line, flush=True)
    y = preds["pd"][clear] > 0
    results["the run's detector"] = score(preds["logit"][clear], y, 0.0)
    own = results["the run's detector"]
    print(f"the run's detector: accuracy {own['accuracy']:.4f}, FNR {own['fnr']:.4f}")
    if a.out:
        Path(a.out).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
