"""Exact labeler: adjacency rules, agreement with MeshLab, analytic penetration depth and clearance."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from neuralcol.collision.labeler import (
    SUBSET_BOUNDARY,
    SUBSET_NEGATIVE,
    SUBSET_POSITIVE,
    ExactLabeler,
    split_subsets,
)


@pytest.fixture(scope="module")
def scape_np(scape):
    return scape.vertices.numpy().astype(np.float64), scape.faces.numpy()


@pytest.fixture(scope="module")
def scape_labeler(scape_np):
    verts, faces = scape_np
    return ExactLabeler(faces, verts[0])


def meshlab_collides(verts: np.ndarray, faces: np.ndarray) -> bool:
    """Independent reference: MeshLab's per-face self-intersection filter."""
    pymeshlab = pytest.importorskip("pymeshlab")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=verts, face_matrix=faces))
    ms.compute_selection_by_self_intersections_per_face()
    return ms.current_mesh().selected_face_number() > 0


# ------------------------------------------------------------------------------------------ adjacency
def test_edge_neighbours_folded_flat_never_count():
    verts = np.array([[0, 0, 0], [1, 0, 0], [0.3, 1, 0], [0.4, 0.8, 0.0]], float)  # d lies on triangle abc
    faces = np.array([[0, 1, 2], [1, 0, 3]])
    lab = ExactLabeler(faces, np.array([[0, 0, 0], [1, 0, 0], [0.3, 1, 0], [0.4, -0.8, 0.0]], float))
    assert not lab.verdict(verts) and lab.label(verts).n_pairs == 0
    verts[3, 2] = 0.3  # folded past flat: still an edge neighbour
    assert not lab.verdict(verts)


def _one_vertex_fan(tip):
    """Triangles (0, 1, 2) and (0, 3, 4) share vertex 0 only; the second's far edge is at height tip."""
    rest = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0.2, 0.0], [-0.8, -0.9, 0.0]], float)
    faces = np.array([[0, 1, 2], [0, 3, 4]])
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.5, 0.2, tip], [0.4, 0.1, -0.3]], float)
    return ExactLabeler(faces, rest), verts


def test_fold_through_one_vertex_neighbour_counts():
    lab, verts = _one_vertex_fan(tip=0.3)  # edge (3, 4) pierces triangle (0, 1, 2)
    label = lab.label(verts)
    assert lab.verdict(verts) and label.collides and label.n_pairs == 1 and label.pd > 0


def test_one_vertex_neighbours_touching_at_the_vertex_do_not_count():
    lab, _ = _one_vertex_fan(tip=0.3)
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0.2, 0.5], [-0.8, -0.9, 0.4]], float)
    assert not lab.verdict(verts)
    assert lab.label(verts).pd < 0


def test_subdivided_coplanar_triangles_never_count(scape_np):
    verts, faces = scape_np
    v1, f1 = trimesh.remesh.subdivide(verts[0], faces)
    v2, f2 = trimesh.remesh.subdivide(v1, f1)
    for v, f in ((v1, f1), (v2, f2)):  # exact midpoints: many exactly coplanar one-vertex neighbours
        lab = ExactLabeler(f, v)
        assert len(lab.intersecting_pairs(v)) == 0
        assert not lab.label(v).collides
    flat = trimesh.creation.box(extents=(1, 1, 1))
    fv, ff = trimesh.remesh.subdivide_to_size(flat.vertices, flat.faces, max_edge=0.1)
    assert not ExactLabeler(ff, fv).verdict(fv)


# ------------------------------------------------------------------------------------------ MeshLab
def test_scape_verdicts_match_meshlab(scape_np, scape_labeler):
    verts, faces = scape_np
    ours = [scape_labeler.verdict(v) for v in verts]
    ref = [meshlab_collides(v, faces) for v in verts]
    assert ours == ref, [i + 1 for i in range(len(ours)) if ours[i] != ref[i]]
    assert sum(ref) == 2  # files 8 and 71
    for i in np.nonzero(ref)[0]:  # the same faces as MeshLab's selection
        import pymeshlab

        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=verts[i], face_matrix=faces))
        ms.compute_selection_by_self_intersections_per_face()
        sel = set(np.nonzero(ms.current_mesh().face_selection_array())[0].tolist())
        assert set(np.unique(scape_labeler.intersecting_pairs(verts[i])).tolist()) == sel


def test_variants_match_meshlab_including_near_boundary(scape_np, scape_labeler):
    """>= 200 interpolations / extrapolations of SCAPE poses, plus pairs of samples straddling the boundary."""
    verts, faces = scape_np
    rng = np.random.default_rng(0)
    free = [i for i in range(len(verts)) if i not in (7, 70)]
    variants = []
    for _ in range(200):
        i, j = rng.choice(free, 2, replace=False)
        t = rng.uniform(-0.8, 1.8)
        variants.append(verts[i] + t * (verts[j] - verts[i]))
    ours = np.array([scape_labeler.verdict(v) for v in variants])
    assert 0.1 < ours.mean() < 0.9, f"variants should mix both classes, got {ours.mean():.2f} colliding"
    # boundary: bisect along free -> colliding paths, then step a little to each side
    near = []
    for k in np.nonzero(ours)[0][:12]:
        i, j = k, k  # placeholder to keep the loop readable
        lo, hi = np.zeros_like(verts[0]), variants[k]
        lo = verts[free[k % len(free)]]
        if scape_labeler.verdict(lo):
            continue
        a, b = 0.0, 1.0
        for _ in range(30):
            m = 0.5 * (a + b)
            if scape_labeler.verdict(lo + m * (hi - lo)):
                b = m
            else:
                a = m
        step = 2e-3 * (b if b > 0 else 1.0)
        near += [lo + (a - step) * (hi - lo), lo + (b + step) * (hi - lo)]
        del i, j
    assert len(near) >= 16
    near_ours = [scape_labeler.verdict(v) for v in near]
    assert near_ours[0::2] == [False] * (len(near) // 2) and near_ours[1::2] == [True] * (len(near) // 2)
    all_v = variants + near
    ref = np.array([meshlab_collides(v, faces) for v in all_v])
    ours_all = np.concatenate([ours, near_ours])
    bad = np.nonzero(ref != ours_all)[0]
    assert len(bad) == 0, f"{len(bad)} of {len(all_v)} verdicts differ from MeshLab: {bad[:10]}"


def test_label_consistency_on_variants(scape_np, scape_labeler):
    verts, faces = scape_np
    rng = np.random.default_rng(1)
    for _ in range(40):
        i, j = rng.choice(69, 2, replace=False)
        v = verts[i] + rng.uniform(-0.8, 1.8) * (verts[j] - verts[i])
        lb = scape_labeler.label(v)
        assert lb.collides == scape_labeler.verdict(v) == (lb.n_pairs > 0) == (lb.pd > 0)
        assert lb.pd == lb.pd_sub.max()
        assert -scape_labeler.cap <= lb.pd


# ------------------------------------------------------------------------------------------ analytic
def _two_spheres(subdiv=4, rotvec=(0.3, 0.2, 0.1)):
    s = trimesh.creation.icosphere(subdivisions=subdiv, radius=1.0)
    v = np.asarray(s.vertices)
    f = np.asarray(s.faces)
    v2 = Rotation.from_rotvec(rotvec).apply(v)  # avoid vertices exactly on the other sphere
    faces = np.concatenate([f, f + len(v)])
    part = np.repeat([0, 1], len(v))
    return (lambda d: np.concatenate([v, v2 + [d, 0.0, 0.0]])), faces, part


def test_spheres_pd_matches_analytic_depth_and_clearance():
    at, faces, part = _two_spheres(subdiv=4)  # 2562 vertices each; faces sit < 1e-3 inside the sphere
    rest = at(6.0)
    diag = np.linalg.norm(rest.max(0) - rest.min(0))
    lab = ExactLabeler(faces, rest, partition=part, clearance_cap=0.2 / diag)  # cap = 0.2
    ds = np.linspace(2.15, 1.05, 23)
    pds = []
    for d in ds:
        lb = lab.label(at(d))
        analytic = 2.0 - d  # translational penetration depth (> 0) or minus the gap (< 0)
        pds.append(lb.pd)
        assert lb.collides == (analytic > 0)
        assert lb.pd == pytest.approx(analytic, rel=0.05, abs=2e-3), f"D={d:.3f}"
        np.testing.assert_allclose(lb.pd_sub, [lb.pd, lb.pd], rtol=0.05, atol=2e-3)
    steps = np.diff(pds)
    assert (steps > 0).all(), "PD grows monotonically as the spheres move into each other"
    assert np.abs(steps).max() < 3 * (ds[0] - ds[1]), "no jumps: PD changes like the distance"


def test_boxes_pd_matches_analytic():
    box = trimesh.creation.box(extents=(1, 1, 1))
    v, f = trimesh.remesh.subdivide_to_size(box.vertices + 0.5, box.faces, max_edge=0.25)
    faces = np.concatenate([f, f + len(v)])

    # generic position: a tiny rotation keeps the two grids from lining up exactly (exactly aligned grids
    # make edges graze edges; see docs/labels.md, "degenerate contacts")
    v2 = Rotation.from_rotvec([2e-3, -1e-3, 1.5e-3]).apply(v - 0.5) + 0.5

    def at(s):
        return np.concatenate([v, v2 + [s, 0.3, 0.2]])

    lab = ExactLabeler(faces, at(3.0), clearance_cap=0.1)
    for s in (1.3, 1.1, 1.02, 0.98, 0.95, 0.9, 0.85):
        analytic = 1.0 - s  # overlap along x (< the y, z overlaps 0.7, 0.8)
        lb = lab.label(at(s))
        assert lb.collides == (analytic > 0)
        assert lb.pd == pytest.approx(analytic, rel=0.05, abs=1e-6), f"s={s}"


def test_partition_uninvolved_part_keeps_clearance():
    at, faces, part = _two_spheres(subdiv=3)
    third = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    tv = np.asarray(third.vertices)
    faces3 = np.concatenate([faces, np.asarray(third.faces) + 2 * len(tv)])
    part3 = np.concatenate([part, np.full(len(tv), 2)])

    def at3(d, y=2.3):
        return np.concatenate([at(d), tv + [0.0, y, 0.0]])  # third sphere 0.3 above the first

    rest = at3(6.0, y=6.0)  # all apart in the rest mesh
    lab = ExactLabeler(faces3, rest, partition=part3, clearance_cap=0.5 / np.linalg.norm(rest.max(0) - rest.min(0)))
    lb = lab.label(at3(1.8))
    assert lb.collides and lb.pd == pytest.approx(0.2, rel=0.05)
    assert lb.pd_sub[2] == pytest.approx(-0.3, rel=0.05), "part 2 is free: minus its clearance"
    assert lb.pd == lb.pd_sub.max()


def test_split_subsets():
    pd = np.array([-0.3, -1e-9, 0.0, 0.005, 0.01, 0.0100001, 2.0])
    codes = split_subsets(pd, eps=0.01)
    assert codes.tolist() == [SUBSET_NEGATIVE, SUBSET_NEGATIVE, SUBSET_BOUNDARY, SUBSET_BOUNDARY,
                              SUBSET_BOUNDARY, SUBSET_POSITIVE, SUBSET_POSITIVE]


def test_bad_input():
    lab, verts = _one_vertex_fan(0.3)
    with pytest.raises(ValueError, match=r"expected \(5, 3\)"):
        lab.label(verts[:4])
    bad = verts.copy()
    bad[1, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        lab.label(bad)


def test_clearance_of_separate_parts_matches_fcl_distance():
    """Far-pair clearance = exact polyhedral distance; python-fcl's BVH distance is the reference."""
    fcl = pytest.importorskip("fcl")
    at, faces, _ = _two_spheres(subdiv=3)
    rest = at(6.0)
    lab = ExactLabeler(faces, rest, clearance_cap=0.5 / np.linalg.norm(rest.max(0) - rest.min(0)))
    n_v, n_f = len(rest) // 2, len(faces) // 2

    def bvh(v, f):
        m = fcl.BVHModel()
        m.beginModel(len(v), len(f))
        m.addSubModel(v, f)
        m.endModel()
        return fcl.CollisionObject(m)

    for d in (2.03, 2.1, 2.3, 2.45):
        v = at(d)
        res = fcl.DistanceResult()
        fcl.distance(bvh(v[:n_v], faces[:n_f]), bvh(v[n_v:], faces[n_f:] - n_v), fcl.DistanceRequest(), res)
        assert lab.label(v).pd == pytest.approx(-res.min_distance, rel=1e-6, abs=1e-9), f"D={d}"


def test_build_labeler_from_the_labeling_group(tube):
    """``labeling=<backend>`` files build their labeler through Hydra; a wrong target, an unknown setting or
    ``labeling.backend`` set without its file are named."""
    from pathlib import Path

    from hydra import compose, initialize_config_dir

    from neuralcol.collision.backends import build_labeler, gpu_available

    verts, faces = tube

    def labeling(*overrides):
        conf = Path(__file__).resolve().parents[1] / "conf"
        with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
            return compose(config_name="config", overrides=list(overrides)).labeling

    cfg = labeling()
    lab = build_labeler(cfg, faces, verts)
    assert type(lab) is ExactLabeler and cfg.backend == lab.backend == "cpu"
    assert lab.eps == pytest.approx(cfg.labeler.boundary_eps * lab.diag) and lab.n_parts == 1
    ref = ExactLabeler(faces, verts, boundary_eps=cfg.labeler.boundary_eps)
    assert lab.label(verts).pd == ref.label(verts).pd
    if not gpu_available():  # auto: the CPU labeler without CUDA
        assert type(build_labeler(labeling("labeling=auto"), faces, verts)) is ExactLabeler
    with pytest.raises(ValueError, match=r"labeling.labeler._target_='neuralcol.collision.labeler.Nope'"):
        build_labeler(labeling("labeling.labeler._target_=neuralcol.collision.labeler.Nope"), faces, verts)
    with pytest.raises(ValueError, match=r"labeling.labeler.tol=1: not a setting of"):
        build_labeler(labeling("+labeling.labeler.tol=1"), faces, verts)
    with pytest.raises(ValueError, match=r"labeling.backend='fcl': .* choose a backend with labeling=fcl"):
        build_labeler(labeling("labeling.backend=fcl"), faces, verts)


# ------------------------------------------------------------------------------------------ labels for training


def _limited_cases(scape_np):
    """SCAPE interpolations (both classes) with 4 parts, and the labelers pruned and reference."""
    verts, faces = scape_np
    rng = np.random.default_rng(3)
    part = (verts[0][:, 1] > np.median(verts[0][:, 1])).astype(np.int64) * 2 + (verts[0][:, 0] > 0)
    meshes = []
    for _ in range(24):
        i, j = rng.choice(69, 2, replace=False)
        meshes.append(verts[i] + rng.uniform(-0.8, 1.8) * (verts[j] - verts[i]))
    return meshes, ExactLabeler(faces, verts[0], partition=part)


@pytest.mark.parametrize("floor", [0.05, 0.25, 0.6, 2.0])
def test_limited_label_is_the_full_label_with_clearances_capped(scape_np, floor):
    """label_limited(v, L) == max(PD_i, -L) of the full label bit for bit, verdict and counted pairs equal, and the
    detector's clipped targets (clip(pd / cap, -floor, 0.25)) equal the full label's: pruned and reference paths."""
    from neuralcol.collision.labeler import limit_clearance
    from neuralcol.samples.oracle import training_clearance_limit

    meshes, lab = _limited_cases(scape_np)
    limit = training_clearance_limit(lab.cap, -floor)
    full = [lab.label(v) for v in meshes]
    assert 0 < np.mean([f.collides for f in full]) < 1
    assert any((f.pd_sub < -limit).any() for f in full) or floor >= 1.0, "some clearance beyond the limit"
    for prune in (True, False):
        lab.prune = prune
        for v, f in zip(meshes, full):
            got = lab.label_limited(v, limit)
            want = limit_clearance(f, limit)
            assert (got.collides, got.n_pairs, got.pd) == (want.collides, want.n_pairs, want.pd)
            np.testing.assert_array_equal(got.pd_sub, want.pd_sub)
            clip = lambda x: np.clip(np.asarray(x) / lab.cap, -floor, 0.25)  # noqa: E731
            np.testing.assert_array_equal(clip(got.pd_sub), clip(f.pd_sub))
            assert clip(got.pd) == clip(f.pd)
            assert split_subsets(np.array([got.pd]), lab.eps) == split_subsets(np.array([f.pd]), lab.eps)
        a, b = lab.label_limited(meshes[0]), lab.label(meshes[0])  # no limit: the full label
        assert (a.collides, a.n_pairs, a.pd) == (b.collides, b.n_pairs, b.pd)
        np.testing.assert_array_equal(a.pd_sub, b.pd_sub)
    lab.prune = True
    with pytest.raises(ValueError, match="clearance_limit"):
        lab.label_limited(meshes[0], 0.0)


def test_label_without_clearance_is_the_full_label_where_it_collides(scape_np):
    """ExactLabeler(clearance=False): verdict, counted pairs, vertex depths and every positive PD_i equal the full
    label's bit for bit, every other PD_i is -cap, and no near table is ever built (verdict, pairs, penetrations,
    label); a mesh labelled against itself gets the full label's free PD to the last bit or so."""
    meshes, lab = _limited_cases(scape_np)
    lean = ExactLabeler(lab.faces, lab.rest, partition=lab.partition, clearance=False)
    n_colliding = 0
    for v in meshes:
        full, got = lab.label(v), lean.label(v)
        assert (got.collides, got.n_pairs) == (full.collides, full.n_pairs)
        hit = full.pd_sub > 0
        n_colliding += bool(hit.any())
        np.testing.assert_array_equal(got.pd_sub[hit], full.pd_sub[hit])
        np.testing.assert_array_equal(got.pd_sub[~hit], -lean.cap)
        np.testing.assert_array_equal(lean.vertex_depths(v), lab.vertex_depths(v))
        assert lean.verdict(v) == full.collides
        np.testing.assert_array_equal(lean.intersecting_pairs(v), lab.intersecting_pairs(v))
        a, b = lean.penetrations(v), lab.penetrations(v)  # the grid's records and the near table's: the same
        assert a.n_pairs == b.n_pairs
        for x, y in ((a.depth, b.depth), (a.vector, b.vector), (a.crossing_pairs, b.crossing_pairs)):
            np.testing.assert_array_equal(x, y)
    assert 0 < n_colliding < len(meshes)
    assert lean._near is None, "the labeler without clearance never builds the rest mesh's near table"
    at_rest = ExactLabeler(lab.faces, lab.rest)
    assert lean.label(lab.rest).pd == pytest.approx(at_rest.label(lab.rest).pd, rel=1e-14, abs=0)


def test_large_mesh_checks_follow_the_moved_region_and_match_whole_checks():
    """On a mesh of INCREMENTAL_FACES faces or more, consecutive checks find the pairs again only where the mesh moved;
    along a sequence of local moves (and a whole-mesh one), the pairs and the penetrations equal a fresh labeler's
    whole-mesh check, and the labels too."""
    from neuralcol.collision import labeler as L

    s = trimesh.creation.icosphere(subdivisions=5)  # 20 480 faces
    v0, f = np.asarray(s.vertices, np.float64), np.asarray(s.faces, np.int64)
    assert len(f) >= L.INCREMENTAL_FACES
    lab = ExactLabeler(f, v0, clearance=False)
    rng = np.random.default_rng(0)
    v = v0.copy()
    cap = v[:, 2] > 0.9
    v[cap, 2] -= 0.25  # the north cap pushed through: a colliding start
    seen, modes = [], []
    for step in range(6):
        if step == 4:
            v = v + rng.normal(scale=1e-3, size=v.shape)  # everything moves: a whole check again
        else:
            centre = v[rng.integers(len(v))]
            near = np.linalg.norm(v - centre, axis=1) < 0.15
            v = v.copy()
            v[near] += rng.normal(scale=0.02, size=(near.sum(), 3))
        fresh = ExactLabeler(f, v0, clearance=False)
        full = fresh.candidate_pairs(v)
        full = full[L.counted_mask(v, f, full, 1.0, 0.0)]
        full = full[np.lexsort((full[:, 1], full[:, 0]))]
        got = lab.intersecting_pairs(v)
        modes.append(lab._last_mode)
        np.testing.assert_array_equal(got, full)
        a, b = lab.penetrations(v), fresh.penetrations(v)
        assert a.n_pairs == b.n_pairs == len(full)
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.crossing_pairs, b.crossing_pairs)
        la, lb = lab.label(v), fresh.label(v)
        assert (la.collides, la.n_pairs, la.pd) == (lb.collides, lb.n_pairs, lb.pd)
        seen.append(len(full))
    assert max(seen) > 0
    assert modes == ["whole", "moved", "moved", "moved", "whole", "moved"], modes
