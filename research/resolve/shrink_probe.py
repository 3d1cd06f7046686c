"""Resolve probe: how far can the neural handler's correction shrink? For a run's colliding realistic meshes that
the repair alone does not free, ``run.resolve`` gives a result R; the correction D = R - input is scaled by s and
the repair (the run's ``handler.repair``) tried from input + s D; bisection finds the smallest s in [0, 1] from
which the repair frees the mesh. Prints the largest displacement (fraction of the diagonal) of R and of the shrunk
result, per mesh and summarised.

    PYTHONPATH=. python research/resolve/shrink_probe.py RUN_DIR [A:]B [--steps 5] [--out F.json]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

import neuralcol
from neuralcol.repair.contact import outward_sign
from neuralcol.repair.meshes import repair_meshes
from neuralcol.repair.settings import repair_from_config
from research.resolve.untangle_probe import colliding_rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir")
    ap.add_argument("rows")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--out")
    a = ap.parse_args()
    run = neuralcol.load_run(a.run_dir, workers=0)
    lab, faces = run.labeler, run.faces
    _, pick, x = colliding_rows(run, a.rows)
    settings = repair_from_config(run.cfg, enabled=True)
    sign = outward_sign(faces, lab.rest)

    def repaired(meshes):
        out, ok, _ = repair_meshes(meshes, faces, lab, settings, float(lab.eps), lab.diag, sign)
        return out, np.array([ok[k] and not lab.label(out[k]).collides for k in range(len(out))])

    _, free0 = repaired(x)
    rest = np.flatnonzero(~free0)
    print(f"{a.run_dir} [{a.rows}]: {len(x)} colliding, the repair alone frees {free0.mean():.3f}; "
          f"{len(rest)} go to the neural handler", flush=True)
    res = run.resolve(x[rest])
    rows = []
    for j, k in enumerate(rest):
        r = np.asarray(res.vertices[j], np.float64)
        if not np.isfinite(r).all() or lab.label(r).collides:
            rows.append({"mesh": int(pick[k]), "resolved": False})
            continue
        d = r - x[k]
        top = float(np.linalg.norm(d, axis=1).max() / lab.diag)
        s_lo, s_hi, best = 0.0, 1.0, r
        for _ in range(a.steps):
            s = 0.5 * (s_lo + s_hi)
            out, ok = repaired((x[k] + s * d)[None])
            if ok[0]:
                s_hi, best = s, out[0]
            else:
                s_lo = s
        shrunk = float(np.linalg.norm(best - x[k], axis=1).max() / lab.diag)
        rows.append({"mesh": int(pick[k]), "resolved": True, "s": s_hi, "largest": top, "largest_shrunk": shrunk})
        print(f"  mesh {pick[k]}: largest {100 * top:.2f} % -> s {s_hi:.3f}, {100 * shrunk:.2f} %", flush=True)
    done = [r for r in rows if r["resolved"]]
    if done:
        before = 100 * np.median([r["largest"] for r in done])
        after = 100 * np.median([r["largest_shrunk"] for r in done])
        print(f"freed by the neural path {len(done)}/{len(rows)}; median largest {before:.2f} -> {after:.2f} %",
              flush=True)
    if a.out:
        with open(a.out, "w") as fh:
            json.dump({"run": a.run_dir, "rows": a.rows, "repair_alone": float(free0.mean()), "meshes": rows}, fh,
                      indent=1)


if __name__ == "__main__":
    main()
