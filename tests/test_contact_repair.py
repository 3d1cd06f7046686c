"""Contact repair: the push on analytic triangle pairs, two spheres pushed into each other repaired by
the exact labeler's contacts with the far side left in place, the iteration cap and the step cap."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from neuralcol.collision.labeler import ExactLabeler
from neuralcol.repair.contact import contact_push, diffusion_operator, outward_sign, repair_contacts
from neuralcol.repair.meshes import repair_meshes
from neuralcol.repair.settings import RepairSettings, repair_settings


def two_spheres(overlap: float, subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two unit spheres along x whose centres are 2 - overlap apart (overlap > 0: they intersect); also the
    rest pose (1 apart from touching)."""
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    v, f = np.asarray(s.vertices, np.float64), np.asarray(s.faces, np.int64)
    faces = np.concatenate([f, f + len(v)])

    def place(gap):
        return np.concatenate([v, v + np.array([2.0 + gap, 0.0, 0.0])])

    return place(-overlap), faces, place(1.0)


def test_outward_sign_closed_flipped_and_open():
    s = trimesh.creation.icosphere(subdivisions=1)
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    assert outward_sign(f, v) == 1.0
    assert outward_sign(f[:, ::-1], v) == -1.0
    assert outward_sign(f[1:], v) == 0.0


def test_push_of_a_triangle_through_another_plane():
    """Triangle a has one vertex 0.1 below triangle b's plane (z = 0, normal +z on a closed mesh's outside) and
    two 0.2 above it: only the low vertex is pushed, by half of delta - s along +z; b's vertices are pushed
    along a's normal by half of their own shortfall."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],               # b: z = 0, normal +z
                  [0.2, 0.2, -0.1], [0.3, 0.2, 0.2], [0.2, 0.3, 0.2]], float)  # a
    f = np.array([[0, 1, 2], [3, 4, 5]])
    delta = 0.05
    push = contact_push(v, f, np.array([[1, 0]]), delta, sign=1.0)
    np.testing.assert_allclose(push[3], [0, 0, 0.5 * (delta + 0.1)], atol=1e-12)
    np.testing.assert_allclose(push[4:6], 0.0, atol=1e-12)
    # b against a's plane: the outward normal of a, times half of each of b's vertices' shortfall
    ta = v[3:]
    n = np.cross(ta[1] - ta[0], ta[2] - ta[0])
    n /= np.linalg.norm(n)
    s = (v[:3] - ta[0]) @ n
    need = np.maximum(delta - s, 0)
    np.testing.assert_allclose(push[:3], 0.5 * need[:, None] * n[None], atol=1e-12)
    # an open mesh (sign 0): the side of b holding most of a is the target side, the same here
    np.testing.assert_allclose(contact_push(v, f, np.array([[1, 0]]), delta, sign=0.0)[3], push[3], atol=1e-12)
    assert not contact_push(v, f, np.zeros((0, 2), int), delta, 1.0).any()


def test_two_spheres_pushed_into_each_other_are_repaired_locally():
    v, f, rest = two_spheres(0.06)
    lab = ExactLabeler(f, rest)
    assert lab.label(v).collides
    r = repair_contacts(v, f, lab, delta=3 * lab.eps, smooth_steps=4, max_iter=60)
    assert r.resolved and r.iterations >= 1 and r.pairs_per_iteration[-1] == 0
    assert not lab.label(r.vertices).collides
    moved = np.linalg.norm(r.vertices - v, axis=1)
    n = len(v) // 2
    # the far halves of both spheres stay exactly where they were; the contact region moved by about the overlap
    far = np.concatenate([v[:n, 0] < -0.5, v[n:, 0] > 2.44])
    assert moved[far].max() == 0.0
    assert 0.01 < moved.max() < 0.2
    # a mesh without intersections comes back unchanged, after one question to the labeler
    free = repair_contacts(rest, f, lab, delta=3 * lab.eps)
    assert free.resolved and free.iterations == 0 and np.array_equal(free.vertices, rest)


class StuckLabeler:
    """Always reports the same pair: the repair must stop at max_iter, never moving a vertex more than
    max_step per iteration."""

    def __init__(self, pair):
        self.pair, self.calls = np.asarray(pair).reshape(1, 2), 0

    def intersecting_pairs(self, vertices):
        self.calls += 1
        return self.pair


def test_iteration_and_step_caps():
    v, f, _ = two_spheres(0.06, subdivisions=1)
    lab = StuckLabeler([0, len(f) // 2])
    r = repair_contacts(v, f, lab, delta=0.5, smooth_steps=2, max_iter=5, max_step=0.01)
    assert not r.resolved and r.iterations == 5 and lab.calls == 6
    assert np.linalg.norm(r.vertices - v, axis=1).max() <= 5 * 0.01 + 1e-12
    with pytest.raises(ValueError, match="delta"):
        repair_contacts(v, f, lab, delta=0.0)
    with pytest.raises(ValueError, match=r"\(V, 3\)"):
        repair_contacts(v[None], f, lab, delta=0.1)


def test_diffusion_operator_is_symmetric_and_spreads_one_ring_per_step():
    v, f, _ = two_spheres(0.0, subdivisions=1)
    w = diffusion_operator(f, len(v))
    assert abs(w - w.T).max() < 1e-15
    x = np.zeros(len(v))
    x[0] = 1.0
    ring = set(f[(f == 0).any(1)].ravel())
    assert set(np.flatnonzero(w @ x)) == ring


def test_settings_and_batch():
    assert repair_settings(None) is None
    assert repair_settings({"enabled": False}) is None
    assert repair_settings({"delta": 2.0}) == RepairSettings(delta=2.0)
    with pytest.raises(ValueError, match="unknown keys"):
        repair_settings({"deltta": 2.0})
    with pytest.raises(ValueError, match="delta > 0"):
        RepairSettings(delta=-1.0)
    v, f, rest = two_spheres(0.06)
    lab = ExactLabeler(f, rest)
    diag = float(np.linalg.norm(np.ptp(rest, axis=0)))
    out, ok, its = repair_meshes(np.stack([v, rest]), f, lab, RepairSettings(smooth_steps=4), lab.eps, diag,
                                 outward_sign(f, rest))
    assert ok.tolist() == [True, True] and its[1] == 0 and np.array_equal(out[1], rest)
    assert not lab.label(out[0]).collides


def test_shrink_corrections_bisects_to_the_smallest_freeing_share():
    """Analytic: the repair (identity here) frees mesh k exactly when its share of the correction is >= t_k."""
    from neuralcol.handler.resolve import shrink_corrections

    t = np.array([0.3, 0.9, 0.05])
    x = np.zeros((3, 4, 3))
    result = np.ones((3, 4, 3))
    calls = []

    def repaired(m):
        calls.append(len(m))
        share = m[:, 0, 0]  # x + s * (result - x) = s everywhere
        return m, np.where(share >= t, -1.0, 0.5)

    kept, pd, s = shrink_corrections(x, result, repaired, steps=5)
    assert calls == [3] * 5  # one batched repair per step
    assert (s >= t).all() and (s - t < 1 / 32 + 1e-12).all()
    np.testing.assert_allclose(kept, s[:, None, None] * result)
    assert (pd == -1.0).all()
    # a repair that moves more than the whole correction is not kept; nothing is tried without steps
    kept, pd, s = shrink_corrections(x, result, lambda m: (m + 5.0, np.full(len(m), -1.0)), steps=3)
    np.testing.assert_array_equal(kept, result)
    assert (s == 1.0).all() and np.isnan(pd).all()
    kept, pd, s = shrink_corrections(x, result, repaired, steps=0)
    assert (s == 1.0).all() and np.array_equal(kept, result)
    with pytest.raises(ValueError, match="shrink_steps"):
        RepairSettings(shrink_steps=-1)


def test_shrink_corrections_on_two_spheres():
    """Two spheres pushed deep into each other, the 'correction' moving one of them far away: a fraction of it
    and the contact repair free them, moving far less; the last share bisection rejected does not."""
    from neuralcol.handler.resolve import shrink_corrections

    v, f, rest = two_spheres(0.3)
    lab = ExactLabeler(f, rest)
    diag = float(np.linalg.norm(np.ptp(rest, axis=0)))
    settings = RepairSettings(method="contact", smooth_steps=4, max_iter=5)  # too few iterations for the input
    n = len(v) // 2
    result = v.copy()
    result[n:, 0] += 1.0  # far apart: free
    assert lab.label(v).collides and not lab.label(result).collides

    def repaired(m):
        out, _, _ = repair_meshes(m, f, lab, settings, lab.eps, diag, outward_sign(f, rest))
        return out, np.array([lab.label(o).pd for o in out])

    assert repaired(v[None])[1][0] > 0
    kept, pd, s = shrink_corrections(v[None], result[None], repaired, steps=5)
    assert 1 / 32 < s[0] < 1 and pd[0] <= 0 and not lab.label(kept[0]).collides
    assert np.linalg.norm(kept[0] - v, axis=1).max() < 0.5
    _, pd_lo = repaired((v + (s[0] - 1 / 32) * (result - v))[None])
    assert pd_lo[0] > 0


def test_cap_displacements_clips_the_largest_moves_to_the_smallest_free_cap():
    """Analytic: moves 1, 2, 4 along x; the label frees the mesh when vertex 0 moved >= 0.8, i.e. cap c >= 0.2."""
    from neuralcol.repair.cap import cap_displacements

    x = np.zeros((2, 3, 3))
    result = np.zeros((2, 3, 3))
    result[:, :, 0] = [1.0, 2.0, 4.0]
    result[1, 2, 1] = 1.0  # the second also moves vertex 2 sideways: never free below the full result

    def label(m):
        return np.where((m[:, 0, 0] >= 0.8 - 1e-12) & (m[:, 2, 1] == 0), -1.0, 0.3)

    kept, pd, c = cap_displacements(x, result, label, steps=6)
    assert 0.2 <= c[0] < 0.2 + 1 / 64 and pd[0] == -1.0
    np.testing.assert_allclose(kept[0, :, 0], np.minimum([1.0, 2.0, 4.0], 4 * c[0]))
    np.testing.assert_array_equal(kept[0, :, 1:], 0.0)
    assert np.array_equal(kept[1], result[1])
    assert c[1] == 1.0 and np.isnan(pd[1]) and np.array_equal(kept[1], result[1])
    kept, pd, c = cap_displacements(x, result, label, steps=0)
    assert (c == 1.0).all() and np.array_equal(kept, result)
    # the bisection on the verdict, the full label only for what is kept: the same caps, one label call
    calls = []

    def counted(m):
        calls.append(len(m))
        return label(m)

    kept2, pd2, c2 = cap_displacements(x, result, counted, 6, collides=lambda m: label(m) > 0)
    np.testing.assert_array_equal(c2, [cap0 := cap_displacements(x, result, label, 6)[2][0], 1.0])
    assert calls == [1] and pd2[0] == -1.0 and np.isnan(pd2[1]) and cap0 < 1
    # a verdict the full label contradicts: the capped mesh is dropped, the result kept
    kept3, pd3, c3 = cap_displacements(x, result, lambda m: np.full(len(m), 0.3), 6,
                                       collides=lambda m: np.zeros(len(m), bool))
    assert (c3 == 1.0).all() and np.isnan(pd3).all() and np.array_equal(kept3, result)
    with pytest.raises(ValueError, match="cap_steps"):
        RepairSettings(cap_steps=-2)
    with pytest.raises(ValueError, match="whole number"):
        RepairSettings(cap_steps="6")


def test_edge_strain():
    from neuralcol.handler.resolve import edge_strain

    v, f, _ = two_spheres(0.0, subdivisions=1)
    from neuralcol.geometry.topology import edge_topology

    e = edge_topology(f).edges
    lengths = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    np.testing.assert_allclose(edge_strain(v[None], 1.1 * v[None], f), [0.1 * lengths.max() / lengths.mean()])
    w = v + 0.3  # a translation strains nothing
    assert edge_strain(v[None], w[None], f)[0] < 1e-12


def test_retry_runs_only_where_the_repairs_fail_and_is_kept_only_where_it_frees():
    v, f, rest = two_spheres(0.06, subdivisions=2)
    lab = ExactLabeler(f, rest)
    diag = float(np.linalg.norm(np.ptp(rest, axis=0)))
    stalled = {"max_iter": 0, "extra_iter": 0}  # an untangle that gives up at once

    def run(retry, untangle=stalled):
        s = RepairSettings(method="untangle", untangle=untangle, retry=retry)
        return repair_meshes(np.stack([v, rest]), f, lab, s, lab.eps, diag, outward_sign(f, rest))

    out0, ok0, _ = run(None)
    assert ok0.tolist() == [False, True] and np.array_equal(out0[0], v)
    out1, ok1, its1 = run({"max_iter": 80})  # the retry frees the colliding one; the free one is never retried
    assert ok1.tolist() == [True, True] and its1[0] > 0 and its1[1] == 0 and np.array_equal(out1[1], rest)
    assert not lab.label(out1[0]).collides
    out2, ok2, _ = run({"anchor": 0.5})  # a retry that fails too leaves the earlier result as it was
    assert ok2.tolist() == [False, True] and np.array_equal(out2[0], out0[0])
    out3, ok3, _ = run({"max_iter": 0}, untangle=None)  # the repairs free it: the retry never runs
    assert ok3[0] and np.array_equal(out3[0], run(None, untangle=None)[0][0])
    with pytest.raises(ValueError, match="retry"):
        RepairSettings(retry={"ancor": 0.01})


def test_repair_package_numpy_in_numpy_out():
    """neuralcol.repair.repair on a batch of a free and a colliding pair of spheres: the free one comes back bit for
    bit, the colliding one free (also for a second labeler built on another mesh, so at another scale); the moves
    and their ratio to the input's depth are the returned vertices' own."""
    from neuralcol.repair import Repaired, repair

    hit, faces, rest = two_spheres(0.08, subdivisions=2)
    free = rest.copy()
    batch = np.stack([free, hit])
    lab = ExactLabeler(faces, rest)
    out = repair(batch, faces, lab, rest=rest)
    assert isinstance(out, Repaired) and isinstance(out.vertices, np.ndarray) and out.vertices.dtype == np.float64
    np.testing.assert_array_equal(out.vertices[0], free)
    assert out.untouched.tolist() == [True, False] and out.repaired.tolist() == [False, True]
    assert out.freed.tolist() == [True, True] and out.pd_input[1] > 0
    assert not ExactLabeler(faces, hit).verdict(out.vertices[1])  # another labeler (other scale) agrees
    moves = np.linalg.norm(out.vertices - batch, axis=2)
    np.testing.assert_allclose(out.largest_move, moves.max(1))
    np.testing.assert_allclose(out.median_move, np.median(moves, 1))
    assert np.isnan(out.move_to_depth[0])
    assert out.move_to_depth[1] == pytest.approx(moves[1].max() / out.pd_input[1])


def test_repair_of_a_large_mesh_counts_its_exact_checks(monkeypatch):
    """With progress, a mesh of LARGE_FACES faces or more gets a bar counting the exact checks; the result is the
    same as without it."""
    from fault_labelers import two_spheres

    import neuralcol.repair.meshes as meshes
    from neuralcol.collision.labeler import ExactLabeler

    v, f = two_spheres(1.7, subdivisions=2)
    lab = ExactLabeler(f, v, clearance=False)
    plain = meshes.repair(v[None], f, lab)
    counts = []

    class Bar:
        def __init__(self, **kw):
            self.n = 0

        def __enter__(self):
            return self

        def __exit__(self, *a):
            counts.append(self.n)

        def update(self, k):
            self.n += k

        def set_postfix_str(self, *a, **kw):
            pass

    monkeypatch.setattr(meshes, "LARGE_FACES", len(f))
    monkeypatch.setattr("neuralcol.utils.progress.progress_bar",
                        lambda iterable=None, **kw: iterable if iterable is not None else Bar(**kw))
    counted = meshes.repair(v[None], f, lab, progress=True)
    np.testing.assert_array_equal(counted.vertices, plain.vertices)
    assert counts and counts[0] >= 3, "every exact check counted (the input's label, the repair's, the result's)"


def test_move_to_depth_is_not_given_for_depths_at_round_off():
    from neuralcol.repair.cap import move_to_depth

    out = move_to_depth([0.5, 0.5, 0.5, 0.0], [0.25, 1e-12, -0.1, 0.0], diagonal=10.0)
    assert out[0] == 2.0 and np.isnan(out[1:]).all()
