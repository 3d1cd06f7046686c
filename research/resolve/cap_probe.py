"""Resolve probe: how much of the repair's largest moves is needed. The repair (``contact_untangle``) on a run's
colliding realistic meshes A..B; each freed mesh whose largest vertex displacement exceeds ``--above`` (fraction of the
diagonal) is pulled back towards its input with exact labels only, by bisection (6 steps) on either
``scale``: x + s d (the whole displacement scaled), or ``cap``: x + d_i min(1, c m / |d_i|) (each move clipped at c
times the largest m; :func:`neuralcol.repair.cap.cap_displacements`). Prints the p95 of the per-mesh largest
displacement over the freed meshes, before and after, and per mesh the half penetration depth for comparison.

    PYTHONPATH=. python research/resolve/cap_probe.py RUN_DIR [A:]B [--mode scale|cap] [--above 0.02]
"""

from __future__ import annotations

import argparse

import numpy as np

import neuralcol
from neuralcol.handler.resolve import shrink_corrections
from neuralcol.repair.cap import cap_displacements
from neuralcol.repair.contact import outward_sign
from neuralcol.repair.meshes import repair_meshes
from neuralcol.repair.settings import repair_from_config
from research.resolve.untangle_probe import colliding_rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir")
    ap.add_argument("rows")
    ap.add_argument("--mode", choices=("scale", "cap"), default="cap")
    ap.add_argument("--above", type=float, default=0.02)
    a = ap.parse_args()
    run = neuralcol.load_run(a.run_dir, workers=0)
    lab, faces = run.labeler, run.faces
    data, pick, x = colliding_rows(run, a.rows)
    settings = repair_from_config(run.cfg, enabled=True, overrides=["method=contact_untangle"])
    out, _, _ = repair_meshes(x, faces, lab, settings, float(lab.eps), lab.diag, outward_sign(faces, lab.rest))

    def label(meshes):
        return np.array([lab.label(m).pd for m in meshes])

    free = label(out) <= 0
    top = np.linalg.norm(out - x, axis=-1).max(-1) / lab.diag
    big = np.flatnonzero(free & (top > a.above))
    if a.mode == "cap":
        kept, _, f = cap_displacements(x[big], out[big], label, 6)
    else:  # the repair as the identity: shrink_corrections then bisects the uniform scale on labels alone
        kept, _, f = shrink_corrections(x[big], out[big], lambda m: (m, label(m)), 6)
    after = top.copy()
    after[big] = np.linalg.norm(kept - x[big], axis=-1).max(-1) / lab.diag
    for j, k in enumerate(big):
        print(f"  mesh {pick[k]}: largest {100 * top[k]:.2f} -> {100 * after[k]:.2f} % ({a.mode} {f[j]:.3f}; PD/2 "
              f"{100 * data['pd'][pick[k]] / 2 / lab.diag:.2f} %)")
    print(f"{a.run_dir} [{a.rows}] {a.mode}: the repair frees {free.mean():.3f}; {len(big)} above "
          f"{100 * a.above:.1f} %; p95 of the largest {100 * np.percentile(top[free], 95):.2f} -> "
          f"{100 * np.percentile(after[free], 95):.2f} %")


if __name__ == "__main__":
    main()
