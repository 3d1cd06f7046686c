"""``neuralcol.check`` against CGAL's exact-predicate self-intersection test on held-out meshes of several topologies.

    .venv/bin/python -m research.anymesh.check_agreement [SETS...]

SETS default to ~/neuralcol-cache/collision/*/realistic_*.npz.

Every mesh of each cached realistic set (meshes nobody trained on; the faces found by vertex count, as in
``research/exact_labels/label_sets.py``) is judged by ``neuralcol.check`` and by CGAL's
``Polygon_mesh_processing.does_self_intersect`` (``pip install cgal``; its kernel has exact predicates). CGAL's rule is
ours for triangles sharing no vertex or one vertex; for two triangles sharing an edge it also reports a coplanar
overlap (a flat fold over the edge), which ours never counts, so a disagreement there is counted apart.
Prints per set: meshes, colliding by each, disagreements.
"""

from __future__ import annotations

import glob
import sys
import time
from pathlib import Path

import numpy as np


def agreement(vertices: np.ndarray, faces: np.ndarray) -> dict:
    """Verdicts of ``neuralcol.check`` and CGAL on meshes (N, V, 3) with faces (F, 3), and where they differ."""
    from CGAL import CGAL_Polygon_mesh_processing as pmp

    import neuralcol
    from bench.labeler_contenders import cgal_meshes

    ours = neuralcol.check(vertices, faces).collides
    theirs = np.array([bool(pmp.does_self_intersect(m)) for m in cgal_meshes(vertices, faces)])
    return {"n": len(ours), "ours": int(ours.sum()), "cgal": int(theirs.sum()),
            "differ": np.flatnonzero(ours != theirs).tolist()}


def main(files: list[str]) -> int:
    from research.exact_labels.label_sets import faces_of

    differ = 0
    for f in files:
        z = np.load(f)
        if "vertices" not in z.files:
            continue  # (a set's label file, no meshes)
        v = z["vertices"]
        t0 = time.perf_counter()
        a = agreement(v, faces_of(v.shape[1]))
        differ += len(a["differ"])
        print(f"{Path(f).parent.name}/{Path(f).stem}: V={v.shape[1]}, {a['n']} meshes; colliding: ours {a['ours']}, "
              f"CGAL {a['cgal']}; verdicts differ: {len(a['differ'])} {a['differ'][:10]} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
    return int(differ > 0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:] or sorted(glob.glob(str(Path.home() / "neuralcol-cache/collision/*/realistic_*.npz")))))
