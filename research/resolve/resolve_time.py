"""``TrainedRun.resolve`` (what a user calls) on a run's colliding realistic meshes, per repair method,
side by side: share freed (exact label), median / p95-largest displacement, seconds per mesh.

    PYTHONPATH=. python research/resolve/resolve_time.py RUN_DIR [A:]B [--methods contact untangle] [--out F.json]
        [--set handler.repair.shrink_steps=5 ...]   (config keys set on the loaded run first)
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import yaml
from omegaconf import OmegaConf

import neuralcol
from research.resolve.untangle_probe import realistic_set


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir")
    ap.add_argument("rows")
    ap.add_argument("--methods", nargs="+", default=["contact", "untangle"])
    ap.add_argument("--out")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    a = ap.parse_args()
    lo, _, hi = a.rows.rpartition(":")
    run = neuralcol.load_run(a.run_dir)
    for kv in a.set:
        key, _, value = kv.partition("=")
        OmegaConf.update(run.cfg, key, yaml.safe_load(value), force_add=True)
    data = realistic_set(run)
    pick = np.flatnonzero(data["pd"] > 0)[int(lo or 0):int(hi)]
    meshes = data["vertices"][pick]
    run.resolve(meshes[:1])  # warm up (pool, compiled kernels)
    report = {"run": a.run_dir, "rows": a.rows, "n": len(meshes), "set": a.set}
    for method in a.methods:
        OmegaConf.update(run.cfg, "handler.repair.method", method)
        t = time.perf_counter()
        res = run.resolve(meshes)
        secs = (time.perf_counter() - t) / len(meshes)
        med = res.displacement_median / res.diagonal
        top = res.displacement_max / res.diagonal
        free = np.nan_to_num(res.pd_after, nan=1.0) <= 0
        report[method] = {"free": float(free.mean()), "median_displacement_frac": float(np.median(med)),
                          "p95_largest_frac": float(np.percentile(top, 95)), "seconds_per_mesh": secs,
                          "repaired": float(res.repaired.mean())}
        print(f"{method}: n {len(meshes)}, free {free.mean():.3f}, median displacement {100 * np.median(med):.4f} %, "
              f"p95 of the largest {100 * np.percentile(top, 95):.2f} %, {secs:.2f} s per mesh", flush=True)
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(report, fh, indent=1)


if __name__ == "__main__":
    main()
