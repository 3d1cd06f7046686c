"""neuralcol.handler.sequence: a motion resolved with smooth corrections, on a toy where the answer is
known: one vertex sinking through a floor, a resolver that lifts it well above."""

from __future__ import annotations

import numpy as np
import pytest

from neuralcol.handler.sequence import frame_jumps, move_toward, resolve_sequence


def _sinking(n_frames: int = 30, speed: float = 0.1) -> np.ndarray:
    """(T, 4, 3): vertex 0 moves down by ``speed`` a frame from z = 1 (below z = 0 from frame 11 on); the others
    stay."""
    x = np.zeros((n_frames, 4, 3))
    x[:, 1:, 0] = [1.0, 2.0, 3.0]
    x[:, 0, 2] = 1.0 - speed * np.arange(n_frames)
    return x


def _collides(m: np.ndarray) -> bool:
    return bool(m[0, 2] < 0)


def _lift(m: np.ndarray) -> np.ndarray:
    out = m.copy()
    out[0, 2] = max(out[0, 2], 0.5)  # a resolver that overshoots: a jump of 0.5+ where the input moves 0.1
    return out


def test_frames_one_by_one_pop_and_the_sequence_does_not():
    x = _sinking()
    alone = np.stack([_lift(m) if _collides(m) else m for m in x])
    assert frame_jumps(alone - x).max() / frame_jumps(x).max() > 5  # the pop resolve_sequence exists for
    res = resolve_sequence(x, _lift, _collides, rate=frame_jumps(x).max())
    assert not res.collides.any() and not any(_collides(m) for m in res.vertices)
    assert res.correction_jump.max() <= res.rate * (1 + 1e-9)
    assert res.jump_ratio <= 1 + 1e-9
    np.testing.assert_allclose(res.input_jump, frame_jumps(x))
    assert res.resolved.any() and not res.resolved[:10].any()  # the resolver only ran where the warm start collided
    assert (res.vertices[:, 1:] == x[:, 1:]).all()  # vertices no correction needs stay put


def test_a_free_motion_comes_back_unchanged():
    x = _sinking(8)  # z from 1 down to 0.3: never below the floor
    res = resolve_sequence(x, _lift, _collides, rate=0.1)
    np.testing.assert_array_equal(res.vertices, x)
    assert not res.resolved.any() and res.jump_ratio == 0.0


def test_move_toward_caps_each_vertex_and_stops_at_the_goal():
    a = np.zeros((2, 3))
    b = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.5]])
    out = move_toward(a, b, 1.0)
    np.testing.assert_allclose(out, [[0.6, 0.8, 0.0], [0.0, 0.0, 0.5]])


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="expected \\(T, V, 3\\)"):
        resolve_sequence(np.zeros((4, 3)), _lift, _collides, 0.1)
    with pytest.raises(ValueError, match="rate must be > 0"):
        resolve_sequence(_sinking(3), _lift, _collides, 0.0)
