"""The realistic evaluation set: construction, clear cases, out-of-box codes, and the handler's
displacement transfer (the user's mesh comes back, corrected)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuralcol.data.realistic import KINDS, balanced_selection, clear_mask, make_realistic_meshes, out_of_box
from neuralcol.geometry.acap import ACAP
from neuralcol.handler.resolve import transfer_displacement
from neuralcol.repair.cap import displacement_stats
from tests.conftest import make_tube, twist


@pytest.fixture(scope="module")
def tube_set():
    v0, f = make_tube(n_rings=10, n_around=8)
    poses = np.stack([twist(v0, a) for a in (0.0, 0.4, 0.8, 1.2)])
    acap = ACAP(poses[0], f)
    feats = acap.encode(torch.as_tensor(poses))
    return poses, feats, acap


def test_kinds_sources_and_endpoints(tube_set):
    poses, feats, acap = tube_set
    m = make_realistic_meshes(poses, feats, acap, heldout=[3], n_acap_interp=6, n_vertex_interp=5, n_perturbed=4,
                              t_range=(0.0, 1.0), perturb_scale=0.2, seed=1)
    assert m.vertices.shape == (1 + 6 + 5 + 4, poses.shape[1], 3)
    np.testing.assert_array_equal(np.bincount(m.kind, minlength=len(KINDS)), [1, 6, 5, 4])
    np.testing.assert_array_equal(m.vertices[0], poses[3])  # the held-out mesh itself
    acap_rows = m.kind == KINDS.index("acap_interp")
    assert (m.source[acap_rows, 0] != m.source[acap_rows, 1]).all()
    assert (m.source[m.kind == KINDS.index("perturbed"), 0] == 3).all()  # perturbations start from held-out meshes
    assert (np.abs(m.t[m.kind == KINDS.index("perturbed")]) <= 0.2).all()
    # a vertex interpolation is exactly the blend of its two source meshes
    k = np.flatnonzero(m.kind == KINDS.index("vertex_interp"))[0]
    i, j, t = m.source[k, 0], m.source[k, 1], m.t[k]
    np.testing.assert_allclose(m.vertices[k], (1 - t) * poses[i] + t * poses[j], atol=1e-12)
    # an ACAP interpolation of two twists of a tube is the twist in between (ACAP is exact on twists, up to
    # the decoder's centroid pinning and round-off)
    k = np.flatnonzero(m.kind == KINDS.index("acap_interp"))[0]
    i, j, t = m.source[k, 0], m.source[k, 1], m.t[k]
    angles = np.array([0.0, 0.4, 0.8, 1.2])
    v0 = poses[0]
    ref = twist(v0, (1 - t) * angles[i] + t * angles[j])
    ref = ref - ref.mean(0) + v0.mean(0)
    assert np.abs(m.vertices[k] - ref).max() < 2e-3
    again = make_realistic_meshes(poses, feats, acap, [3], 6, 5, 4, (0.0, 1.0), 0.2, seed=1)
    np.testing.assert_array_equal(again.vertices, m.vertices)  # seeded


def test_bad_arguments(tube_set):
    poses, feats, acap = tube_set
    with pytest.raises(ValueError, match="t_range"):
        make_realistic_meshes(poses, feats, acap, [], 1, 1, 1, t_range=(1.0, 0.0))
    with pytest.raises(ValueError, match="heldout"):
        make_realistic_meshes(poses, feats, acap, [9], 1, 1, 1)
    with pytest.raises(ValueError, match=">= 2 meshes"):
        make_realistic_meshes(poses[:1], feats[:1], acap, [], 1, 1, 1)


def test_clear_mask_and_out_of_box():
    pd = np.array([0.5, 0.05, -0.05, -0.5, np.nan, 0.0])
    np.testing.assert_array_equal(clear_mask(pd, eps=0.01, clear_eps=10), [True, False, False, True, False, False])
    z = np.array([[0.0, 0.0], [1.5, 0.0], [0.0, -1.01]])
    np.testing.assert_array_equal(out_of_box(z, np.array([-1.0, -1.0]), np.array([1.0, 1.0])), [False, True, True])


def test_transfer_keeps_the_input_where_the_code_did_not_move():
    g = torch.Generator().manual_seed(0)
    v_user = torch.randn(2, 50, 3, generator=g, dtype=torch.float64)
    base = torch.randn(2, 50, 3, generator=g, dtype=torch.float64)  # the round trip: another mesh entirely
    np.testing.assert_array_equal(transfer_displacement(v_user, base, base).numpy(), v_user.numpy())
    # a correction that moves 10 vertices by 1 and, through the decoder's centroid pinning, every vertex by
    # -0.2: the median anchor removes the shift, so 40 vertices stay exactly where the user put them
    after = base.clone()
    after[:, :10, 0] += 1.0
    after[:, :, 0] -= 0.2
    out = transfer_displacement(v_user, base, after, anchor="median")
    np.testing.assert_allclose(out[:, 10:].numpy(), v_user[:, 10:].numpy(), atol=1e-12)
    np.testing.assert_allclose((out - v_user)[:, :10, 0].numpy(), 1.0, atol=1e-12)
    raw = transfer_displacement(v_user, base, after, anchor="none")
    np.testing.assert_allclose((raw - v_user)[:, 10:, 0].numpy(), -0.2, atol=1e-12)
    with pytest.raises(ValueError, match="anchor"):
        transfer_displacement(v_user, base, after, anchor="mean")


def test_displacement_stats_by_hand():
    v = np.zeros((1, 4, 3))
    out = v.copy()
    out[0, 0] = [3.0, 4.0, 0.0]  # one vertex moved by 5
    s = displacement_stats(v, out, diagonal=10.0)
    assert s["median"][0] == 0.0 and s["max"][0] == 5.0 and s["mean"][0] == pytest.approx(1.25)
    assert s["max_frac"][0] == pytest.approx(0.5)


def test_balanced_selection():
    kind = np.array([0, 0, 1, 1, 1, 1, 2, 2, 3, 3, 3])
    pd = np.array([0.5, -0.5, 0.5, 0.5, 0.5, -0.5, 0.05, -0.5, np.nan, -0.5, 0.5])
    keep = balanced_selection(kind, pd, eps=0.01, clear_eps=10, per_class=None, seed=0)
    assert {0, 1} <= set(keep)  # held-out meshes always
    rest = keep[kind[keep] != 0]
    assert (pd[rest] > 0).sum() == (pd[rest] < 0).sum() == 3  # 4 clear colliding, 3 clear free -> 3 + 3
    assert 6 not in keep and 8 not in keep  # near the boundary, unlabeled
    two = balanced_selection(kind, pd, 0.01, 10, per_class=2, seed=0)
    assert len(two) == 2 + 4
    np.testing.assert_array_equal(two, balanced_selection(kind, pd, 0.01, 10, per_class=2, seed=0))


def test_report_real_meshes_block():
    """The run's detector on the realistic set; the separate mesh detector's blocks of older runs
    (``mesh_detector``, ``detection_mesh``) are read without a crash and left out."""
    from experiments.reporting.markdown import realistic_rows

    def run(method, acc, mesh_acc=None):
        m = {"detector": {"method": method},
             "realistic": {"n_clear": 300, "detection": {"accuracy": acc, "fnr": 0.5},
                           "round_trip": {"agreement": 0.7}, "handling": None}}
        if mesh_acc is not None:  # an older run with the separate mesh detector
            m["mesh_detector"] = {"test": {"accuracy": 0.9}}
            m["realistic"]["detection_mesh"] = {"accuracy": mesh_acc, "fnr": 0.2}
        return m

    rows = realistic_rows([run("supv", 0.6, 0.8), run("active", 0.62), run("active", 0.64, 0.88)],
                          ["supv", "active"])
    table = [r for r in rows if r.startswith("|")]
    assert table[0] == "| real meshes: accuracy, detector | 60.00% | 63.00% ± 1.41 |"  # one seed: no spread shown
    assert not any("mesh detector" in r for r in table)
    assert not any("resolve" in r for r in table)  # no handler results: no row
    assert realistic_rows([{"detector": {"method": "supv"}}], ["supv"]) == []


def test_report_real_meshes_small_displacement_is_shown():
    """A median displacement of 4.3e-6 of the diagonal (neuralcol_s0's) printed as ``0.00%`` hid it: two
    significant digits for that row, two decimals for the rates beside it."""
    from experiments.reporting.markdown import realistic_rows

    def run(disp):
        return {"detector": {"method": "active"},
                "realistic": {"n_clear": 314, "detection": {"accuracy": 0.8, "fnr": 0.2},
                              "round_trip": {"agreement": 0.8},
                              "handling": {"verified": {"resolved_rate": 0.97}, "displacement_median_frac": disp}}}

    table = [r for r in realistic_rows([run(4.3e-6), run(4.5e-6)], ["active"]) if r.startswith("|")]
    assert "| real meshes: resolve, median displacement (% diag) | 0.00044% ± 1.4e-05 |" in table
    assert "| real meshes: resolve, collision-free (verified) | 97.00% ± 0.00 |" in table


def test_report_wall_time_per_stage():
    """Table 3's wall time per stage: minutes summed over sittings, mean ± std over the seeds of each
    method; a stage under half a minute in every run has no row but stays in the total; runs without ``sittings``
    (from before sittings were recorded) give no table."""
    from experiments.reporting.markdown import wall_time_markdown

    def run(m, detector_s, minutes, n=2):
        return {"detector": {"method": m},
                "sittings": {"n": n, "minutes": minutes,
                             "stage_seconds": {"data": 12.0, "latent": 600.0, "detector": detector_s}}}

    lines = wall_time_markdown([run("supv", 3600.0, 72.0), run("active", 5400.0, 102.0),
                                run("active", 6600.0, 122.0, 3), {"detector": {"method": "supv"}}],
                               ["supv", "active"])
    table = [r for r in lines if r.startswith("|")]
    assert table[0] == "| stage | Supv | Active+bd (ours) |"
    assert "| detector (labeling + training, all rounds) | 60.0 | 100.0 ± 14.1 |" in table
    assert "| autoencoder (latent space) | 10.0 | 10.0 ± 0.0 |" in table
    assert not any(r.startswith("| data") for r in table)  # 12 s everywhere
    assert "| **total** | 72.0 | 112.0 ± 14.1 |" in table and "| sittings | 2 | 2.5 ± 0.71 |" in table
    assert wall_time_markdown([{"detector": {"method": "supv"}}], ["supv"]) == []


def test_report_wall_time_takes_the_rounds_record_where_a_killed_sitting_lost_the_detectors_time():
    """neuralcol_s1 (a paper-scale run): sittings killed inside the rounds, before each safe point recorded the
    running stage's time, lost 142 minutes of the detector's
    time from sittings.json while its rounds kept their running totals. The table takes the larger of the two, grows
    the total by the difference and names the run; a run whose sittings hold the time keeps its own figure."""
    from experiments.reporting.markdown import wall_time_markdown

    def run(name, detector_s, minutes, rounds_s):
        return {"_path": f"/runs/{name}", "detector": {"method": "active"},
                "rounds": [{"label_seconds": 10.0, "train_seconds": 20.0, "project_seconds": 0.0},
                           dict(zip(("label_seconds", "train_seconds", "project_seconds"), rounds_s))],
                "sittings": {"n": 1, "minutes": minutes, "stage_seconds": {"detector": detector_s}}}

    lost = run("neuralcol_s1", 3600.0, 70.0, (1200.0, 10800.0, 0.0))     # rounds: 200 min, sittings: 60
    whole = run("neuralcol_s0", 12600.0, 220.0, (1300.0, 11000.0, 60.0))  # rounds 206 min < sittings' 210
    lines = wall_time_markdown([lost, whole], ["active"])
    table = [r for r in lines if r.startswith("|")]
    assert "| detector (labeling + training, all rounds) | 205.0 ± 7.1 |" in table  # 200 and 210
    assert "| **total** | 215.0 ± 7.1 |" in table  # 70 + 140 and 220
    note = " ".join(r for r in lines if not r.startswith("|"))
    assert "1 run(s) (neuralcol_s1)" in note and "neuralcol_s0" not in note


class _SumPool:
    """A stand-in label pool: the 'PD' of a mesh is the sum of its coordinates, every mesh labeled."""

    def label_report(self, vertices, clearance_limit=None):
        from types import SimpleNamespace

        pd = vertices.reshape(len(vertices), -1).sum(1)
        if clearance_limit is not None:
            pd = np.maximum(pd, -clearance_limit)
        return SimpleNamespace(ok=np.ones(len(vertices), bool), labels=SimpleNamespace(pd=pd))


class _ShiftSpace:
    """A latent space whose round trip moves every vertex by 0.5 (codes: the meshes flattened)."""

    dim = 6
    box_lo = torch.zeros(6)

    def encode(self, v):
        return v.reshape(len(v), -1)

    def decode(self, z):
        return z.reshape(len(z), -1, 3) + 0.5


def test_round_trips_on_a_draw_label_only_those_and_agree_with_all():
    from neuralcol.stages.realistic import round_trip_pd, round_trip_rows

    v = torch.as_tensor(np.random.default_rng(0).normal(size=(12, 2, 3)))
    assert round_trip_rows(12, None, 0) is None and round_trip_rows(12, 12, 0) is None
    rows = round_trip_rows(12, 5, 0)
    assert len(rows) == 5 and np.all(np.diff(rows) > 0) and np.array_equal(rows, round_trip_rows(12, 5, 0))
    z_all, pd_all = round_trip_pd(_ShiftSpace(), v, _SumPool())
    z, pd = round_trip_pd(_ShiftSpace(), v, _SumPool(), rows=rows)
    assert torch.equal(z, z_all)  # every mesh still gets its code (the detector reads them all)
    np.testing.assert_allclose(pd[rows], pd_all[rows])
    others = np.setdiff1d(np.arange(12), rows)
    assert np.isnan(pd[others]).all()
    np.testing.assert_allclose(pd_all, v.numpy().reshape(12, -1).sum(1) + 3.0)


def _curl(v: np.ndarray, theta: float, length: float = 2.0) -> np.ndarray:
    """The tube rolled along a circle through ``theta`` radians: past 2 pi its ends pass through each other."""
    r = length / theta
    phi = theta * v[:, 2] / length
    return np.stack([r - (r - v[:, 0]) * np.cos(phi), v[:, 1], (r - v[:, 0]) * np.sin(phi)], -1)


def test_clearance_limited_labels_keep_the_selection_and_every_verdict(tmp_path):
    """label_clearance=clear labels free meshes only up to clear_eps * eps: the same meshes are kept, colliding
    meshes keep their PD bit for bit, free ones read exactly -limit (clear either way)."""
    from neuralcol.collision.labeler import ExactLabeler
    from neuralcol.collision.pool import LabelPool
    from neuralcol.samples.realistic import evaluation_limit, realistic_set

    v0, f = make_tube(n_rings=16, n_around=8)
    poses = np.stack([_curl(v0, a) for a in (0.5, 2.0, 4.0, 5.5)])
    acap = ACAP(poses[0], f)
    feats = acap.encode(torch.as_tensor(poses)).numpy()
    lab = ExactLabeler(f, poses[0], boundary_eps=1e-4)
    cfg = dict(seed=0, n_acap_interp=40, n_vertex_interp=20, n_perturbed=20, t_range=[-0.6, 1.6], perturb_scale=0.8,
               clear_eps=10, per_class=None, label_clearance="clear")
    limit = evaluation_limit(cfg, lab.eps)
    assert limit == 10 * lab.eps
    full, pd_full, _ = realistic_set(poses, feats, acap, [3], LabelPool(lab), cfg, tmp_path, lab.eps)
    fast, pd_fast, cached = realistic_set(poses, feats, acap, [3], LabelPool(lab), cfg, tmp_path, lab.eps,
                                          clearance_limit=limit)
    assert not cached  # its own cache file: the stored PD differs
    assert (pd_full > 0).sum() >= 5 and (pd_full < -limit).sum() >= 5  # both classes are there
    np.testing.assert_array_equal(fast.vertices, full.vertices)
    np.testing.assert_array_equal(pd_fast[pd_full > 0], pd_full[pd_full > 0])
    np.testing.assert_array_equal(pd_fast[pd_full < -limit], -limit)
    assert evaluation_limit({**cfg, "label_clearance": "full"}, lab.eps) is None
    assert evaluation_limit({**cfg, "clear_eps": 0}, lab.eps) is None
    with pytest.raises(Exception, match="realistic.label_clearance='some'"):
        evaluation_limit({**cfg, "label_clearance": "some"}, lab.eps)
