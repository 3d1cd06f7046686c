"""CGAL's closed-triangle rule (neuralcol check --rule cgal): analytic cases beside the paper's rule, and CGAL's own
self_intersections pair for pair where the cgal bindings are installed."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from neuralcol.collision.labeler import ExactLabeler


def pairs_both(v, f):
    lab = ExactLabeler(np.asarray(f), np.asarray(v, float), clearance=False)
    return set(map(tuple, lab.closed_rule_pairs(v).tolist())), set(map(tuple, lab.intersecting_pairs(v).tolist()))


def test_touching_counts_under_the_closed_rule_only():
    # a corner of the second triangle rests on the first one's interior
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, 0], [0.5, 0.5, 1], [1.5, 0.5, 1]], float)
    closed, paper = pairs_both(v, [[0, 1, 2], [3, 4, 5]])
    assert closed == {(0, 1)} and paper == set()
    v[3, 2] = 1e-9  # lifted off: no contact under either rule
    assert pairs_both(v, [[0, 1, 2], [3, 4, 5]]) == (set(), set())


def test_edge_neighbours_count_when_folded_flat():
    flat = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.3, 0.5, 0]], float)  # both on the same side of 0-1
    closed, paper = pairs_both(flat, [[0, 1, 2], [1, 0, 3]])
    assert closed == {(0, 1)} and paper == set()
    hinge = flat.copy()
    hinge[3] = [0.3, 0.5, 0.2]  # at an angle: they share the edge only
    assert pairs_both(hinge, [[0, 1, 2], [1, 0, 3]])[0] == set()
    opposite = flat.copy()
    opposite[3] = [0.3, -0.5, 0.0]  # coplanar, on the other side: a flat sheet
    assert pairs_both(opposite, [[0, 1, 2], [1, 0, 3]])[0] == set()


def test_one_vertex_neighbours_and_duplicates_and_degenerate_faces():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0.5], [0, -1, 0.5], [2, 0, 0]], float)
    assert pairs_both(v, [[0, 1, 2], [0, 3, 4]])[0] == set(), "meeting at the shared vertex only"
    assert pairs_both(v, [[0, 1, 2], [0, 5, 4]])[0] == {(0, 1)}, "an edge along the other's edge past the vertex"
    assert pairs_both(v, [[0, 1, 2], [2, 0, 1]])[0] == {(0, 1)}, "a duplicated face"
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    assert pairs_both(line, [[0, 1, 2], [3, 4, 5]])[0] == {(0, 0)}, "a degenerate face, paired with itself"


def _cgal_pairs(v, f):
    from CGAL import CGAL_Polygon_mesh_processing as pmp
    from CGAL.CGAL_Kernel import Point_3
    from CGAL.CGAL_Polyhedron_3 import Polyhedron_3

    mesh = Polyhedron_3()
    pmp.polygon_soup_to_polygon_mesh([Point_3(*x) for x in v.tolist()], np.asarray(f).tolist(), mesh)
    assert mesh.size_of_facets() == len(f)
    for k, fh in enumerate(mesh.facets()):
        fh.set_id(k)
    out: list = []
    pmp.self_intersections(mesh, out)
    return {tuple(sorted((p.first.id(), p.second.id()))) for p in out}


@pytest.mark.parametrize("offset", [1.0, 1.5, 2.0, 2.2])
def test_closed_rule_is_cgals_pair_for_pair(offset):
    """Two boxes of a grid-aligned subdivision (faces touching exactly at offset 1.0 and 2.0: coplanar contacts) and
    two spheres: the closed rule's pairs are CGAL's."""
    pytest.importorskip("CGAL")
    box = trimesh.creation.box(extents=(1, 1, 1))
    v, f = trimesh.remesh.subdivide(box.vertices, box.faces)
    boxes = (np.concatenate([v, v + [offset, 0.25, 0.0]]), np.concatenate([f, f + len(v)]))
    s = trimesh.creation.icosphere(subdivisions=2)
    spheres = (np.concatenate([s.vertices, s.vertices + [offset, 0.0, 0.0]]),
               np.concatenate([s.faces, s.faces + len(s.vertices)]))
    for vv, ff in (boxes, spheres):
        assert pairs_both(vv, ff)[0] == _cgal_pairs(vv, ff)


def test_cli_names_the_rule(tmp_path):
    import io
    import json

    from neuralcol.cli import main

    flat = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.3, 0.5, 0]], float)
    path = tmp_path / "fold.obj"
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in flat) + "f 1 2 3\nf 2 1 4\n")
    rows = {}
    for rule in ("paper", "cgal"):
        out = io.StringIO()
        code = main(["check", str(path), "--json", "--pairs", "--rule", rule], out=out, err=io.StringIO())
        rows[rule] = (code, json.loads(out.getvalue()))
    assert rows["paper"][0] == 0 and rows["paper"][1]["rule"] == "paper" and rows["paper"][1]["pair_list"] == []
    code, row = rows["cgal"]
    assert code == 1 and row["rule"] == "cgal" and row["pair_list"] == [[0, 1]] and row["pd"] is None
