"""Resolving a motion: per-frame corrections that leave every frame free and vary smoothly in time.

Resolving the frames of an animation one by one can pop: two neighbouring frames that collide alike may be freed
by different moves, and a frame that starts to collide gets its whole correction at once. Here the correction of
frame t is ``c_t = out_t - in_t`` (V, 3), and the motion is resolved in two passes:

* **forward, warm-started**: frame t starts from ``in_t + c_{t-1}`` (the previous correction carried over). If
  that mesh collides, the single-mesh resolve (``resolve_one``: the repair, the neural handler) frees it from
  there, so consecutive corrections differ only by what the new frame needs. If it is free, the correction decays
  towards zero by at most ``rate`` per vertex (kept as it was where the decayed one collides).
* **backward, ramped**: where a correction still changes by more than ``rate`` at some vertex between frames t and
  t+1 (a collision's onset, a frame the warm start could not free), ``c_t`` is moved towards ``c_{t+1}`` until the
  change is at most ``rate`` per vertex, kept where that frame stays free; from the last frame to the first, so
  the ramps chain.

Free frames: a frame whose warm start is free and that carries no correction (none before it, or the last one
decayed to exactly 0) is never passed to ``resolve_one`` and comes back bit for bit, so a motion whose frames are all
free comes back unchanged. The free frames within a ramp (the frames after a collision while its correction decays,
and the frames before one while it ramps in, about ``|correction| / rate`` of each) are moved by design: the
correction reaches them gradually so that the motion stays smooth instead of popping at the collision's onset or end.

``rate`` is a length: by default the largest frame-to-frame vertex move of the input itself (the
yardstick: the correction's largest change against the input's), times ``handler.sequence.rate``. Frames the
single-mesh resolve cannot free, and jumps the ramp cannot take without a collision, are reported, not hidden.

Symbols: T frames, V vertices.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np


class SequenceResolution(NamedTuple):
    """:func:`resolve_sequence` of T frames.

    vertices (T, V, 3) float64: the resolved frames. collides (T,) bool: the exact verdict on each. resolved (T,)
    bool: the single-mesh resolve ran on the frame (its warm start collided). correction_jump (T - 1,): the largest
    per-vertex change of the correction between frames t and t+1; input_jump (T - 1,): the input's own. rate: the
    largest change the passes allowed."""

    vertices: np.ndarray
    collides: np.ndarray
    resolved: np.ndarray
    correction_jump: np.ndarray
    input_jump: np.ndarray
    rate: float

    @property
    def jump_ratio(self) -> float:
        """The correction's largest frame-to-frame change over the input's largest (0 for a still input with a
        constant correction; inf if the input is still and the correction moves)."""
        top_c = float(self.correction_jump.max(initial=0.0))
        top_i = float(self.input_jump.max(initial=0.0))
        return top_c / top_i if top_i > 0 else (0.0 if top_c == 0 else np.inf)


def frame_jumps(frames: np.ndarray) -> np.ndarray:
    """(T - 1,) the largest per-vertex distance between consecutive frames (T, V, 3)."""
    f = np.asarray(frames, np.float64)
    return np.linalg.norm(np.diff(f, axis=0), axis=-1).max(-1) if len(f) > 1 else np.zeros(0)


def move_toward(start: np.ndarray, goal: np.ndarray, rate: float) -> np.ndarray:
    """``start`` (V, 3) moved towards ``goal`` by at most ``rate`` per vertex; where the goal is within ``rate`` the
    vertex takes the goal's own values (so a correction decayed towards zero becomes exactly 0, not a round-off
    residue, and the frame it is added to comes back bit for bit)."""
    d = goal - start
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return np.where(n <= rate, goal, start + d * np.minimum(1.0, rate / np.maximum(n, 1e-300)))


def resolve_sequence(frames: np.ndarray, resolve_one: Callable[[np.ndarray], np.ndarray],
                     collides: Callable[[np.ndarray], bool], rate: float,
                     progress: Callable[[int], None] | None = None) -> SequenceResolution:
    """Resolve a motion (module docstring).

    Args:
        frames: (T, V, 3) the input frames, in order.
        resolve_one: a mesh (V, 3) -> the resolved mesh (V, 3) (e.g. ``TrainedRun.resolve`` of one mesh).
        collides: a mesh (V, 3) -> its exact verdict.
        rate: the largest per-vertex change of the correction between frames the passes aim for (> 0).
        progress: called with the frame index after each forward step (None: silent).
    """
    x = np.asarray(frames, np.float64)
    if x.ndim != 3 or x.shape[-1] != 3 or len(x) < 1:
        raise ValueError(f"resolve_sequence: frames have shape {x.shape}, expected (T, V, 3) with T >= 1")
    if not rate > 0:
        raise ValueError(f"resolve_sequence: rate must be > 0, got {rate}")
    t_len = len(x)
    corr = np.zeros_like(x)
    resolved = np.zeros(t_len, bool)
    hit = np.zeros(t_len, bool)
    for t in range(t_len):
        prev = corr[t - 1] if t else np.zeros_like(x[0])
        if collides(x[t] + prev):
            corr[t] = resolve_one(x[t] + prev) - x[t]
            resolved[t] = True
            hit[t] = collides(x[t] + corr[t])
        else:
            decayed = move_toward(prev, np.zeros_like(prev), rate)
            corr[t] = prev if collides(x[t] + decayed) else decayed
        if progress is not None:
            progress(t)
    for t in range(t_len - 2, -1, -1):
        if np.linalg.norm(corr[t + 1] - corr[t], axis=1).max() <= rate:
            continue
        ramp = move_toward(corr[t + 1], corr[t], rate)
        if not collides(x[t] + ramp):
            corr[t] = ramp
            hit[t] = False
    out = x + corr
    return SequenceResolution(out, hit, resolved, frame_jumps(corr), frame_jumps(x), float(rate))
