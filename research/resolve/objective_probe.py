"""Resolve probe: what the paper's other objective and larger margins do for the meshes the default ``resolve``
leaves colliding. ``run.resolve`` (defaults) on a run's colliding realistic meshes A..B; its failures are resolved
again with each variant (the Cartesian objective; the latent one with larger verification margins; both).

    PYTHONPATH=. python research/resolve/objective_probe.py RUN_DIR [A:]B [--out F.json]

Prints the share free after the default, then per variant how many failures it frees, their largest displacement
(fraction of the diagonal, %) and the seconds it spent.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import neuralcol
from research.resolve.untangle_probe import colliding_rows

VARIANTS = {
    "cartesian": dict(objective="cartesian"),
    "latent, margins to 24": dict(margins=[4.0, 6.0, 8.0, 12.0, 16.0, 24.0]),
    "cartesian, margins to 24": dict(objective="cartesian", margins=[4.0, 6.0, 8.0, 12.0, 16.0, 24.0]),
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir")
    ap.add_argument("rows")
    ap.add_argument("--out")
    a = ap.parse_args()
    run = neuralcol.load_run(a.run_dir)
    _, pick, x = colliding_rows(run, a.rows)
    t = time.perf_counter()
    res = run.resolve(x)
    free = np.nan_to_num(res.pd_after, nan=1.0) <= 0
    fail = np.flatnonzero(~free)
    report = {"run": a.run_dir, "rows": a.rows, "n": len(x), "free": float(free.mean()),
              "seconds": time.perf_counter() - t, "failures": pick[fail].tolist(), "variants": {}}
    print(f"{a.run_dir} [{a.rows}]: default frees {free.mean():.3f} ({report['seconds']:.0f} s); "
          f"{len(fail)} failures: {pick[fail].tolist()}", flush=True)
    for name, kw in VARIANTS.items():
        if not len(fail):
            break
        t = time.perf_counter()
        r = run.resolve(x[fail], **kw)
        ok = np.nan_to_num(r.pd_after, nan=1.0) <= 0
        top = r.displacement_max / r.diagonal
        secs = time.perf_counter() - t
        report["variants"][name] = {"freed": int(ok.sum()), "largest_pct": (100 * top).tolist(),
                                    "pd_after": r.pd_after.tolist(), "seconds": secs}
        print(f"  {name}: frees {int(ok.sum())}/{len(fail)}, largest of the freed "
              f"{np.round(100 * top[ok], 1).tolist()} %, {secs:.0f} s", flush=True)
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(report, fh, indent=1)


if __name__ == "__main__":
    main()
