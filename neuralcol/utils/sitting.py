"""Runs longer than a sitting: a time budget per invocation (``max_minutes``), checked at safe points.

A paper-scale run takes many hours on two cores; a session lasts at most three. ``python -m experiments.run ...
max_minutes=150`` starts a clock; at every safe point (before each stage of the pipeline, after each committed
batch of labels, after each finished round of the detector and at each checkpoint inside a round
(``detector.checkpoint_minutes``), the checkpoint saved first) the code calls
:func:`check`, which raises :class:`SittingOver` once the budget is spent. Everything done so far is on disk, so
rerunning the same command goes on where this sitting stopped (``resume: true``, ``neuralcol/utils/resume.py``).
Work between two safe points is not interrupted: a sitting can overrun its budget by one batch of labels, the
minutes between two checkpoints of a round's training or one stage that has no safe point inside (e.g. the
handler's evaluation).

The budget is process-wide (one run per process): :func:`start` sets it, :func:`stop` clears it. Without a
budget :func:`check` never raises.
"""

from __future__ import annotations

import contextlib
import os
import time

STOP_AT_ENV = "NEURALCOL_SITTING_STOP_AT"
EXIT_CODE = 75  # EX_TEMPFAIL: "try again"; a shell loop can rerun the command until it exits 0


class SittingOver(Exception):
    """The sitting's time budget is spent; raised at a safe point (everything before it is saved)."""

    def __init__(self, where: str, minutes: float, budget: float):
        self.where, self.minutes, self.budget = where, float(minutes), float(budget)
        super().__init__(f"stopped at {where} after {minutes:.1f} min (max_minutes={budget:g}); everything up to "
                         "here is saved: rerun the same command to go on")


_state: dict = {"t0": None, "budget": None, "held": 0, "on_check": None}


def start(max_minutes: float | None) -> None:
    """Start this process's sitting clock with a budget of ``max_minutes`` (None or <= 0: no budget)."""
    budget = None if max_minutes is None or float(max_minutes) <= 0 else float(max_minutes)
    _state.update(t0=time.monotonic(), budget=budget)


def stop() -> None:
    """No budget any more (the run is over, or a test is); no :func:`on_check` callback either."""
    _state.update(t0=None, budget=None, on_check=None)


def on_check(fn) -> None:
    """Call ``fn()`` (no arguments) at every :func:`check`, held or not, until :func:`stop`."""
    _state["on_check"] = fn


def minutes() -> float:
    """Minutes since :func:`start` (0 without a clock)."""
    return 0.0 if _state["t0"] is None else (time.monotonic() - _state["t0"]) / 60.0


def over() -> bool:
    """True once the budget is spent."""
    return _state["budget"] is not None and minutes() >= _state["budget"]


def check(where: str) -> None:
    """Raise :class:`SittingOver` naming ``where`` if the budget is spent; call only where stopping loses nothing.
    Inside :func:`held` it never raises. Tests stop a run at a chosen safe point, whatever the clock, with
    ``NEURALCOL_SITTING_STOP_AT=<text>`` (the first safe point whose ``where`` contains it; cf. ``NEURALCOL_FAULT``)."""
    if _state["on_check"] is not None:  # e.g. SittingRecord.progress: a killed sitting keeps its stage's time
        _state["on_check"]()
    if _state["held"]:
        return
    forced = os.environ.get(STOP_AT_ENV)
    if over() or (forced and forced in where):
        raise SittingOver(where, minutes(), _state["budget"] or 0.0)


@contextlib.contextmanager
def held():
    """No stop inside (work whose result is only saved at its end, e.g. a round's acquisition, whose labels the
    round's checkpoint records: stopping inside would lose the round's training)."""
    _state["held"] += 1
    try:
        yield
    finally:
        _state["held"] -= 1
