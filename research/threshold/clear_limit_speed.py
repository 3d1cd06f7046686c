"""Time of an exact label with clearances measured in full against labels limited to the clear-case clearance
(``realistic.label_clearance: clear``), side by side on the same realistic candidates, per class.

    .venv/bin/python -m research.threshold.clear_limit_speed --dataset scape --n 150
    .venv/bin/python -m research.threshold.clear_limit_speed --dataset anny_body --n 12

Candidates: the realistic set's ACAP interpolations of the data set (neuralcol.data.realistic, seed 0), labeled in
full once to sort them into clear colliding and clear free meshes; then each class is labeled both ways, one mesh
after the other in this process (one core), and the selection each way is compared.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from neuralcol.collision.labeler import ExactLabeler
from neuralcol.data.realistic import clear_mask, make_realistic_meshes
from neuralcol.geometry.acap import ACAP

CLEAR_EPS, BOUNDARY_EPS = 10.0, 1e-4  # conf/realistic/default.yaml, conf/labeling/cpu.yaml


def load(name: str):
    if name == "scape":
        from neuralcol.data.datasets import load_mesh_dataset

        ds = load_mesh_dataset("../shared/data/scape")
    else:
        from pathlib import Path

        from neuralcol.data.datasets import load_procedural_dataset

        ds = load_procedural_dataset(name, 150, 0, cache_dir=Path.home() / "neuralcol-cache" / "datasets")
    return ds.vertices.numpy().astype(np.float64), ds.faces.numpy()


def main() -> None:
    ap = argparse.ArgumentParser(prog="python -m research.threshold.clear_limit_speed")
    ap.add_argument("--dataset", default="scape", help="scape or a procedural data set (anny_body, proc_hand, ...)")
    ap.add_argument("--n", type=int, default=150, help="meshes timed per class")
    args = ap.parse_args()
    verts, faces = load(args.dataset)
    lab = ExactLabeler(faces, verts[0], boundary_eps=BOUNDARY_EPS)
    limit = CLEAR_EPS * lab.eps
    acap = ACAP(verts[0], faces)
    feats = acap.encode(torch.as_tensor(verts)).numpy()
    cand = make_realistic_meshes(verts, feats, acap, [], 12 * args.n, 0, 0, (-0.6, 1.6), 0.8, 0).vertices
    pd = np.full(len(cand), np.nan)
    found = {"colliding": [], "free": []}
    for i, v in enumerate(cand):  # label in full until both classes have n clear meshes
        pd[i] = lab.label(v).pd
        if clear_mask(pd[i:i + 1], lab.eps, CLEAR_EPS)[0]:
            found["colliding" if pd[i] > 0 else "free"].append(i)
        if min(len(x) for x in found.values()) >= args.n:
            break
    for name, idx in found.items():
        idx = idx[:args.n]
        t = time.perf_counter()
        full = np.array([lab.label(cand[i]).pd for i in idx])
        t_full = time.perf_counter() - t
        t = time.perf_counter()
        lim = np.array([lab.label_limited(cand[i], limit).pd for i in idx])
        t_lim = time.perf_counter() - t
        same = np.array_equal(clear_mask(full, lab.eps, CLEAR_EPS), clear_mask(lim, lab.eps, CLEAR_EPS)) \
            and np.array_equal(full > 0, lim > 0)
        print(f"{args.dataset} {name} ({len(idx)} meshes): full {t_full / len(idx) * 1e3:.1f} ms, limited "
              f"{t_lim / len(idx) * 1e3:.1f} ms per mesh, ratio {t_lim / t_full:.2f}; same selection and verdicts: "
              f"{same}")


if __name__ == "__main__":
    main()
