"""neuralcol.repair.untangle: the labeler's penetration vectors, the intersection-contour gradient
against finite differences, and untangling analytic cases and SCAPE meshes to collision-free."""

from __future__ import annotations

import numpy as np
import pytest
from fault_labelers import two_spheres

from neuralcol.collision.labeler import ExactLabeler
from neuralcol.repair.untangle import SmoothField, UntangleSettings, contour_gradient, untangle


def _spheres(offset: float, subdivisions: int = 2):
    return two_spheres(offset, subdivisions)


def test_penetration_vectors_of_two_overlapping_spheres():
    """Two unit spheres 1.6 apart: each cap inside the other sphere is a penetrating region; its vectors point to
    the other sphere's surface, their lengths are the labeler's depths, and the depths are vertex_depths'."""
    rest, faces = _spheres(3.0)
    lab = ExactLabeler(faces, rest)
    v, _ = _spheres(1.6)
    pen = lab.penetrations(v)
    assert pen.n_pairs == lab.label(v).n_pairs > 0
    np.testing.assert_array_equal(pen.depth, lab.vertex_depths(v))
    inside = np.flatnonzero(pen.depth > 0)
    assert len(inside) > 0
    norm = np.linalg.norm(pen.vector[inside], axis=1)
    np.testing.assert_allclose(norm, pen.depth[inside], rtol=1e-12)
    n = len(v) // 2
    a, b = inside[inside < n], inside[inside >= n]  # caps of sphere A (inside B) and of B (inside A)
    assert len(a) and len(b)
    assert (pen.vector[a, 0] < 0).all() and (pen.vector[b, 0] > 0).all()  # each back towards its own side
    target = v[a] + pen.vector[a]  # on sphere B's (polyhedral) surface: about 1 from B's centre
    np.testing.assert_allclose(np.linalg.norm(target - [1.6, 0.0, 0.0], axis=1), 1.0, atol=0.05)


def test_contour_gradient_matches_finite_differences():
    rng = np.random.default_rng(0)
    v, faces = two_spheres(1.7)
    lab = ExactLabeler(faces, two_spheres(3.0)[0])
    v = v + 1e-3 * rng.standard_normal(v.shape)
    pairs = lab.intersecting_pairs(v)
    grad, length = contour_gradient(v, faces, pairs)
    assert length > 0
    moved = np.flatnonzero(np.abs(grad).sum(1) > 0)
    h = 1e-7
    for i in moved[:6]:
        for d in range(3):
            e = np.zeros_like(v)
            e[i, d] = h
            fd = (contour_gradient(v + e, faces, pairs)[1] - contour_gradient(v - e, faces, pairs)[1]) / (2 * h)
            assert fd == pytest.approx(grad[i, d], rel=1e-4, abs=1e-6)
    assert contour_gradient(v, faces, np.zeros((0, 2), np.int64))[1] == 0.0


def test_contour_of_a_pair_sharing_a_vertex():
    """Two triangles sharing vertex 0 and crossing: no edge from the shared vertex crosses, so the segment runs from
    it to the one crossing point (the length the shared vertex adds, with its finite-difference gradient)."""
    v = np.array([[0.0, 0, 0], [2, -1, 0], [2, 1, 0], [1, 0, -1], [1, 0, 1]])  # triangle 0-1-2 in z = 0, 0-3-4
    faces = np.array([[0, 1, 2], [0, 3, 4]])  # in y = 0 through it: their segment is x in [0, 1] on the x axis
    grad, length = contour_gradient(v, faces, np.array([[0, 1]]))
    assert length == pytest.approx(1.0, rel=1e-12)
    h = 1e-7
    for i in range(5):
        for d in range(3):
            e = np.zeros_like(v)
            e[i, d] = h
            fd = (contour_gradient(v + e, faces, [[0, 1]])[1] - contour_gradient(v - e, faces, [[0, 1]])[1]) / (2 * h)
            assert fd == pytest.approx(grad[i, d], abs=1e-6)
    assert np.abs(grad).sum() > 0


@pytest.mark.parametrize("offset", [1.9, 1.2])
def test_untangle_separates_overlapping_spheres(offset):
    """Shallow (0.1) and deep (0.8 of a radius) overlaps come out free; the far sides barely move."""
    rest, faces = _spheres(3.0, subdivisions=3)
    lab = ExactLabeler(faces, rest)
    v, _ = _spheres(offset, subdivisions=3)
    out = untangle(v, lab, UntangleSettings())
    assert out.resolved and not lab.label(out.vertices).collides
    moved = np.linalg.norm(out.vertices - v, axis=1)
    far = (v[:, 0] < -0.5) | (v[:, 0] > offset + 0.5)  # the sides away from the contact
    assert moved[far].max() < 0.5 * moved.max()


def _bump_through_sheet(height: float) -> tuple[np.ndarray, np.ndarray]:
    """Two open 12 x 12 grids: a flat sheet at z = 0 and, ``height`` above it, a sheet with a Gaussian bump 0.4
    high (no enclosed region: only contour minimisation can untangle it)."""
    n = 12
    x, y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n), indexing="ij")
    flat = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    quad = np.array([[i * n + j, i * n + j + n, i * n + j + 1] for i in range(n - 1) for j in range(n - 1)])
    faces = np.concatenate([quad, np.stack([quad[:, 2], quad[:, 1], quad[:, 1] + 1], 1)])
    bump = flat.copy()
    bump[:, :2] *= 0.9
    bump[:, 2] = height + 0.4 * np.exp(-3 * (flat[:, 0] ** 2 + flat[:, 1] ** 2))
    return np.concatenate([flat, bump]), np.concatenate([faces, faces + n * n])


def test_contour_step_adapts_on_open_sheets():
    """A bump pushed 0.2 through a flat sheet (open surfaces): both the fixed and the adaptive contour step free it,
    the adaptive one (x1.3 while the curves shrink) in fewer iterations."""
    rest, faces = _bump_through_sheet(1.0)
    lab = ExactLabeler(faces, rest)
    v, _ = _bump_through_sheet(-0.2)
    assert lab.label(v).collides and not lab.closed
    fixed = untangle(v, lab, UntangleSettings(contour_grow=1.0, contour_shrink=1.0, max_iter=200))
    adaptive = untangle(v, lab, UntangleSettings(max_iter=200))
    for out in (fixed, adaptive):
        assert out.resolved and not lab.label(out.vertices).collides
    assert adaptive.iterations < fixed.iterations


def test_untangle_frees_colliding_scape_interpolations(scape):
    """SCAPE poses pushed past their ends (t = 1.8): the untangled meshes are free by the exact label."""
    v = scape.vertices.numpy().astype(np.float64)
    faces = scape.faces.numpy()
    lab = ExactLabeler(faces, v[0])
    settings = UntangleSettings()
    field = SmoothField(faces, v.shape[1], settings.stiffness, settings.anchor)
    freed = tried = 0
    for a, b in ((0, 9), (3, 40), (12, 55), (20, 66)):
        mesh = v[a] + 1.8 * (v[b] - v[a])
        if not lab.label(mesh).collides:
            continue
        tried += 1
        out = untangle(mesh, lab, settings, field)
        freed += int(out.resolved and not lab.label(out.vertices).collides)
    assert tried >= 2 and freed >= tried - 1


def test_crossing_pairs_are_the_intersecting_pairs(scape):
    """Penetrations.crossing_pairs (from the crossing records, no second broadphase) equal intersecting_pairs on
    overlapping spheres, a folded open sheet and colliding SCAPE interpolations; the pass at clearance limit 0
    (its box shortcut) gives the full label's counted pairs and depths."""
    rest, faces = _spheres(3.0)
    lab = ExactLabeler(faces, rest)
    cases = [(lab, _spheres(1.6)[0]), (lab, _spheres(1.2)[0])]
    v = scape.vertices.numpy().astype(np.float64)
    slab = ExactLabeler(scape.faces.numpy(), v[0])
    cases += [(slab, v[a] + 1.8 * (v[b] - v[a])) for a, b in ((12, 55), (20, 66), (5, 30))]
    n = 16  # an open sheet rolled over a radius r and back down through itself (a mesh with boundary)
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    sheet = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    quads = np.arange(n * n).reshape(n, n)[:-1, :-1].ravel()
    sheet_faces = np.concatenate([np.stack([quads, quads + 1, quads + n], 1),
                                  np.stack([quads + 1, quads + n + 1, quads + n], 1)])
    r, u = 0.05, np.maximum(sheet[:, 0] - 0.5, 0)
    angle, back = np.minimum(u / r, np.pi), np.maximum(u - np.pi * r, 0)
    folded = sheet.copy()
    folded[:, 0] = np.where(u > 0, 0.5 + r * np.sin(angle) - back, sheet[:, 0])
    folded[:, 2] = r * (1 - np.cos(angle)) - 0.5 * back
    cases.append((ExactLabeler(sheet_faces, sheet), folded))
    colliding = 0
    for labeler, mesh in cases:
        pen = labeler.penetrations(mesh, 0.3, seed_vectors=False)
        want = np.unique(np.sort(labeler.intersecting_pairs(mesh), axis=1), axis=0).reshape(-1, 2)
        np.testing.assert_array_equal(pen.crossing_pairs, want)
        assert pen.n_pairs == labeler.label(mesh).n_pairs == len(want)
        np.testing.assert_array_equal(labeler.penetrations(mesh).depth, labeler.vertex_depths(mesh))
        colliding += pen.n_pairs > 0
    assert colliding == len(cases)


def test_edge_faces_of_a_small_mesh():
    from neuralcol.geometry.topology import edge_faces, edge_topology

    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4]])  # a fan: edges 0-2 and 0-3 inside, the rest boundary
    topo = edge_topology(faces)
    got = edge_faces(topo.face_edges, len(topo.edges))
    for e, (i, j) in enumerate(topo.edges):
        want = sorted(f for f in range(3) if i in faces[f] and j in faces[f])
        assert sorted(t for t in got[e] if t >= 0) == want
        assert (got[e] >= 0).sum() == topo.face_count[e]


def test_untangle_goes_on_only_while_the_pairs_still_fall():
    """Past max_iter, still_falling: on while the fewest pairs of the last window is below progress x the fewest
    before it, never past max_iter + extra_iter; extra_iter 0 stops at max_iter."""
    from neuralcol.repair.untangle import still_falling

    s = UntangleSettings(max_iter=4, extra_iter=6, window=2, progress=0.9)
    assert still_falling([100, 90, 80, 70, 60], s)  # last two (70, 60) below 0.9 x 80
    assert not still_falling([100, 90, 80, 79, 78], s)  # 78 > 0.9 x 80: hovering
    assert not still_falling(list(range(100, 89, -1)), s)  # 10 iterations done: extra_iter spent
    assert not still_falling([100, 90, 80, 70, 60], UntangleSettings(max_iter=4, extra_iter=0))
    assert not still_falling([5, 4], s)  # no history before the window


def test_untangle_settings_refuse_bad_values():
    with pytest.raises(ValueError, match="untangle"):
        UntangleSettings(share=0.0)
    with pytest.raises(ValueError, match="extra_iter >= 0"):
        UntangleSettings(extra_iter=-1)
    with pytest.raises(ValueError, match="contour_min <= contour_step <= contour_max"):
        UntangleSettings(contour_step=2.0)
    with pytest.raises(ValueError, match="vertices have shape"):
        untangle(np.zeros((3, 2)), None, UntangleSettings())


def _folded_strip(c):
    """A 10 x 24 grid strip (x in [-1, 1], y in [-1, 3]); with ``c``, its part beyond y = 1 folded back over the
    rest (y -> 2 - y) at height 0.8 s (s - c), s the distance from the crease: below the strip (through it) for
    s < c. None: the flat strip."""
    nx, ny = 10, 24
    x, y = np.meshgrid(np.linspace(-1, 1, nx), np.linspace(-1, 3, ny), indexing="ij")
    flat = np.stack([x.ravel(), y.ravel(), np.zeros(nx * ny)], 1)
    quad = np.array([[i * ny + j, i * ny + j + ny, i * ny + j + 1] for i in range(nx - 1) for j in range(ny - 1)])
    faces = np.concatenate([quad, np.stack([quad[:, 2], quad[:, 1], quad[:, 1] + 1], 1)])
    if c is None:
        return flat, faces
    v = flat.copy()
    top = flat[:, 1] > 1
    s = flat[top, 1] - 1
    v[top, 1] = 1 - s
    v[top, 2] = 0.8 * s * (s - c)
    return v, faces


def test_collision_kinds_of_analytic_cases():
    """deep: one sphere 0.8 radius into another; distant contact: a shallow overlap of two spheres, a bump
    through another sheet (separate components), a strip folded back through itself far from the crease; local
    fold: the strip through itself next to the crease; None: free. outcome_by_kind counts per kind."""
    from neuralcol.handler.collision_kinds import collision_kind, kinds_of, outcome_by_kind

    rest, faces = _spheres(3.0)
    lab = ExactLabeler(faces, rest)
    assert collision_kind(lab, _spheres(1.2)[0]) == "deep"
    assert collision_kind(lab, _spheres(1.97)[0]) == "distant contact"
    assert collision_kind(lab, _spheres(2.5)[0]) is None
    sheet, sheet_faces = _bump_through_sheet(-0.2)
    assert collision_kind(ExactLabeler(sheet_faces, _bump_through_sheet(0.3)[0]), sheet) == "distant contact"
    strip, strip_faces = _folded_strip(None)
    lab_strip = ExactLabeler(strip_faces, strip)
    assert collision_kind(lab_strip, _folded_strip(0.3)[0]) == "local fold"  # through itself next to the crease
    assert collision_kind(lab_strip, _folded_strip(1.5)[0]) == "distant contact"  # 8+ rows from it
    counts = outcome_by_kind(kinds_of(lab, np.stack([_spheres(1.2)[0], _spheres(1.97)[0], _spheres(1.3)[0]])),
                             np.array([True, False, False]))
    assert counts["deep"] == {"n": 2, "freed": 1, "rate": 0.5}
    assert counts["distant contact"]["n"] == 1 and counts["local fold"]["n"] == 0


def test_contact_untangle_is_the_push_where_it_frees_and_untangle_elsewhere():
    """handler.repair.method=contact_untangle: the contact push's mesh where it frees the input; where it does not
    (no iterations allowed here), untangle's from the input, bit for bit."""
    from neuralcol.repair.contact import outward_sign
    from neuralcol.repair.meshes import repair_meshes
    from neuralcol.repair.settings import RepairSettings

    rest, faces = _spheres(3.0)
    lab = ExactLabeler(faces, rest)
    v = np.stack([_spheres(1.9)[0], _spheres(1.2)[0]])
    sign = outward_sign(faces, rest)

    def repaired(**kw):
        return repair_meshes(v, faces, lab, RepairSettings(**kw), lab.eps, lab.diag, sign)

    contact, ok_c, _ = repaired(method="contact")
    untangled, ok_u, _ = repaired(method="untangle")
    both, ok_b, _ = repaired(method="contact_untangle")
    assert ok_u.all() and ok_b.all()
    for k in range(2):
        np.testing.assert_array_equal(both[k], contact[k] if ok_c[k] else untangled[k])
    forced, ok_f, _ = repaired(method="contact_untangle", max_iter=0)
    assert ok_f.all()
    np.testing.assert_array_equal(forced, untangled)
    with pytest.raises(ValueError, match="contact_untangle"):
        RepairSettings(method="push")


def test_field_solved_near_its_targets_is_the_whole_mesh_field():
    """On a large mesh with local targets, SmoothField solves the neighbourhood within reach alone: the vertices
    beyond it stay exactly put and the rest match the whole mesh's field to 1e-5 of the targets' moves."""
    import scipy.sparse as sp
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=6)  # 40 962 vertices, ~200 edge rings pole to pole
    faces, n = np.asarray(s.faces), len(s.vertices)
    field = SmoothField(faces, n, stiffness=1.0, anchor=0.05)
    index = np.array([0, *np.flatnonzero((faces == 0).any(1))[:2]])  # a vertex and two of its neighbours' faces
    index = np.unique(faces[index].ravel())[:3]
    targets = np.array([[0.01, 0.0, 0.0], [0.0, 0.02, 0.0], [0.0, 0.0, -0.01]])
    reach = field.within_reach(index)
    assert 0 < reach.sum() < field.LOCAL_SHARE * n, "the targets' reach is a neighbourhood, not the mesh"
    local = field.solve(index, targets, hold=10.0)
    w = np.zeros(n)
    w[index] = 10.0
    rhs = np.zeros((n, 3))
    rhs[index] = 10.0 * targets
    whole = sp.linalg.spsolve((field.base + sp.diags(w)).tocsc(), rhs)
    assert (local[~reach] == 0).all()
    np.testing.assert_allclose(local, whole, rtol=0, atol=1e-5 * np.abs(targets).max())
    assert np.abs(whole[~reach]).max() > 0, "the whole mesh's field does reach that far, if faintly"
