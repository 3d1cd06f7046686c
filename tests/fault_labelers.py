"""An exact labeler with injected faults, and the two-spheres meshes, for the LabelPool fault tests
(tests/test_pool_faults.py, tests/test_pool_dask.py).

A module of its own (not the test file) so the pool's spawned worker processes can unpickle the labeler by
importing it (``tests/`` is on ``sys.path`` under pytest, and spawn passes ``sys.path`` to the children).

The fault is chosen by the first vertex's x coordinate: a sentinel far outside any test mesh.
"""

from __future__ import annotations

import os
import time

import numpy as np

from neuralcol.collision.labeler import ExactLabeler, Label

RAISE = 1001.0  # label() raises ValueError (a degenerate mesh)
EXIT = 1002.0  # the process dies with os._exit(3) (never use in this process: workers >= 2 only)
HANG = 1003.0  # label() sleeps "forever" (workers >= 2 with a timeout only)
NAN = 1004.0  # label() returns a NaN PD
FLAKY = 1005.0  # label() raises the first time it sees such a mesh in this process, then labels it
EXIT_ONCE = 1006.0  # the process dies with os._exit(3) the first time any process sees such a mesh (needs
                    # FaultLabeler.marker: a file path, created by the process that dies), then labels it
SLOW = 1007.0  # label() computes for SLOW_S seconds of CPU time, then labels (slow but not hung; a stopped
               # process does not advance it, as it does a sleep)
SLOW_S = 1.5

_seen_flaky: set[bytes] = set()


def mark(vertices: np.ndarray, sentinel: float) -> np.ndarray:
    """A copy of one mesh (V, 3) whose first vertex carries ``sentinel``."""
    v = np.array(vertices, dtype=np.float64)
    v[0, 0] = sentinel
    return v


class FaultLabeler(ExactLabeler):
    """:class:`ExactLabeler` that misbehaves on meshes marked with :func:`mark`."""

    marker: str | None = None  # EXIT_ONCE: file that records that a process died on such a mesh

    def label(self, vertices) -> Label:
        v = np.asarray(vertices)
        x = float(v[0, 0])
        if x == RAISE:
            raise ValueError("degenerate mesh (injected fault)")
        if x == EXIT:
            os._exit(3)
        if x == EXIT_ONCE:
            if self.marker is None:
                raise RuntimeError("FaultLabeler.marker is not set (needed by EXIT_ONCE)")
            try:
                fd = os.open(self.marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)  # atomic: one process only
            except FileExistsError:
                pass
            else:
                os.close(fd)
                os._exit(3)
        if x == HANG:
            time.sleep(1e6)
        if x == SLOW:
            t0 = time.process_time()
            while time.process_time() - t0 < SLOW_S:
                pass
        if x == NAN:
            lb = super().label(v)
            return Label(lb.collides, lb.n_pairs, float("nan"), lb.pd_sub)
        if x == FLAKY:
            key = v.tobytes()
            if key not in _seen_flaky:
                _seen_flaky.add(key)
                raise RuntimeError("transient failure (injected fault)")
        return super().label(v)


def two_spheres(offset: float, subdivisions: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Two unit icospheres (subdivisions=1: 42 vertices each), the second shifted by ``offset`` along x."""
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions)
    v, f = np.asarray(s.vertices, np.float64), np.asarray(s.faces, np.int64)
    return np.concatenate([v, v + [offset, 0.0, 0.0]]), np.concatenate([f, f + len(v)])


class SphereDecoder:
    """A stand-in decoder for ``LabelPool.label_codes_report``: code (offset, m) -> two spheres ``offset`` apart,
    NaN vertices when m > 2.4, the RAISE sentinel when m > 2.7; ``shift`` is added to every offset."""

    def __init__(self, shift: float = 0.0):
        self.shift = float(shift)

    def __call__(self, codes: np.ndarray) -> np.ndarray:
        out = []
        for offset, m in np.asarray(codes, np.float64):
            v = two_spheres(offset + self.shift)[0]
            if m > 2.7:
                v = mark(v, RAISE)
            elif m > 2.4:
                v[3] = np.nan
            out.append(v)
        return np.stack(out) if out else np.zeros((0, 2 * 162, 3))
