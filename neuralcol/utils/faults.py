"""Fault injection for crash-safety tests: kill this process at a named point.

``NEURALCOL_FAULT="<point>:<n>[,<point>:<n>...]"`` makes the process send itself ``SIGKILL`` the ``n``-th
time it reaches ``<point>`` (counted per process). Points:

* ``label_chunk``: a chunk of meshes has been labeled by the exact-label pool (the parent process).
* ``train_epoch``: a detector training epoch starts (any round, bootstrap or fine-tuning).
* ``store_append``: D_c rows were written to the HDF5 file but not yet committed.

Unset (the normal case) it costs one environment lookup per call. Used by ``tests/test_reliability.py``;
``docs/reliability.md`` lists the faults tried and what happens.
"""

from __future__ import annotations

import os
import signal
from collections import Counter

ENV = "NEURALCOL_FAULT"
POINTS = ("label_chunk", "train_epoch", "store_append")
_reached: Counter = Counter()


def parse_faults(spec: str) -> dict[str, int]:
    """``"label_chunk:2,train_epoch:5"`` -> ``{"label_chunk": 2, "train_epoch": 5}``."""
    faults = {}
    for item in filter(None, (s.strip() for s in spec.split(","))):
        point, _, n = item.partition(":")
        if point not in POINTS or not (n or "1").isdigit() or int(n or 1) < 1:
            raise ValueError(f"{ENV}={spec!r}: {item!r} is not <point>:<n> with point in {POINTS} and n >= 1")
        faults[point] = int(n or 1)
    return faults


def fault_point(name: str) -> None:
    """Count one arrival at ``name``; die by SIGKILL if ``NEURALCOL_FAULT`` asks for this arrival."""
    spec = os.environ.get(ENV)
    if not spec:
        return
    _reached[name] += 1
    if parse_faults(spec).get(name) == _reached[name]:
        print(f"[fault injection] {ENV}: killing process {os.getpid()} at {name} #{_reached[name]}", flush=True)
        os.kill(os.getpid(), getattr(signal, "SIGKILL", signal.SIGTERM))
