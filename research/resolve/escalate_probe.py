"""Resolve probe: what an escalation does for the meshes untangle leaves colliding. Untangle (defaults) on a run's
colliding realistic meshes A..B, alone (no neural step); each failure then continues from its result under each
escalation variant (more iterations, stronger settings).

    PYTHONPATH=. python research/resolve/escalate_probe.py RUN_DIR [A:]B [--json OUT]

Prints the share free after the default untangle, then per variant the share free after it, the p95 of the per-mesh
largest displacement (fraction of the diagonal, %, over all meshes A..B) and the seconds the variant spent.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

import neuralcol
from neuralcol.repair.untangle import SmoothField, UntangleSettings, untangle
from research.resolve.untangle_probe import realistic_set

VARIANTS = {
    "+160 iterations": dict(max_iter=160),
    "+160, contour_max 2, delta 0.5": dict(max_iter=160, contour_max=2.0, delta=0.5),
    "+160, share 1 (one side moves all the way)": dict(max_iter=160, share=1.0),
}


def main() -> None:
    run = neuralcol.load_run(sys.argv[1], workers=0)
    lo, _, hi = sys.argv[2].rpartition(":")
    lo, hi = int(lo or 0), int(hi)
    lab, faces = run.labeler, run.faces
    data = realistic_set(run)
    pick = np.flatnonzero(data["pd"] > 0)[lo:hi]
    meshes = data["vertices"][pick].astype(np.float64)
    base = UntangleSettings()
    field = SmoothField(faces, meshes.shape[1], base.stiffness, base.anchor)
    first, top0 = [], []
    t0 = time.perf_counter()
    for v in meshes:
        out = untangle(v, lab, base, field)
        first.append(out)
        top0.append(np.linalg.norm(out.vertices - v, axis=1).max() / lab.diag)
    secs0 = time.perf_counter() - t0
    free0 = np.array([o.resolved for o in first])
    report = {"run": sys.argv[1], "range": [lo, hi], "n": len(meshes), "free": float(free0.mean()),
              "p95_largest_pct": 100 * float(np.percentile(top0, 95)), "seconds": secs0, "variants": {}}
    print(f"{sys.argv[1]} [{lo}:{hi}] n {len(meshes)}: untangle free {free0.mean():.3f}, p95 largest "
          f"{report['p95_largest_pct']:.2f} %, {secs0:.0f} s; {int((~free0).sum())} to escalate", flush=True)
    for name, kw in VARIANTS.items():
        us = UntangleSettings(**{**base.__dict__, **kw})
        free, top, secs = free0.copy(), list(top0), 0.0
        for k in np.flatnonzero(~free0):
            t = time.perf_counter()
            out = untangle(first[k].vertices, lab, us, field)
            secs += time.perf_counter() - t
            free[k] = out.resolved and not lab.label(out.vertices).collides
            top[k] = np.linalg.norm(out.vertices - meshes[k], axis=1).max() / lab.diag
        report["variants"][name] = {"free": float(free.mean()), "p95_largest_pct": 100 * float(np.percentile(top, 95)),
                                    "seconds": secs}
        print(f"  {name}: free {free.mean():.3f}, p95 largest {100 * np.percentile(top, 95):.2f} %, {secs:.0f} s",
              flush=True)
    if "--json" in sys.argv:
        with open(sys.argv[sys.argv.index("--json") + 1], "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
