"""Label cached mesh sets (the realistic sets' ``vertices`` in ``<cache>/collision/*/realistic_*.npz``) with the
labeler of a given checkout, to compare the verdicts of two versions of the code on the same meshes:

    git worktree add /tmp/before b2549cd     # the labeler before exact verdicts (touch_tol 1e-6 there)
    SETS=~/neuralcol-cache/collision/*/realistic_*.npz
    .venv/bin/python research/exact_labels/label_sets.py /tmp/before before.npz $SETS
    .venv/bin/python research/exact_labels/label_sets.py . after.npz $SETS
    .venv/bin/python research/exact_labels/label_sets.py --compare before.npz after.npz

Faces come from the cached generated data sets or SCAPE, by vertex count. Each set is labeled against its first
mesh as the rest mesh (the verdict does not depend on it, up to the old tolerance's mean edge length). Prints per
set: meshes, colliding before/after, verdicts that differ.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np


def faces_of(n_vertices: int) -> np.ndarray:
    """The faces of the data set with this vertex count: a cached generated data set
    (``$NEURALCOL_CACHE/datasets/*.npz``, default ``~/neuralcol-cache``) or SCAPE (``../shared/data/scape``)."""
    import os

    from neuralcol.geometry.mesh_io import read_mesh

    cache = Path(os.environ.get("NEURALCOL_CACHE", Path.home() / "neuralcol-cache")) / "datasets"
    for f in sorted(cache.glob("*.npz")):
        z = np.load(f)
        if z["vertices"].shape[1] == n_vertices:
            return z["faces"]
    v, faces = read_mesh(Path(__file__).resolve().parents[3] / "shared/data/scape/1.obj")
    if len(v) == n_vertices:
        return faces
    raise SystemExit(f"no data set with {n_vertices} vertices in {cache} or SCAPE")


def label_sets(root: str, out: str, files: list[str]) -> None:
    sys.path.insert(0, str(Path(root).resolve()))
    from neuralcol.collision.labeler import ExactLabeler  # the checkout's own

    result = {}
    for f in files:
        z = np.load(f)
        v = z["vertices"] if "vertices" in z.files else None
        if v is None:
            continue
        faces = faces_of(v.shape[1])
        lab = ExactLabeler(faces, v[0])
        t0 = time.perf_counter()
        labels = lab.label_batch(v)
        key = f"{Path(f).parent.name}/{Path(f).stem}"
        result[key + ":collides"] = labels.collides
        result[key + ":pd"] = labels.pd
        print(f"{key}: {len(v)} meshes, {labels.collides.sum()} collide, {time.perf_counter() - t0:.1f} s", flush=True)
    np.savez(out, **result)


def compare(before: str, after: str) -> None:
    a, b = np.load(before), np.load(after)
    for key in sorted(k for k in a.files if k.endswith(":collides")):
        ca, cb = a[key], b[key]
        pa, pb = a[key.replace(":collides", ":pd")], b[key.replace(":collides", ":pd")]
        free = ~ca & ~cb
        print(f"{key[:-9]}: {len(ca)} meshes; colliding {ca.sum()} -> {cb.sum()}; "
              f"verdicts differ {int((ca != cb).sum())}; "
              f"free PDs equal {int((pa[free] == pb[free]).sum())}/{int(free.sum())}; colliding PDs max |diff| "
              f"{np.abs(pa[ca & cb] - pb[ca & cb]).max(initial=0):.3g}")


if __name__ == "__main__":
    if sys.argv[1] == "--compare":
        compare(sys.argv[2], sys.argv[3])
    else:
        label_sets(sys.argv[1], sys.argv[2], sys.argv[3:])
