"""Progress reports that suit where they go: bars on a terminal, lines in a log file.

On a terminal (or in a Jupyter kernel) loops show tqdm bars and Lightning trainers their progress bar, as before.
Off a terminal (``python -m experiments.run > log.txt 2>&1``, SLURM, CI) a redrawn bar fills the file with
``\\r`` redraws, so the same loops write newline-terminated lines instead:

- a library loop (:func:`progress_bar`, a tqdm stand-in, on stderr like tqdm): a line every
  ``NEURALCOL_PROGRESS_INTERVAL`` seconds (count, rate, ETA) and one when it ends; a loop shorter than
  :data:`QUIET_S` writes nothing;
- a Lightning training (:func:`trainer_progress`, on stdout like Lightning's bar): no bar; a line with the logged
  losses at every tenth of the epochs and at least every interval.

The choice, from the environment (unset: ``bar`` when the stream the bar would draw on is a terminal, else
``lines``)::

    NEURALCOL_PROGRESS=bar|lines|off|auto   # off: neither bars nor lines
    NEURALCOL_PROGRESS_INTERVAL=30          # seconds between two lines of one loop or training

Lightning is imported only by :func:`epoch_lines` (the labeler's pool uses this module without torch).
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Mapping

from neuralcol.errors import UserInputError

MODE_ENV = "NEURALCOL_PROGRESS"
INTERVAL_ENV = "NEURALCOL_PROGRESS_INTERVAL"
MODES = ("bar", "lines", "off")
DEFAULT_INTERVAL_S = 30.0
QUIET_S = 2.0  # lines mode: a loop that ends sooner writes no line
EPOCH_MARKS = 10  # lines mode: a training writes a line at every 1/EPOCH_MARKS of its epochs
MAX_METRICS = 6  # loss values shown on an epoch line

Clock = Callable[[], float]


def progress_mode(stream=None) -> str:
    """``bar``, ``lines`` or ``off``: ``NEURALCOL_PROGRESS`` if set, else ``bar`` when ``stream`` (default
    ``sys.stderr``, where tqdm draws) is a terminal or a Jupyter kernel's stream, else ``lines``.

    Raises:
        UserInputError: ``NEURALCOL_PROGRESS`` holds another value.
    """
    value = os.environ.get(MODE_ENV, "").strip().lower()
    if value and value != "auto":
        if value not in MODES:
            raise UserInputError(f"{MODE_ENV}={value!r} is not a progress mode; set it to bar, lines or off, or "
                                 "unset it (bars on a terminal, lines otherwise)")
        return value
    return "bar" if _interactive(sys.stderr if stream is None else stream) else "lines"


def _interactive(stream) -> bool:
    """True for a terminal and for a Jupyter kernel's output stream (tqdm.auto draws a widget there)."""
    try:
        tty = bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed file
        tty = False
    return tty or type(stream).__module__.startswith("ipykernel")


def progress_interval() -> float:
    """Seconds between two progress lines of one loop: ``NEURALCOL_PROGRESS_INTERVAL``, default 30.

    Raises:
        UserInputError: the variable is not a positive number.
    """
    value = os.environ.get(INTERVAL_ENV, "").strip()
    if not value:
        return DEFAULT_INTERVAL_S
    try:
        seconds = float(value)
    except ValueError:
        seconds = float("nan")
    if not seconds > 0 or math.isinf(seconds):
        raise UserInputError(f"{INTERVAL_ENV}={value!r} is not a number of seconds; set a positive number "
                             f"(default {DEFAULT_INTERVAL_S:g}) or unset it")
    return seconds


def format_duration(seconds: float) -> str:
    """``seconds`` as ``M:SS`` or ``H:MM:SS``; ``?`` when unknown (NaN or infinite)."""
    if not math.isfinite(seconds):
        return "?"
    m, s = divmod(int(round(max(seconds, 0.0))), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def format_rate(count: float, seconds: float, unit: str) -> str:
    """``count`` items in ``seconds`` as ``12.3 mesh/s`` or, below one per second, ``4.5 s/mesh``."""
    if count <= 0 or seconds <= 0:
        return f"? {unit}/s"
    rate = count / seconds
    return f"{rate:.3g} {unit}/s" if rate >= 1 else f"{1 / rate:.3g} s/{unit}"


def _write_line(stream, line: str) -> None:
    """One newline-terminated line on ``stream``, flushed."""
    stream.write(line.replace("\r", " ") + "\n")
    stream.flush()


class LineProgress:
    """The part of tqdm's interface the library loops use (iterate, ``update``, ``close``, ``with``), writing
    newline-terminated lines: one per ``interval_s`` at most while it runs, one when it closes (unless it ran
    shorter than ``quiet_s`` and wrote nothing before).

    Args:
        iterable: items to yield (optional; without it, call :meth:`update`).
        total: number of items (default ``len(iterable)`` where defined).
        desc: what is counted, the line's prefix. unit: the item's name (``mesh``).
        interval_s: seconds between two lines (default :func:`progress_interval`).
        quiet_s: a loop closed sooner than this, with no line written yet, writes nothing.
        stream: where lines go (default: ``sys.stderr`` at the time of writing). clock: seconds, monotonic.
    """

    def __init__(self, iterable: Iterable | None = None, total: int | None = None, desc: str = "", unit: str = "it",
                 interval_s: float | None = None, quiet_s: float = QUIET_S, stream=None,
                 clock: Clock = time.monotonic):
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)
        self.iterable, self.total, self.desc, self.unit = iterable, total, desc, unit
        self.interval_s = progress_interval() if interval_s is None else float(interval_s)
        self.quiet_s, self.stream, self.clock = float(quiet_s), stream, clock
        self.n, self.lines_written, self.closed = 0, 0, False
        self._t0 = self._last = clock()

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __iter__(self):
        if self.iterable is None:
            raise TypeError("LineProgress without an iterable: call update() instead of iterating")
        try:
            for item in self.iterable:
                yield item
                self.update(1)
        finally:
            self.close()

    def __len__(self) -> int:
        return int(self.total or 0)

    def update(self, n: int = 1) -> None:
        """Count ``n`` more items; write a line when ``interval_s`` has passed since the last one."""
        self.n += n
        now = self.clock()
        if now - self._last >= self.interval_s:
            self._emit(self._running_line(now - self._t0))
            self._last = now

    def close(self) -> None:
        """Write the last line (count, time, rate), unless the loop was quiet and short; idempotent."""
        if self.closed:
            return
        self.closed = True
        elapsed = self.clock() - self._t0
        if self.lines_written or elapsed >= self.quiet_s:
            self._emit(self._final_line(elapsed))

    def _prefix(self) -> str:
        return f"{self.desc}: " if self.desc else ""

    def _count(self) -> str:
        return f"{self.n}/{self.total} {self.unit}" if self.total else f"{self.n} {self.unit}"

    def _running_line(self, elapsed: float) -> str:
        rate = format_rate(self.n, elapsed, self.unit)
        if not self.total:
            return f"{self._prefix()}{self._count()}, {rate}, {format_duration(elapsed)} elapsed"
        eta = (self.total - self.n) * elapsed / self.n if self.n else float("nan")
        return (f"{self._prefix()}{self._count()} ({100 * self.n / self.total:.0f}%), {rate}, "
                f"{format_duration(elapsed)} elapsed, ETA {format_duration(eta)}")

    def _final_line(self, elapsed: float) -> str:
        stopped = "stopped at " if self.total and self.n < self.total else ""
        return (f"{self._prefix()}{stopped}{self._count()} in {format_duration(elapsed)} "
                f"({format_rate(self.n, elapsed, self.unit)})")

    def _emit(self, line: str) -> None:
        _write_line(sys.stderr if self.stream is None else self.stream, line)
        self.lines_written += 1


def progress_bar(iterable: Iterable | None = None, *, total: int | None = None, desc: str = "", unit: str = "it",
                 disable: bool = False):
    """tqdm for library loops, chosen by :func:`progress_mode`: a ``tqdm.auto`` bar (bar), a
    :class:`LineProgress` (lines), or a disabled tqdm (off, or ``disable``). Same use as tqdm:
    ``for x in progress_bar(xs, desc=...)`` or ``with progress_bar(total=n) as bar: bar.update(1)``."""
    from tqdm.auto import tqdm

    mode = "off" if disable else progress_mode()
    if mode == "lines":
        return LineProgress(iterable, total=total, desc=desc, unit=unit)
    return tqdm(iterable, total=total, desc=desc, unit=unit, disable=mode == "off")


def loss_metrics(metrics: Mapping) -> dict[str, float]:
    """The total losses in ``metrics`` (Lightning's ``callback_metrics``): scalar entries whose name ends in
    ``loss`` (``train/loss``, ``val/mesh_loss``; not the terms ``train/loss_pd``), sorted, at most
    :data:`MAX_METRICS`, as floats."""
    out = {}
    for key in sorted(metrics):
        value = metrics[key]
        if not key.endswith("loss") or getattr(value, "numel", lambda: 1)() != 1:
            continue
        out[key] = float(value)
        if len(out) == MAX_METRICS:
            break
    return out


class EpochReport:
    """When to write a training's epoch lines and what they say (lines mode; Lightning-free, see
    :func:`epoch_lines`): a line when the finished epochs cross a 1/``marks`` step of the total, when
    ``interval_s`` has passed since the last line, and at the last epoch. A training of any length therefore
    writes at most ``marks`` + elapsed / ``interval_s`` + 1 lines.

    Args:
        name: the training's name, the line's prefix (``[autoencoder]``).
        marks: lines at every 1/``marks`` of the epochs. interval_s: default :func:`progress_interval`.
        stream: default ``sys.stdout`` (where Lightning draws its bar) at the time of writing.
        clock: seconds, monotonic.
    """

    def __init__(self, name: str, marks: int = EPOCH_MARKS, interval_s: float | None = None, stream=None,
                 clock: Clock = time.monotonic):
        self.name, self.marks, self.stream, self.clock = name, int(marks), stream, clock
        self.interval_s = progress_interval() if interval_s is None else float(interval_s)
        self.start()

    def start(self, done: int = 0) -> None:
        """A training (re)starts with ``done`` epochs finished (a resumed one: its checkpoint's)."""
        self._t0 = self._last = self.clock()
        self._done0 = self._last_done = int(done)

    def epoch_end(self, done: int, total: int | None, metrics: Mapping[str, float]) -> bool:
        """Epoch ``done`` (1-based) of ``total`` (None: unbounded) finished with ``metrics``; writes a line if
        it is time. Returns whether it wrote."""
        now = self.clock()
        crossed = bool(total) and done * self.marks // total > self._last_done * self.marks // total
        if not (crossed or now - self._last >= self.interval_s or (total and done >= total)):
            return False
        line = self._line(done, total, metrics, now - self._t0)
        _write_line(sys.stdout if self.stream is None else self.stream, line)
        self._last, self._last_done = now, done
        return True

    def _line(self, done: int, total: int | None, metrics: Mapping[str, float], elapsed: float) -> str:
        count = f"epoch {done}/{total} ({100 * done / total:.0f}%)" if total else f"epoch {done}"
        values = ", ".join(f"{k} {v:.4g}" for k, v in metrics.items())
        ran = done - self._done0
        per_epoch = elapsed / ran if ran > 0 else float("nan")
        timing = f"{per_epoch:.3g} s/epoch, {format_duration(elapsed)} elapsed"
        if total:
            timing += f", ETA {format_duration((total - done) * per_epoch)}"
        return f"[{self.name}] {count}" + (f": {values}" if values else "") + f"; {timing}"


def epoch_lines(name: str, marks: int = EPOCH_MARKS, interval_s: float | None = None, stream=None,
                clock: Clock = time.monotonic):
    """A Lightning callback writing :class:`EpochReport` lines (the logged losses) after each training epoch
    (after its validation, when the epoch has one)."""
    import lightning as L

    class EpochLines(L.Callback):
        """Epoch lines of one Lightning training (lines mode, :func:`neuralcol.utils.progress.epoch_lines`)."""

        def __init__(self):
            self.report = EpochReport(name, marks, interval_s, stream, clock)

        def on_train_start(self, trainer, pl_module) -> None:
            self.report.start(trainer.current_epoch)

        def on_train_epoch_end(self, trainer, pl_module) -> None:
            total = trainer.max_epochs if trainer.max_epochs and trainer.max_epochs > 0 else None
            self.report.epoch_end(trainer.current_epoch + 1, total, loss_metrics(trainer.callback_metrics))

    return EpochLines()


def trainer_progress(enabled: bool, name: str, callbacks: Iterable = ()) -> dict:
    """``enable_progress_bar`` and ``callbacks`` keyword arguments of a Lightning Trainer, by
    :func:`progress_mode` of ``sys.stdout`` (where Lightning's bar draws): with ``enabled``, Lightning's bar
    (bar) or no bar and :func:`epoch_lines` (lines); without it, or off, neither. ``callbacks`` are kept, in
    order, before the epoch lines.

    Example: ``L.Trainer(max_epochs=100, **trainer_progress(cfg.progress_bar, "autoencoder"))``.
    """
    mode = progress_mode(sys.stdout) if enabled else "off"
    extra = [epoch_lines(name)] if mode == "lines" else []
    return {"enable_progress_bar": mode == "bar", "callbacks": [*callbacks, *extra]}
