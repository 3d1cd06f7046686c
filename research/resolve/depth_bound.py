"""A lower bound on resolve's largest displacement. To free a mesh, the two sides of its deepest
penetration must together move at least its penetration depth, so some vertex moves at least PD / 2. Prints, per
run, the colliding realistic meshes' PD / 2 as a fraction of the diagonal (median, p95, share above 3 %).

    PYTHONPATH=. python research/resolve/depth_bound.py RUN_DIR [RUN_DIR ...] [--n 100]
"""

from __future__ import annotations

import sys

import numpy as np

import neuralcol
from research.resolve.untangle_probe import realistic_set


def main() -> None:
    n = int(sys.argv[sys.argv.index("--n") + 1]) if "--n" in sys.argv else 100
    runs = [a for a in sys.argv[1:] if not a.startswith("--") and not a.isdigit()]
    print("| run | colliding meshes | PD/2, median (% diag) | PD/2, p95 (%) | share with PD/2 > 3 % |")
    print("|---|---|---|---|---|")
    for r in runs:
        run = neuralcol.load_run(r, workers=0)
        pd = realistic_set(run)["pd"]
        half = pd[pd > 0][:n] / 2 / run.labeler.diag
        print(f"| {r} | {len(half)} | {100 * np.median(half):.2f} | {100 * np.percentile(half, 95):.2f} | "
              f"{np.mean(half > 0.03):.2f} |")


if __name__ == "__main__":
    main()
