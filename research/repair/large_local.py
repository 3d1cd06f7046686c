"""A local collision on a large mesh: nefertiti.obj (100 k faces, from ``python -m bench.public_meshes fetch``) with
the patch within 6 % of the diagonal around its highest vertex pushed 3 % of the diagonal against its normals, resolved
by the exact repairs with whole-mesh checks and with checks that follow the moved region
(``neuralcol.collision.labeler.INCREMENTAL_FACES``): seconds, freed, largest move.

    .venv/bin/python -m research.repair.large_local
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def main() -> None:
    import trimesh

    import neuralcol.collision.labeler as labeler
    from neuralcol.api.anymesh import labeler_for
    from neuralcol.geometry.source_mesh import read_source
    from neuralcol.repair import repair

    m = read_source(ROOT / "bench" / "data" / "public" / "common-3d-test-models" / "data" / "nefertiti.obj")
    v0, f = m.vertices, m.faces
    diag = float(np.linalg.norm(np.ptp(v0, 0)))
    normals = trimesh.Trimesh(v0, f, process=False).vertex_normals
    centre = v0[np.argmax(v0[:, 1])]
    near = np.linalg.norm(v0 - centre, axis=1) < 0.06 * diag
    v = v0.copy()
    v[near] -= 0.03 * diag * normals[near]
    default = labeler.INCREMENTAL_FACES
    for name, limit in (("whole checks", 10**12), ("checks following the moved region", default)):
        labeler.INCREMENTAL_FACES = limit
        lab = labeler_for(f, v0, clearance=False)
        t = time.perf_counter()
        r = repair(v[None], f, lab, rest=v0)
        print(f"{name}: {time.perf_counter() - t:.1f} s, input pairs {len(lab.intersecting_pairs(v))}, freed "
              f"{bool(r.pd_after[0] <= 0)}, largest move {100 * r.largest_move[0] / diag:.3f} % of the diagonal")
    labeler.INCREMENTAL_FACES = default


if __name__ == "__main__":
    main()
