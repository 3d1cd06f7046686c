"""Resolve probe: the untangle repair (region push + intersection contour minimisation) against the plain
contact repair, on a run's colliding realistic meshes, both alone on the inputs (no neural step).

    PYTHONPATH=. python research/resolve/untangle_probe.py RUN_DIR [A:]B [key=value ...]

RUN_DIR: a finished run (its labeler and topology; its realistic set is read from the cache of its latent space
and labeler). [A:]B: the colliding meshes A (default 0) to B. key=value: UntangleSettings fields;
--untangle-only skips the contact repair. Prints, per method, the share collision-free by the exact label, the
median over meshes of the per-mesh median vertex displacement and the 95th percentile of the per-mesh largest one
(fractions of the diagonal, in %), and seconds per mesh.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

import neuralcol
from neuralcol.repair.contact import diffusion_operator, repair_contacts
from neuralcol.repair.untangle import SmoothField, UntangleSettings, untangle


def realistic_set(run) -> dict:
    folder = run.context().samples_dir(run.labeler)
    files = sorted(Path(folder).glob("realistic_[0-9a-f]*.npz"))
    if not files:
        sys.exit(f"{folder}: no realistic set (run the run's realistic stage first)")
    return dict(np.load(files[0]))


def colliding_rows(run, rows: str) -> tuple[dict, np.ndarray, np.ndarray]:
    """The run's realistic set, the indices of its colliding meshes in ``rows`` ("A:B" of the colliding ones) and
    their vertices (n, V, 3) float64."""
    lo, _, hi = rows.rpartition(":")
    data = realistic_set(run)
    pick = np.flatnonzero(data["pd"] > 0)[int(lo or 0):int(hi)]
    return data, pick, data["vertices"][pick].astype(np.float64)


def main() -> None:
    run = neuralcol.load_run(sys.argv[1], workers=0)
    lo, _, hi = sys.argv[2].rpartition(":")
    lo, hi = int(lo or 0), int(hi)
    args = [a for a in sys.argv[3:] if a != "--untangle-only"]
    ints = ("max_iter", "extra_iter", "window")
    kw = {k: int(v) if k in ints else float(v) for k, v in (a.split("=", 1) for a in args)}
    lab, faces = run.labeler, run.faces
    data = realistic_set(run)
    pick = np.flatnonzero(data["pd"] > 0)[lo:hi]
    meshes = data["vertices"][pick].astype(np.float64)
    us = UntangleSettings(**kw)
    field = SmoothField(faces, meshes.shape[1], us.stiffness, us.anchor)
    w = diffusion_operator(faces, meshes.shape[1])
    methods = {
        "contact repair": lambda v: repair_contacts(v, faces, lab, 3.0 * lab.eps, 16, 60, operator=w,
                                                    max_step=0.002 * lab.diag),
        f"untangle {kw or 'defaults'}": lambda v: untangle(v, lab, us, field),
    }
    if "--untangle-only" in sys.argv:
        methods.pop("contact repair")
    for name, fn in methods.items():
        free, med, top, secs = [], [], [], []
        for v in meshes:
            t0 = time.perf_counter()
            out = fn(v)
            secs.append(time.perf_counter() - t0)
            moved = np.linalg.norm(out.vertices - v, axis=1) / lab.diag
            free.append(not lab.label(out.vertices).collides)
            med.append(np.median(moved))
            top.append(moved.max())
        print(f"{name}: n {len(meshes)}, free {np.mean(free):.3f}, median displacement {100 * np.median(med):.4f} %, "
              f"p95 of the largest {100 * np.percentile(top, 95):.2f} %, {np.mean(secs):.2f} s per mesh", flush=True)


if __name__ == "__main__":
    main()
