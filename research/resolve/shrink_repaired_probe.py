"""Resolve probe: shrinking the *repair's* own displacement. For a run's colliding realistic meshes A..B that the
repair alone frees, those whose largest vertex displacement exceeds ``--above`` (fraction of the diagonal) get
:func:`neuralcol.handler.resolve.shrink_corrections` with D = repaired - input (the repair tried again from
input + s D, bisection on s). Prints the p95 of the per-mesh largest displacement over all meshes freed, before and
after, and the seconds the shrink spent.

    PYTHONPATH=. python research/resolve/shrink_repaired_probe.py RUN_DIR [A:]B [--above 0.01] [--steps 5]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import neuralcol
from neuralcol.handler.resolve import shrink_corrections
from neuralcol.repair.contact import outward_sign
from neuralcol.repair.meshes import repair_meshes
from neuralcol.repair.settings import repair_from_config
from research.resolve.untangle_probe import colliding_rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir")
    ap.add_argument("rows")
    ap.add_argument("--above", type=float, default=0.01)
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--out")
    a = ap.parse_args()
    run = neuralcol.load_run(a.run_dir, workers=0)
    lab, faces = run.labeler, run.faces
    data, pick, x = colliding_rows(run, a.rows)
    settings = repair_from_config(run.cfg, enabled=True, overrides=["method=contact_untangle"])
    sign = outward_sign(faces, lab.rest)

    def repaired(meshes):
        out, _, _ = repair_meshes(meshes, faces, lab, settings, float(lab.eps), lab.diag, sign)
        return out, np.array([lab.label(o).pd for o in out])

    t = time.perf_counter()
    out, pd = repaired(x)
    secs_repair = time.perf_counter() - t
    free = pd <= 0
    top = np.linalg.norm(out - x, axis=-1).max(-1) / lab.diag
    big = np.flatnonzero(free & (top > a.above))
    t = time.perf_counter()
    kept, _, s = shrink_corrections(x[big], out[big], repaired, a.steps)
    secs = time.perf_counter() - t
    after = top.copy()
    after[big] = np.linalg.norm(kept - x[big], axis=-1).max(-1) / lab.diag
    half_pd = np.asarray(data["pd"][pick], np.float64) / 2 / lab.diag
    p95 = (100 * np.percentile(top[free], 95), 100 * np.percentile(after[free], 95))
    print(f"{a.run_dir} [{a.rows}]: repair frees {free.mean():.3f} ({secs_repair:.0f} s); {len(big)} above "
          f"{100 * a.above:.1f} %; p95 of the largest {p95[0]:.2f} -> {p95[1]:.2f} %; shrink {secs:.0f} s", flush=True)
    for j, k in enumerate(big):
        print(f"  mesh {pick[k]}: largest {100 * top[k]:.2f} -> {100 * after[k]:.2f} % (s {s[j]:.3f}; PD/2 "
              f"{100 * half_pd[k]:.2f} %)", flush=True)
    if a.out:
        with open(a.out, "w") as fh:
            json.dump({"run": a.run_dir, "rows": a.rows, "above": a.above, "free": float(free.mean()),
                       "p95_before_pct": p95[0], "p95_after_pct": p95[1], "seconds_repair": secs_repair,
                       "seconds_shrink": secs, "meshes": pick[big].tolist(), "s": s.tolist(),
                       "largest_before": top[big].tolist(), "largest_after": after[big].tolist()}, fh, indent=1)


if __name__ == "__main__":
    main()
