"""Timing statistics shared by the benchmarks: repeated wall-clock measurements and their summaries.

A summary is ``{"median", "min", "max", "reps"}``; ratios are taken between summaries measured in the same run.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence


def repeat(fn: Callable[[], object], reps: int, warmup: int = 1) -> list[float]:
    """Wall-clock seconds of ``reps`` calls of ``fn`` after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def repeat_within(fn: Callable[[], object], reps: int, budget_s: float, warmup: int = 1) -> list[float]:
    """As :func:`repeat`, but no further call starts once the timed calls took ``budget_s`` seconds in all (at
    least one timed call): a bounded measurement when the cost of one call is not known beforehand."""
    for _ in range(warmup):
        fn()
    out: list[float] = []
    while len(out) < max(reps, 1) and (not out or sum(out) < budget_s):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def repeat_interleaved(fn_a: Callable[[], object], fn_b: Callable[[], object],
                       reps: int) -> tuple[list[float], list[float]]:
    """Wall-clock seconds of ``reps`` calls of ``fn_a`` and ``fn_b``, alternating call by call so both see the same
    machine load (warm them up first)."""
    ta, tb = [], []
    for _ in range(reps):
        for fn, out in ((fn_a, ta), (fn_b, tb)):
            t0 = time.perf_counter()
            fn()
            out.append(time.perf_counter() - t0)
    return ta, tb


def per_mesh_times(fn: Callable[[object], object], meshes: Sequence, reps: int) -> list[float]:
    """Seconds per mesh of ``fn`` over all ``meshes`` (a list or an (N, V, 3) array), once per repetition."""
    per_rep = []
    for _ in range(reps):
        t0 = time.perf_counter()
        for v in meshes:
            fn(v)
        per_rep.append((time.perf_counter() - t0) / len(meshes))
    return per_rep


def summarize(values: list[float], scale: float = 1.0) -> dict:
    """Median, min and max of ``values`` times ``scale``, and their count."""
    vals = [v * scale for v in values]
    return {"median": statistics.median(vals), "min": min(vals), "max": max(vals), "reps": len(vals)}


def scalar(x: float) -> dict:
    """A single measured value in the median/min/max form of the other keys."""
    return {"median": float(x), "min": float(x), "max": float(x), "reps": 1}


def ratio(a: dict, b: dict) -> dict:
    """Ratio of two medians measured in the same run (min/max: the ratio of the extremes)."""
    return {"median": a["median"] / b["median"], "min": a["min"] / b["max"], "max": a["max"] / b["min"],
            "reps": min(a["reps"], b["reps"])}
