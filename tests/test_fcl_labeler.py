"""python-fcl backend (``labeling=fcl``): the paper's labels with ExactLabeler's interface."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

fcl = pytest.importorskip("fcl")

from neuralcol.collision.backends import build_labeler  # noqa: E402
from neuralcol.collision.fcl_labeler import FCLLabeler, box_pairs  # noqa: E402
from neuralcol.collision.labeler import ExactLabeler  # noqa: E402
from neuralcol.collision.pool import LabelPool  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _spheres(centers, subdiv=2):
    """Unit icospheres at ``centers`` along x (each rotated a little, so no vertex lies exactly on another
    sphere); returns vertices, faces, partition (one part per sphere) and the (V_i, F_i) of one sphere."""
    s = trimesh.creation.icosphere(subdivisions=subdiv, radius=1.0)
    v0, f0 = np.asarray(s.vertices), np.asarray(s.faces)
    verts, faces = [], []
    for k, c in enumerate(centers):
        verts.append(Rotation.from_rotvec([0.3 * k + 0.1, 0.2, 0.1 * k]).apply(v0) + [c, 0.0, 0.0])
        faces.append(f0 + k * len(v0))
    part = np.repeat(np.arange(len(centers)), len(v0))
    return np.concatenate(verts), np.concatenate(faces), part, (len(v0), len(f0))


def _fcl_distance(v, f, n_v, n_f, a, b):
    """fcl.distance between spheres a and b of a _spheres mesh."""
    def obj(k):
        m = fcl.BVHModel()
        m.beginModel(n_v, n_f)
        m.addSubModel(v[k * n_v:(k + 1) * n_v], f[k * n_f:(k + 1) * n_f] - k * n_v)
        m.endModel()
        return fcl.CollisionObject(m)
    return fcl.distance(obj(a), obj(b), fcl.DistanceRequest(), fcl.DistanceResult())


# ------------------------------------------------------------------------------------------ analytic
def test_separate_spheres_pd_is_minus_capped_gap():
    rest, faces, part, (n_v, n_f) = _spheres([0.0, 6.0])
    diag = float(np.linalg.norm(rest.max(0) - rest.min(0)))
    lab = FCLLabeler(faces, rest, clearance_cap=0.5 / diag)  # cap = 0.5
    assert lab.cap == pytest.approx(0.5)
    assert lab.label(rest).pd == pytest.approx(-lab.cap)  # far apart: at the cap
    for d in (2.05, 2.2, 2.4, 3.0):
        v, *_ = _spheres([0.0, d])
        gap = _fcl_distance(v, faces, n_v, n_f, 0, 1)
        assert d - 2.0 <= gap <= d - 2.0 + 0.03  # polyhedral spheres: faces lie just inside the unit sphere
        lb = lab.label(v)
        assert not lb.collides and not lab.verdict(v) and lb.n_pairs == 0
        assert lb.pd == pytest.approx(-min(lab.cap, gap), rel=1e-9, abs=1e-12), f"D={d}"
        assert lb.pd_sub.shape == (1,) and lb.pd == lb.pd_sub.max()


def test_interpenetrating_spheres_collide_with_positive_pd():
    rest, faces, part, _ = _spheres([0.0, 6.0])
    lab = FCLLabeler(faces, rest, partition=part)
    assert lab.n_parts == 2
    for d in (1.9, 1.6):
        v, *_ = _spheres([0.0, d])
        lb = lab.label(v)
        assert lb.collides and lab.verdict(v) and lb.n_pairs > 0
        assert lb.pd > lab.tau and (lb.pd_sub > 0).all() and lb.pd == lb.pd_sub.max()
        assert len(lab.intersecting_pairs(v)) == lb.n_pairs


def test_free_part_keeps_its_clearance_next_to_a_collision():
    rest, faces, part, (n_v, n_f) = _spheres([0.0, 6.0, 12.0])
    diag = float(np.linalg.norm(rest.max(0) - rest.min(0)))
    lab = FCLLabeler(faces, rest, partition=part, clearance_cap=0.5 / diag)
    v, *_ = _spheres([0.0, 1.8, 4.1])  # spheres 0 and 1 overlap, sphere 2 is 0.3 from sphere 1
    lb = lab.label(v)
    gap = _fcl_distance(v, faces, n_v, n_f, 1, 2)
    assert lb.collides and lb.pd_sub[0] > 0 and lb.pd_sub[1] > 0
    assert lb.pd_sub[2] == pytest.approx(-gap, rel=1e-9)


def test_one_vertex_fold_is_not_counted_unlike_exact_labeler():
    """Documented difference: FCL cannot tell a fold through a one-vertex neighbour from touching at it."""
    rest = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0.2, 0.0], [-0.8, -0.9, 0.0]], float)
    faces = np.array([[0, 1, 2], [0, 3, 4]])
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.5, 0.2, 0.3], [0.4, 0.1, -0.3]], float)
    assert ExactLabeler(faces, rest).verdict(verts)
    lab = FCLLabeler(faces, rest)
    assert not lab.verdict(verts) and lab.label(verts).n_pairs == 0


def test_box_pairs_matches_brute_force_with_shared_centres():
    rng = np.random.default_rng(0)
    lo = rng.uniform(0, 10, (300, 3))
    hi = lo + rng.uniform(0, 1.5, (300, 3))
    lo[1], hi[1] = lo[0], hi[0]  # two boxes at one centre (the two triangles of an axis-aligned quad)
    lo[2], hi[2] = lo[0] + 0.1, hi[0] - 0.1
    got = box_pairs(lo, hi)
    ov = ((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None])).all(-1)
    i, j = np.nonzero(np.triu(ov, 1))
    assert np.array_equal(got, np.stack([i, j], 1))


# ------------------------------------------------------------------------------------------ SCAPE
@pytest.fixture(scope="module")
def scape_fcl(scape):
    verts = scape.vertices.numpy().astype(np.float64)
    faces = scape.faces.numpy()
    return verts, faces, ExactLabeler(faces, verts[0]), FCLLabeler(faces, verts[0])


def test_verdicts_agree_with_exact_labeler_on_scape(scape_fcl):
    verts, faces, exact, lab = scape_fcl
    rng = np.random.default_rng(3)
    meshes = [verts[i] for i in (0, 7, 70, 12, 45)]  # 7 and 70 collide
    for _ in range(5):  # inter-/extrapolations between free poses: both classes
        i, j = rng.choice([k for k in range(len(verts)) if k not in (7, 70)], 2, replace=False)
        meshes.append(verts[i] + rng.uniform(-0.8, 1.8) * (verts[j] - verts[i]))
    ref = np.array([exact.verdict(v) for v in meshes])
    labels = lab.label_batch(np.stack(meshes))
    assert ref.sum() >= 3 and (~ref).sum() >= 3
    assert np.array_equal(labels.collides, ref)
    assert np.array_equal(labels.pd > 0, ref) and np.array_equal(labels.n_pairs > 0, ref)
    assert [lab.verdict(v) for v in meshes] == ref.tolist()
    assert lab.label(verts[0]).pd == pytest.approx(-lab.cap)  # the rest mesh sits at the cap
    assert (labels.pd >= -lab.cap).all()


def test_broadphase_grid_and_whole_mesh_bvh_give_the_same_contacts(scape_fcl):
    verts, faces, _, lab = scape_fcl
    bvh = FCLLabeler(faces, verts[0], method="bvh")
    grid = FCLLabeler(faces, verts[0], method="grid")
    pa, da = lab.counted_pairs(verts[7])
    pb, db = bvh.counted_pairs(verts[7])
    assert len(pa) > 50 and np.array_equal(pa, pb)
    np.testing.assert_allclose(da, db, rtol=1e-12, atol=1e-15)
    for v in (verts[7], verts[70], verts[12]):
        assert np.array_equal(lab.candidate_pairs(v), grid.candidate_pairs(v))
        a, b = lab.label(v), grid.label(v)
        assert (a.collides, a.n_pairs, a.pd) == (b.collides, b.n_pairs, b.pd)


def test_pickles_and_labels_the_same(scape_fcl):
    verts, faces, _, lab = scape_fcl
    part = (verts[0][:, 1] > np.median(verts[0][:, 1])).astype(np.int64)
    lab4 = FCLLabeler(faces, verts[0], partition=part)
    clone = pickle.loads(pickle.dumps(lab4))
    a, b = lab4.label(verts[7]), clone.label(verts[7])
    assert a.collides == b.collides and a.n_pairs == b.n_pairs and a.pd == b.pd
    assert np.array_equal(a.pd_sub, b.pd_sub) and clone.n_parts == 2


# ------------------------------------------------------------------------------------------ plumbing
def test_build_labeler_from_the_labeling_config_and_label_pool():
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=["labeling=fcl"]).labeling  # conf/labeling/fcl.yaml
    rest, faces, part, _ = _spheres([0.0, 6.0])
    lab = build_labeler(cfg, faces, rest, partition=part)
    assert isinstance(lab, FCLLabeler) and lab.label_kind == "fcl"
    assert lab.tau == pytest.approx(cfg.labeler.touch_tol * lab.ell)
    assert lab.cap == pytest.approx(cfg.labeler.clearance_cap * lab.diag)
    assert lab.eps == pytest.approx(cfg.labeler.boundary_eps * lab.diag)
    lab2 = build_labeler({"backend": "fcl", "labeler": {"_target_": "neuralcol.collision.fcl_labeler.FCLLabeler",
                                                        "clearance_cap": 0.05, "touch_tol": 0.0}}, faces, rest)
    assert lab2.cap == pytest.approx(0.05 * lab2.diag) and lab2.tau == 0.0 and lab2.n_parts == 1
    batch = np.stack([_spheres([0.0, d])[0] for d in (1.7, 2.1, 2.6)])
    with LabelPool(lab, workers=0, progress=False) as pool:
        got = pool.label(batch)
    ref = lab.label_batch(batch)
    assert got.collides.tolist() == [True, False, False]
    for key in ("collides", "n_pairs", "pd", "pd_sub"):
        assert np.array_equal(getattr(got, key), getattr(ref, key)), key
    assert lab.subsets(got.pd).tolist() == [0, 1, 1]  # D_p, D_n, D_n


def test_rejects_bad_input():
    rest, faces, _, _ = _spheres([0.0, 6.0])
    with pytest.raises(ValueError):
        FCLLabeler(faces, rest, method="sweep")
    with pytest.raises(ValueError):
        FCLLabeler(faces, rest, partition=np.zeros(3, dtype=int))
    lab = FCLLabeler(faces, rest)
    bad = rest.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError):
        lab.label(bad)
    with pytest.raises(ValueError):
        lab.verdict(rest[:-1])
