"""Continue interrupted runs: find the run directory an identical earlier command left unfinished, and keep
two processes out of one run directory.

Hydra gives every run a new timestamped directory, so re-running a command that was killed would start over.
With ``resume=true`` (the default) ``experiments.run`` looks for the newest sibling directory of the new one
(``<...>/<timestamp>`` for a run, ``<sweep root>/<timestamp>/<job number>`` in a multirun) that was started
with the same command-line overrides, has not finished (no ``metrics.json``) and is not in use by a live
process, and continues there; the stages resume from their own checkpoints (autoencoder cache, test set,
D_c and the detector's last finished round).
"""

from __future__ import annotations

from pathlib import Path

from filelock import FileLock, Timeout

from neuralcol.errors import UserInputError
from neuralcol.rundir import RunDir

LOCK_NAME = ".run.lock"


def _overrides(run_dir: Path) -> str | None:
    path = RunDir(run_dir).overrides
    return path.read_text() if path.is_file() else None


def _in_use(run_dir: Path) -> bool:
    lock = FileLock(str(run_dir / LOCK_NAME))
    try:
        lock.acquire(timeout=0)
    except Timeout:
        return True
    lock.release()
    return False


def find_interrupted_run(new_dir: str | Path, multirun: bool = False) -> Path | None:
    """The newest unfinished run directory started with the same overrides as ``new_dir``, or None.

    Args:
        new_dir: the directory Hydra created for this run (holds ``.hydra/overrides.yaml``).
        multirun: ``new_dir`` is a job directory ``<sweep dir>/<job number>``; siblings are the same job
            number in the other sweep directories next to this one.
    """
    new_dir = Path(new_dir).resolve()
    mine = _overrides(new_dir)
    if mine is None:
        return None
    if multirun:
        candidates = [d / new_dir.name for d in new_dir.parent.parent.iterdir() if d != new_dir.parent]
    else:
        candidates = [d for d in new_dir.parent.iterdir() if d != new_dir]
    candidates = [d for d in candidates if d.is_dir() and _overrides(d) == mine
                  and not RunDir(d).is_finished() and not RunDir(d).resumed_in.is_file()]
    for d in sorted(candidates, key=lambda p: p.stat().st_mtime, reverse=True):
        if not _in_use(d):
            return d
    return None


def run_to_resume(new_dir: str | Path, hydra_overrides, resume: bool, multirun: bool = False) -> Path | None:
    """The earlier run directory this invocation continues, or None (it works in ``new_dir``).

    Only with ``resume`` and no explicit ``hydra.run.dir=`` / ``hydra.sweep.dir=`` among ``hydra_overrides`` (an
    explicit directory resumes in place): the newest interrupted run of the same overrides
    (:func:`find_interrupted_run`). ``new_dir`` then records where the run went on (``resumed_in``).
    """
    explicit_dir = any(o.startswith(("hydra.run.dir=", "hydra.sweep.dir=")) for o in hydra_overrides)
    if not resume or explicit_dir:
        return None
    earlier = find_interrupted_run(new_dir, multirun=multirun)
    if earlier is not None:
        RunDir(new_dir).resumed_in.write_text(f"{earlier}\n")
    return earlier


class RunDirLock:
    """Hold ``<run_dir>/.run.lock`` while a run works in ``run_dir`` (released when the process dies, even by
    SIGKILL, since it is an OS file lock)."""

    def __init__(self, run_dir: str | Path):
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self._lock = FileLock(str(self.run_dir / LOCK_NAME))

    def __enter__(self) -> RunDirLock:
        try:
            self._lock.acquire(timeout=0)
        except Timeout:
            raise UserInputError(f"{self.run_dir}: another process is running in this run directory; wait for it "
                                 "to finish or choose another hydra.run.dir") from None
        return self

    def __exit__(self, *exc) -> None:
        self._lock.release()
