"""A collision-free mesh comes back untouched: ``TrainedRun.resolve`` labels each mesh exactly first and returns the
free ones bit for bit (no encoder, handler or repair), ``resolve_sequence`` leaves free frames away from a
correction's ramp as they were, and ``python -m experiments.handle`` writes a free input as given. On the shipped
SCAPE model (pretrained/scape), with meshes decoded from U(Z) codes (the colliding ones the contact repair frees in
a fraction of a second)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

N_CODES = 32  # decoded U(Z) codes, seed 7: free and colliding meshes (indices 0 and 1 collide, 2 is free)


@pytest.fixture(scope="module")
def shipped():
    import neuralcol

    with neuralcol.pretrained("scape", workers=0) as run:
        yield run


@pytest.fixture(scope="module")
def meshes(shipped) -> tuple[np.ndarray, np.ndarray]:
    """(free (n, V, 3), colliding (m, V, 3)) float64 meshes: decoded codes moved by float64 noise (values no float32
    holds), split by the exact label."""
    from neuralcol.samples.uniform import uniform_codes

    v = shipped.decode(uniform_codes(shipped.space, 7, 0, N_CODES)).double().numpy()
    v = v + 1e-9 * shipped.diagonal * np.random.default_rng(0).standard_normal(v.shape)
    pd = shipped.label(v).pd
    assert (pd <= 0).sum() >= 3 and (pd > 0).sum() >= 2
    return v[pd <= 0], v[pd > 0]


def _boom(*args, **kwargs):
    raise AssertionError("a free input reached the encoder or the handler")


def test_a_free_mesh_comes_back_bit_identical(shipped, meshes, monkeypatch):
    import neuralcol.handler.resolve as handler
    import neuralcol.repair.meshes as repair_meshes

    mesh = meshes[0][0]
    monkeypatch.setattr(shipped.space, "encode", _boom)
    monkeypatch.setattr(handler, "handle_codes", _boom)
    monkeypatch.setattr(repair_meshes, "repair_meshes", _boom)
    out = shipped.resolve(mesh)
    assert out.vertices.dtype == torch.float64
    np.testing.assert_array_equal(out.vertices[0].cpu().numpy(), mesh)
    assert out.untouched.tolist() == [True] and out.repaired.tolist() == [False]
    np.testing.assert_array_equal(out.pd_after, out.pd_input)
    assert out.pd_input[0] <= 0 and out.pd_input[0] == shipped.label(mesh).pd[0]
    assert out.displacement_max[0] == 0 and out.displacement_mean[0] == 0 and out.displacement_median[0] == 0
    assert np.isnan(out.margin).all() and np.isnan(out.pd_before).all()
    assert torch.isnan(out.codes).all() and torch.isnan(out.codes_before).all() and torch.isnan(out.decoded).all()
    also = shipped.resolve(mesh, verify=False)  # the exact check comes first with or without verification
    np.testing.assert_array_equal(also.vertices[0].cpu().numpy(), mesh)


def test_a_batch_mixing_free_and_colliding_meshes(shipped, meshes):
    """The free rows come back bit for bit; the colliding ones are resolved as they would be alone."""
    free, hit = meshes
    batch = np.stack([free[0], hit[0], free[1], hit[1]])
    out = shipped.resolve(batch)
    alone = shipped.resolve(hit[:2])
    assert out.untouched.tolist() == [True, False, True, False]
    for row in (0, 2):
        np.testing.assert_array_equal(out.vertices[row].cpu().numpy(), batch[row])
    np.testing.assert_array_equal(out.vertices[[1, 3]].cpu().numpy(), alone.vertices.cpu().numpy())
    np.testing.assert_array_equal(out.pd_after[[1, 3]], alone.pd_after)
    assert (out.pd_input[[1, 3]] > 0).all() and (out.pd_after[[1, 3]] <= 0).all()  # freed
    assert (out.displacement_max[[1, 3]] > 0).all() and (out.displacement_max[[0, 2]] == 0).all()
    assert torch.isfinite(out.codes_before[[1, 3]]).all() and np.isfinite(out.pd_before[[1, 3]]).all()


def test_the_handler_objective_follows_the_colliding_rows(shipped, meshes):
    """Through the neural handler (no verification) with a cartesian objective over all rows: the colliding row's
    targets are its own vertices, whatever free rows stand before it."""
    free, hit = meshes
    kw = {"objective": "cartesian", "verify": False, "subset": [0, 1, 2]}
    out = shipped.resolve(np.stack([free[0], hit[0]]), **kw)
    alone = shipped.resolve(hit[:1], **kw)
    np.testing.assert_array_equal(out.vertices[0].cpu().numpy(), free[0])
    np.testing.assert_allclose(out.vertices[1].cpu().numpy(), alone.vertices[0].cpu().numpy(), rtol=0, atol=1e-9)
    assert out.margin[1] == alone.margin[0] and not out.untouched[1]


def test_scape_free_meshes_come_back_bit_identical(shipped, scape):
    v = scape.vertices.numpy()
    free = shipped.label(v).pd <= 0
    assert free.sum() > len(v) // 2
    out = shipped.resolve(v[free])
    assert out.untouched.all()
    np.testing.assert_array_equal(out.vertices.cpu().numpy(), v[free])


def test_an_all_free_motion_comes_back_bit_identical(shipped, meshes):
    mesh = meshes[0][0]
    step = 1e-3 * shipped.diagonal * np.array([1.0, 0.5, -0.25])
    frames = mesh + np.arange(6)[:, None, None] * step  # a rigid drift: every frame free
    seq = shipped.resolve_sequence(frames, progress=False)
    np.testing.assert_array_equal(seq.vertices, frames)
    assert not seq.resolved.any() and not seq.collides.any()


def test_free_frames_away_from_a_collision_come_back_bit_identical(shipped, meshes):
    """A free pose drifting, one colliding frame in the middle: that frame is freed, the free frames (the
    correction decays to exactly 0 within one frame here: the input's jump dwarfs it) are as they were."""
    free, hit = meshes
    step = 1e-3 * shipped.diagonal * np.array([1.0, 0.5, -0.25])
    frames = free[0] + np.arange(7)[:, None, None] * step
    frames[3] = hit[0]
    seq = shipped.resolve_sequence(frames, progress=False)
    assert seq.resolved.tolist() == [False, False, False, True, False, False, False]
    assert not seq.collides[3] and not np.array_equal(seq.vertices[3], frames[3])
    keep = [0, 1, 2, 4, 5, 6]
    np.testing.assert_array_equal(seq.vertices[keep], frames[keep])


def test_the_handle_command_writes_a_free_mesh_as_given(shipped, meshes, tmp_path, capsys):
    from experiments.handle import main
    from neuralcol import read_mesh, write_mesh

    free, hit = meshes
    write_mesh(tmp_path / "free.obj", free[0], shipped.faces)
    write_mesh(tmp_path / "hit.obj", hit[0], shipped.faces)
    main([str(shipped.run_dir), str(tmp_path / "free.obj"), str(tmp_path / "hit.obj"), "--out", str(tmp_path / "out")])
    rows = {line.split()[0]: line for line in capsys.readouterr().out.strip().splitlines()[1:]}
    assert "untouched" in rows["free"] and "untouched" not in rows["hit"]
    assert (tmp_path / "out" / "free_resolved.obj").read_bytes() == (tmp_path / "free.obj").read_bytes()
    given, _ = read_mesh(tmp_path / "hit.obj")
    resolved, _ = read_mesh(tmp_path / "out" / "hit_resolved.obj")
    assert not np.array_equal(resolved, given)


def test_a_decayed_correction_is_exactly_zero():
    """The pure sequence function: a vertex dips below a floor for two frames. Its lift (0.3) ramps in over the four
    frames before and decays at ``rate`` a frame over the four after (0.23, 0.16, 0.09, 0.02), then is exactly 0:
    the frames outside both ramps come back bit for bit."""
    from neuralcol.handler.sequence import move_toward, resolve_sequence

    x = np.zeros((16, 2, 3))
    x[:, 1, 0] = 1.0 + np.arange(16) / 3.0  # a second vertex in motion, never corrected
    x[:, 0, 2] = [0.6, 0.5, 0.4, 0.3, 0.2, 0.1, -0.1, -0.1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8]

    def lift(m):
        out = m.copy()
        out[0, 2] = 0.2 + 1e-3 / 3
        return out

    seq = resolve_sequence(x, lift, lambda m: bool(m[0, 2] < 0), rate=0.07)
    assert seq.resolved.tolist() == [False] * 6 + [True] + [False] * 9 and not seq.collides.any()
    moved = ~(seq.vertices == x).all(axis=(1, 2))
    assert moved.tolist() == [False] * 2 + [True] * 9 + [False] * 5  # ramp in 2-5, the dip 6-7, decay 8-10
    np.testing.assert_array_equal(seq.vertices[:, 1], x[:, 1])
    c = np.array([[0.0, 0.0, 0.1 + 1e-12]])
    assert (move_toward(c, np.zeros_like(c), 0.2) == 0).all() and (move_toward(c, c / 3, 1.0) == c / 3).all()
