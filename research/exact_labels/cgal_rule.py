"""The closed rule (``ExactLabeler.closed_rule_pairs``, ``neuralcol check --rule cgal``) against CGAL's
``self_intersections`` on every public test mesh CGAL reads, pair for pair.

    .venv/bin/pip install cgal
    .venv/bin/python -m bench.public_meshes fetch SOURCE...       # the corpus, into bench/data/public
    .venv/bin/python -m research.exact_labels.cgal_rule [--max-faces 150000]

Each file is read as ``neuralcol check`` reads it (polygons fan-triangulated, STL corners merged), given to CGAL as
the same triangle soup (``polygon_soup_to_polygon_mesh``; a file CGAL cannot make one mesh of, or one it changes, is
skipped), and the two pair sets are compared. Prints one line per file that differs and the counts.
"""

from __future__ import annotations

import argparse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def cgal_pairs(v, f) -> set | None:
    from CGAL import CGAL_Polygon_mesh_processing as pmp
    from CGAL.CGAL_Kernel import Point_3
    from CGAL.CGAL_Polyhedron_3 import Polyhedron_3

    mesh = Polyhedron_3()
    pmp.polygon_soup_to_polygon_mesh([Point_3(*x) for x in v.tolist()], f.tolist(), mesh)
    if mesh.size_of_facets() != len(f) or mesh.size_of_vertices() != len(v):
        return None
    for k, fh in enumerate(mesh.facets()):
        fh.set_id(k)
    out: list = []
    pmp.self_intersections(mesh, out)
    return {tuple(sorted((p.first.id(), p.second.id()))) for p in out}


def main(argv: list[str] | None = None) -> None:
    from neuralcol.collision.labeler import ExactLabeler
    from neuralcol.geometry.source_mesh import SOURCE_SUFFIXES, read_source

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-faces", type=int, default=150_000)
    args = ap.parse_args(argv)
    root = ROOT / "bench" / "data" / "public"
    agree = differ = skipped = 0
    for path in sorted(p for p in root.rglob("*") if p.suffix.lower() in SOURCE_SUFFIXES):
        try:
            m = read_source(path)
        except Exception:
            continue  # refused: bench.public_meshes says why
        theirs = cgal_pairs(m.vertices, m.faces) if len(m.faces) <= args.max_faces else None
        if theirs is None:
            skipped += 1
            continue
        lab = ExactLabeler(m.faces, m.vertices, clearance=False)
        ours = set(map(tuple, lab.closed_rule_pairs(m.vertices).tolist()))
        if ours == theirs:
            agree += 1
        else:
            differ += 1
            print(f"{path.relative_to(root)}: ours {len(ours)}, CGAL {len(theirs)}; only ours "
                  f"{sorted(ours - theirs)[:5]}, only CGAL's {sorted(theirs - ours)[:5]}")
    print(f"{agree} files the same pair for pair, {differ} differ, {skipped} skipped (over --max-faces, or a soup "
          "CGAL does not make one mesh of)")


if __name__ == "__main__":
    main()
