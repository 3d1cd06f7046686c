"""A probe: IPC barrier paths (``ipctk``) as a repair, from a free start towards the colliding input.

    .venv/bin/pip install ipctk==1.6.1
    .venv/bin/python -m research.repair.barrier_probe --dataset scape --start deflated --first 2
    .venv/bin/python -m research.repair.barrier_probe --dataset scape --start repaired --first 5

Both minimise ``1/2 (x - input)^T Q (x - input) + kappa B(x)`` over the vertices ``x`` with Newton steps (the barrier's
Hessian projected to PSD), each step cut by ipctk's continuous collision detection so that ``x`` stays free from a free
start: ``Q = I + stiffness (D - A)`` (the membrane of :mod:`neuralcol.repair.untangle`), ``B`` ipctk's barrier with
activation distance ``dhat`` mean edge lengths. The start:

* ``deflated``: the input smoothed, ``(I + t (D - A))^-1 x``, with the smallest ``t`` of a geometric ladder at which
  the exact labeler calls it free (a free reference made from the input itself, for meshes with no rest pose); the
  path grows the mesh back towards the input and stops each part where it touches;
* ``repaired``: what ``neuralcol.repair.repair`` returned (free), tightened towards the input (less move).

The draw is :mod:`research.repair.hard_cases`'s (``deflated`` runs on the meshes its ``repairs`` left colliding,
``repaired`` on the first meshes it freed). Prints per mesh: free, iterations, seconds, largest and median move.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from bench.repair import barrier_path
from research.repair.hard_cases import draw_path, out_path

LADDER = np.geomspace(0.5, 2000, 24)  # smoothing times tried, in order


def deflated(x: np.ndarray, faces: np.ndarray, labeler, ladder=LADDER):
    """The input smoothed by the first ``t`` of ``ladder`` at which it is free, and that ``t`` (None, None: never)."""
    from neuralcol.repair.untangle import edge_laplacian

    lap = edge_laplacian(faces, len(x))
    for t in ladder:
        y = spla.spsolve((sp.eye(len(x)) + t * lap).tocsc(), x)
        if not labeler.verdict(y):
            return y, float(t)
    return None, None


def main(argv: list[str] | None = None) -> None:
    from neuralcol.api.anymesh import labeler_for

    ap = argparse.ArgumentParser(prog="python -m research.repair.barrier_probe", description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", default="scape")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--start", choices=("deflated", "repaired"), default="deflated")
    ap.add_argument("--first", type=int, default=2, help="meshes tried")
    ap.add_argument("--max-iter", type=int, default=300)
    ap.add_argument("--cache", type=Path, default=Path.home() / "neuralcol-cache")
    args = ap.parse_args(argv)
    z = np.load(draw_path(args.cache, args.dataset, args.seed))
    faces, rest = z["faces"], z["rest"]
    lab = labeler_for(faces, rest)
    per = json.loads(out_path(args.dataset, args.seed, "repairs").read_text())["per_mesh"]
    rows = [m["row"] for m in per if m["freed"] != (args.start == "deflated")][:args.first]
    if args.start == "repaired":
        kept = np.load(args.cache / "repair_draws" / "outputs" / f"{args.dataset}_s{args.seed}_repairs.npz")
        returned = dict(zip(kept["rows"].tolist(), kept["vertices"]))
    for k in rows:
        x = z["meshes"][k].astype(np.float64)
        t0 = time.perf_counter()
        start, t = deflated(x, faces, lab) if args.start == "deflated" else (returned[k], None)
        if start is None:
            print(f"row {k}: no smoothing of the ladder is free")
            continue
        y, its = barrier_path(start, x, faces, float(lab.ell), max_iter=args.max_iter)
        move = np.linalg.norm(y - x, axis=1) / float(lab.diag)
        before = np.linalg.norm(start - x, axis=1).max() / float(lab.diag)
        print(f"row {k}: free {not lab.verdict(y)}, {its} iterations, {time.perf_counter() - t0:.1f} s, largest move "
              f"{100 * move.max():.2f} % (start {100 * before:.2f} %), median {100 * np.median(move):.3f} %"
              f"{'' if t is None else f', smoothing t={t:.3g}'}; input PD {100 * z['pd'][k] / lab.diag:.2f} %",
              flush=True)


if __name__ == "__main__":
    main()
