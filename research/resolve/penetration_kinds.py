"""Resolve probe: how many of a run's colliding realistic meshes have enclosed penetrating regions (deep: a part
inside another part's volume) and how many only local folds (intersection curves that enclose nothing).

    PYTHONPATH=. python research/resolve/penetration_kinds.py RUN_DIR
"""

from __future__ import annotations

import sys

import numpy as np

import neuralcol
from research.resolve.untangle_probe import realistic_set


def main() -> None:
    run = neuralcol.load_run(sys.argv[1], workers=0)
    lab = run.labeler
    data = realistic_set(run)
    rows = []
    for k in np.flatnonzero(data["pd"] > 0):
        pen = lab.penetrations(data["vertices"][k].astype(np.float64), 0.3, seed_vectors=False)
        rows.append((int(data["kind"][k]), bool(np.abs(pen.vector).sum() > 0), data["pd"][k] / lab.diag))
    kind, deep, pd = (np.array(c) for c in zip(*rows))
    print(f"colliding {len(rows)}: with an enclosed region {deep.sum()}, local folds only {(~deep).sum()}; median PD "
          f"{100 * np.median(pd[deep]):.3f} % / {100 * np.median(pd[~deep]):.3f} % of the diagonal")
    for k in np.unique(kind):
        print(f"  kind {k}: {np.sum(kind == k)} meshes, {np.sum(deep[kind == k])} with an enclosed region")


if __name__ == "__main__":
    main()
