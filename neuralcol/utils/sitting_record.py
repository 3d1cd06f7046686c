"""``sittings.json`` of a run directory: one record per invocation of the run (a run of hours is done in sittings,
:mod:`neuralcol.utils.sitting`): when it started, how long each stage took in it, where it stopped (or that it
finished). :meth:`SittingRecord.summary` sums the stages over every sitting for ``metrics.json`` ("sittings")."""

from __future__ import annotations

import datetime as dt
import json
import time
from pathlib import Path

from neuralcol.utils.files import write_json_atomic


class SittingRecord:
    """Appends this invocation's record to ``path`` (created if missing) and keeps it up to date stage by stage,
    so a sitting killed from outside still leaves its finished stages' times."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.records = self._read()
        self.t0 = time.monotonic()
        self.current = {"started": dt.datetime.now().isoformat(timespec="seconds"), "stages": {},
                        "minutes": 0.0, "stopped_at": None, "finished": False}
        self.records.append(self.current)
        self._running_t0 = self._last_write = self.t0
        self._write()

    def _read(self) -> list[dict]:
        if not self.path.is_file():
            return []
        try:
            data = json.loads(self.path.read_text())
        except (OSError, ValueError):
            return []  # an unreadable record is only bookkeeping: start a new one
        return data.get("sittings", []) if isinstance(data, dict) else []

    def _write(self) -> None:
        self.current["minutes"] = round((time.monotonic() - self.t0) / 60.0, 3)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(self.path, {"sittings": self.records})

    def begin(self, name: str) -> None:
        """Stage ``name`` starts: until :meth:`stage` records it, :meth:`progress` keeps its time so far in the
        record's ``running`` entry (a sitting killed from outside mid-stage, e.g. at a session's end, keeps it)."""
        self._running_t0 = self._last_write = time.monotonic()
        self.current["running"] = {"stage": name, "seconds": 0.0}

    def progress(self, every_s: float = 30.0) -> None:
        """The running stage's time so far into the record, written at most every ``every_s`` seconds (called at
        each safe point, :func:`neuralcol.utils.sitting.on_check`)."""
        running = self.current.get("running")
        now = time.monotonic()
        if running is None or now - self._last_write < every_s:
            return
        running["seconds"] = round(now - self._running_t0, 3)
        self._last_write = now
        self._write()

    def stage(self, name: str, seconds: float) -> None:
        """A stage finished in this sitting after ``seconds`` of wall time."""
        self.current.pop("running", None)
        self.current["stages"][name] = round(self.current["stages"].get(name, 0.0) + float(seconds), 3)
        self._write()

    def close(self, stopped_at: str | None = None) -> None:
        """This sitting ends: stopped at ``stopped_at`` (its time budget), or finished (None)."""
        self.current.pop("running", None)
        self.current["stopped_at"] = stopped_at
        self.current["finished"] = stopped_at is None
        self._write()

    def summary(self) -> dict:
        """``{"n": sittings, "minutes": total, "stage_seconds": {stage: seconds over every sitting}}``. A stage
        that ran again after a stop (it had no safe point inside) counts every time it ran; a sitting killed
        mid-stage counts that stage up to its last safe point (its ``running`` entry)."""
        total: dict[str, float] = {}
        for r in self.records:
            running = r.get("running") or {}
            parts = list(r.get("stages", {}).items()) + ([(running["stage"], running.get("seconds", 0.0))]
                                                         if running.get("stage") else [])
            for k, v in parts:
                total[k] = round(total.get(k, 0.0) + float(v), 3)
        return {"n": len(self.records), "minutes": round(sum(float(r.get("minutes", 0.0)) for r in self.records), 3),
                "stage_seconds": total}
