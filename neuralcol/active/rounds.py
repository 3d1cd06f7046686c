"""Rounds of D_c growth as a Lightning Callback (paper Algorithm 1, and the baselines' re-training).

One ``Trainer.fit`` covers every round. The callback watches the epochs: when the last epoch of a round ends
it (1) evaluates the detector on the fixed test set and records the round, (2) stops at ``max_rounds`` or at
the elbow of accuracy vs data set size (Kneedle), otherwise (3) acquires ``n_aug`` new labeled samples
(uniform for the baselines, Newton-projected + uniform for ``active``) and appends them to D_c, (4) switches
to the update schedule (fine-tuning warm-started for ``active``: lr 1e-4, batch 1024, 50 epochs; training from
scratch for the baselines) and (5) saves a checkpoint, so an interrupted run resumes after the last finished
round with D_c truncated to the rows that checkpoint knew. The trained round is also saved before its
acquisition (which labels for about as long as the round trains at the paper's sizes): a run stopped while
acquiring resumes with that acquisition (``on_fit_start``, before Lightning builds the data loaders; the
optimizer side in ``on_train_start``, after it restores the optimizer), not by training the round again.
Inside a round, the training state is saved at an epoch's end every ``checkpoint_minutes`` (the best validation
epoch's weights with it): a run killed there, or stopped by its sitting's budget, goes on from that epoch instead
of training the round again from its start (a round trains 30-60 min at the paper's sizes on 2 cores).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import lightning as L
import numpy as np

from neuralcol.active.acquisition import UniformAcquisition
from neuralcol.active.stopping import should_stop
from neuralcol.samples.datamodule import CollisionDataModule
from neuralcol.samples.store import Origin
from neuralcol.utils import sitting
from neuralcol.utils.faults import fault_point
from neuralcol.utils.files import atomic_path
from neuralcol.utils.safe_files import plain_values


@dataclass(frozen=True)
class Schedule:
    """How the detector is trained in a round: epochs, Adam lr, batch size, whether the weights and the
    optimizer restart from scratch (baselines) or continue (active fine-tuning), and a floor on the optimizer
    steps: a round runs ``max(epochs, ceil(min_steps / batches per epoch))`` epochs, so a budget meant for
    large data sets (the paper's 50 epochs of fine-tuning at 2*10^5+ rows) does not shrink to a few hundred
    steps on a few thousand rows (docs/studies/diagnosis_scape.md, cause 2). ``min_steps = 0``: epochs only (paper)."""

    epochs: int
    lr: float
    batch_size: int
    reinit: bool = False
    min_steps: int = 0

    def __post_init__(self):
        if self.epochs < 1 or self.lr <= 0 or self.batch_size < 1 or self.min_steps < 0:
            raise ValueError(f"schedule {self}: epochs and batch_size must be >= 1, lr > 0 and min_steps >= 0")

    def epochs_for(self, n_train: int) -> int:
        """Epochs of a round on ``n_train`` training rows."""
        batches = max(1, -(-int(n_train) // self.batch_size))  # ceil
        return max(self.epochs, -(-self.min_steps // batches))


class RoundCallback(L.Callback):
    """Grows D_c round by round inside one fit.

    Args:
        datamodule: D_c (already holding the bootstrap rows, round 0).
        acquire: the method's acquisition (uniform or projected); None: the bootstrap round only (``max_rounds = 0``).
        evaluate: module -> dict of test metrics (``accuracy`` among them).
        bootstrap: schedule of round 0.
        update: schedule of every later round.
        n_aug: samples added per round.
        max_rounds: rounds after the bootstrap (0 = bootstrap only).
        stop_at_elbow: stop at the elbow of accuracy vs size (Kneedle) once ``elbow_min_points`` rounds exist.
        elbow_min_points, elbow_sensitivity: Kneedle settings.
        checkpoint_path: where each finished round saves the training state.
        seed: seeds re-initialisation in the baselines' rounds.
        extra_eval: ``net -> dict`` run after the test metrics of every round (e.g. the collision handler's
            evaluation); stored under ``record["handling"]``.
        select_best_val: at the end of a round, restore the weights of the round's epoch with the best
            validation accuracy (model selection on the 20 % validation split of D_c) before testing.
        on_round: called with the list of round records after each round (metrics.json, TensorBoard).
        checkpoint_minutes: inside a round, save the training state at the end of the first epoch that ends this
            many minutes after the last save (0: every epoch; None: at round ends only). A sitting's budget
            (``max_minutes``) is checked there too.
    """

    def __init__(self, datamodule: CollisionDataModule, acquire: UniformAcquisition | None, evaluate: Callable,
                 bootstrap: Schedule, update: Schedule, n_aug: int, max_rounds: int, stop_at_elbow: bool,
                 elbow_min_points: int, elbow_sensitivity: float, checkpoint_path: str | Path, seed: int,
                 select_best_val: bool = True, on_round: Callable[..., None] | None = None,
                 extra_eval: Callable | None = None, checkpoint_minutes: float | None = None):
        if n_aug < 1 or max_rounds < 0:
            raise ValueError(f"n_aug={n_aug} must be >= 1 and max_rounds={max_rounds} >= 0")
        if checkpoint_minutes is not None and not float(checkpoint_minutes) >= 0:
            raise ValueError(f"detector.checkpoint_minutes={checkpoint_minutes}: give minutes >= 0 between the "
                             "checkpoints inside a round (0: every epoch), or null for round ends only")
        if acquire is None and max_rounds > 0:
            raise ValueError(f"max_rounds={max_rounds} rounds need an acquisition (acquire=None: bootstrap only)")
        self.dm = datamodule
        self.acquire = acquire
        self.evaluate = evaluate
        self.bootstrap, self.update = bootstrap, update
        self.n_aug, self.max_rounds = int(n_aug), int(max_rounds)
        self.stop_at_elbow = bool(stop_at_elbow)
        self.elbow_min_points, self.elbow_sensitivity = int(elbow_min_points), float(elbow_sensitivity)
        self.checkpoint_path = Path(checkpoint_path)
        self.seed = int(seed)
        self.on_round = on_round
        self.select_best_val = bool(select_best_val)
        self.extra_eval = extra_eval
        self.checkpoint_minutes = None if checkpoint_minutes is None else float(checkpoint_minutes)
        self._last_save = time.monotonic()  # the last checkpoint this process saved (or its start)
        self._best: tuple[float, int, dict] | None = None  # (val accuracy, epoch, weights) of this round
        # state saved with checkpoints
        self.round = 0
        self.round_start_epoch = 0
        self.round_end_epoch = bootstrap.epochs - 1  # set from the bootstrap rows when the fit starts
        self.rounds: list[dict] = []
        self.finished = False
        self.stopped_by: str | None = None
        self.elbow: float | None = None
        self.seconds = {"label": 0.0, "train": 0.0, "project": 0.0}
        self.store_len: int | None = None
        self.pending_acquisition = False  # the round is trained and saved; its acquisition has not finished
        self._epoch_t0 = 0.0

    @property
    def max_epochs(self) -> int:
        """An upper bound of the epochs of all rounds (the callback stops the fit after the last round)."""
        return self.bootstrap.epochs_for(1) + self.max_rounds * self.update.epochs_for(1)

    def add_label_seconds(self, seconds: float) -> None:
        self.seconds["label"] += float(seconds)

    def schedule(self) -> Schedule:
        return self.bootstrap if self.round == 0 else self.update

    # ---------------------------------------------------------------- checkpoint state
    def state_dict(self) -> dict:
        """The rounds' state for the checkpoint, as plain values (the checkpoint loads with ``weights_only=True``)."""
        state = {"round": self.round, "round_start_epoch": self.round_start_epoch,
                 "round_end_epoch": self.round_end_epoch, "rounds": self.rounds,
                 "finished": self.finished, "stopped_by": self.stopped_by, "elbow": self.elbow,
                 "seconds": dict(self.seconds), "store_len": self.store_len, "batch_size": self.dm.batch_size,
                 "pending_acquisition": self.pending_acquisition,
                 "acquire": None if self.acquire is None else self.acquire.state_dict(),
                 "schedules": [asdict(self.bootstrap), asdict(self.update)],
                 # inside a round: its best validation epoch so far (select_best_val), so a resumed round selects
                 # the same weights as an uninterrupted one
                 "best": None if self._best is None else {"accuracy": self._best[0], "epoch": self._best[1],
                                                          "weights": self._best[2]}}
        return plain_values(state, f"{self.checkpoint_path.name}: RoundCallback state")

    def load_state_dict(self, state: dict) -> None:
        wanted = [asdict(self.bootstrap), asdict(self.update)]
        if state["schedules"] != wanted:
            raise ValueError(f"{self.checkpoint_path}: the checkpoint was trained with schedules "
                             f"{state['schedules']}, the config asks for {wanted}; resume with the same method "
                             "and detector settings or start a new run directory")
        self.round, self.round_end_epoch = int(state["round"]), int(state["round_end_epoch"])
        self.round_start_epoch = int(state.get("round_start_epoch",
                                               self.round_end_epoch - self.schedule().epochs + 1))
        self.rounds, self.finished = list(state["rounds"]), bool(state["finished"])
        self.stopped_by, self.elbow = state["stopped_by"], state["elbow"]
        self.seconds = dict(state["seconds"])
        self.store_len = state["store_len"]
        self.pending_acquisition = bool(state.get("pending_acquisition", False))  # absent in older checkpoints
        self.dm.batch_size = int(state["batch_size"])
        best = state.get("best")  # absent before mid-round checkpoints
        self._best = None if best is None else (float(best["accuracy"]), int(best["epoch"]), dict(best["weights"]))
        if self.acquire is not None:
            self.acquire.load_state_dict(state["acquire"])

    # ---------------------------------------------------------------- hooks
    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self.store_len is not None and len(self.dm) != self.store_len:
            # rows appended after the last checkpoint (the run died while acquiring) are dropped
            self.dm.store.truncate(self.store_len)
            self.dm.refresh()
        if self.store_len is None:
            self.store_len = len(self.dm)
            self.dm.batch_size = self.schedule().batch_size
            pl_module.set_lr(self.schedule().lr)
            if self.dm.n_train == 0:
                self.dm.refresh()
            self.round_start_epoch = 0
            self.round_end_epoch = self.bootstrap.epochs_for(self.dm.n_train) - 1
        if self.pending_acquisition:  # resumed from a trained round whose acquisition was cut off: do it now,
            self._acquire(trainer, pl_module, self.round_end_epoch)  # so the first loaders hold its rows

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self.pending_acquisition:  # (acquired in on_fit_start) after Lightning restored the optimizer and the
            self._start_round(trainer, pl_module)  # loops, so the new lr, re-initialisation and checkpoint stick

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        fault_point("train_epoch")
        self._epoch_t0 = time.perf_counter()

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        acc = trainer.callback_metrics.get("val/accuracy")
        first_epoch = self.round_start_epoch
        # (a resumed fit re-validates the checkpoint's epoch, which belongs to the previous round: skipped)
        if trainer.sanity_checking or acc is None or not self.select_best_val or trainer.current_epoch < first_epoch:
            return
        acc = float(acc)
        if self._best is None or acc > self._best[0]:
            state = {k: v.detach().clone() for k, v in pl_module.net.state_dict().items()}
            self._best = (acc, trainer.current_epoch, state)

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.seconds["train"] += time.perf_counter() - self._epoch_t0
        if trainer.current_epoch >= self.round_end_epoch:
            self._finish_round(trainer, pl_module)
        elif self.checkpoint_minutes is not None and time.monotonic() - self._last_save >= 60 * self.checkpoint_minutes:
            self._save_inside_round(trainer)

    def _write_checkpoint(self, trainer: L.Trainer) -> None:
        """The whole training state to ``checkpoint_path``, written to a temporary file beside it and renamed onto
        it: a kill while writing leaves the previous checkpoint whole. (Lightning writes to the system's temporary
        directory and moves the file over: a copy, not a rename, across file systems; a truncated checkpoint would
        cost the run its training state.)"""
        with atomic_path(self.checkpoint_path) as tmp:
            trainer.save_checkpoint(tmp, weights_only=False)
        self._last_save = time.monotonic()

    def _save_inside_round(self, trainer: L.Trainer) -> None:
        """The training state at the end of this epoch of the round (resumed from the next epoch); the sitting
        stopped here if its time is spent."""
        self._write_checkpoint(trainer)
        done = trainer.current_epoch - self.round_start_epoch + 1
        total = self.round_end_epoch - self.round_start_epoch + 1
        sitting.check(f"round {self.round}'s epoch {done}/{total} (|D_c| = {len(self.dm)})")

    @staticmethod
    def _log_projection(trainer: L.Trainer, quality: dict, step: int) -> None:
        """TensorBoard scalars ``projection/<key>`` against |D_c| (no-op without a TensorBoard logger)."""
        writer = getattr(getattr(trainer, "logger", None), "experiment", None)
        if writer is None or not hasattr(writer, "add_scalar"):
            return
        flat = {k: v for k, v in quality.items() if not isinstance(v, dict)}
        for group, sub in quality.items():  # start, uniform
            if isinstance(sub, dict):
                flat.update({f"{group}_{k}": v for k, v in sub.items()})
        for key, val in flat.items():
            if isinstance(val, (int, float)) and np.isfinite(val):
                writer.add_scalar(f"projection/{key}", float(val), global_step=step)

    def _finish_round(self, trainer: L.Trainer, pl_module) -> None:
        selected = {}
        if self._best is not None:
            val_acc, epoch, state = self._best
            pl_module.net.load_state_dict(state)
            first_epoch = self.round_start_epoch
            selected = {"val_accuracy": val_acc, "selected_epoch": epoch - first_epoch}
            self._best = None
        metrics = self.evaluate(pl_module)
        rows = self.dm.store.read()
        record = {"round": self.round, "dataset_size": len(self.dm), **metrics, **selected,
                  "epochs": self.round_end_epoch - self.round_start_epoch + 1,
                  "label_seconds": self.seconds["label"], "train_seconds": self.seconds["train"],
                  "project_seconds": self.seconds["project"],
                  "n_projected_total": int((rows.origin == Origin.PROJECTED).sum()),
                  "subset_counts": np.bincount(rows.subset, minlength=3).tolist()}
        if self.extra_eval is not None:
            record["handling"] = self.extra_eval(pl_module.on_codes)
        self.rounds.append(record)
        if self.on_round is not None:  # recorded before the (long) acquisition, so a crash there keeps it
            self.on_round(self.rounds, False)
        sizes = [r["dataset_size"] for r in self.rounds]
        acc = [r["accuracy"] for r in self.rounds]
        stop, self.elbow = should_stop(sizes, acc, self.elbow_min_points, self.elbow_sensitivity)
        if self.round >= self.max_rounds or (self.stop_at_elbow and stop):
            self.finished = True
            self.stopped_by = "elbow" if self.round < self.max_rounds else "max_rounds"
            trainer.should_stop = True
            self._save(trainer)
            return
        # the trained round, saved before the (long) acquisition: a stop inside it resumes there
        self.pending_acquisition = True
        self._write_checkpoint(trainer)
        sitting.check(f"round {self.round}'s training, before its acquisition (|D_c| = {len(self.dm)})")
        self._acquire(trainer, pl_module, trainer.current_epoch)
        self._start_round(trainer, pl_module)

    def _save(self, trainer: L.Trainer) -> None:
        """The round records (``on_round``) and the checkpoint."""
        if self.on_round is not None:
            self.on_round(self.rounds, self.finished, echo=False)
        # weights_only here picks what is saved (the whole training state, optimizer and callbacks included); the
        # checkpoint holds plain values only and is read back with weights_only=True (stages/detector.py)
        self._write_checkpoint(trainer)

    def _acquire(self, trainer: L.Trainer, pl_module, epoch: int) -> None:
        """The next round's rows, acquired with the detector of the round that ended at ``epoch`` and appended to
        D_c; the next round's number, epochs and batch size set."""
        record = self.rounds[-1]
        with sitting.held():  # its rows are only saved at its end (the uniform ones are cached as they are labeled)
            new = self.acquire(self.round + 1, pl_module.on_codes, self.dm.store, self.n_aug)
        self.dm.append(new.z, new.pd, new.pd_sub, new.collides, new.subset, self.round + 1, new.origin)
        self.seconds["label"] += new.label_seconds
        self.seconds["project"] += new.project_seconds
        record["next_round_acquisition"] = new.info
        if "projection" in new.info:  # samples this round's detector projected (they join D_c next round)
            record["projection"] = new.info["projection"]
            self._log_projection(trainer, new.info["projection"], len(self.dm))
        self.round += 1
        sched = self.update
        self.dm.batch_size = sched.batch_size
        self.round_start_epoch = epoch + 1
        self.round_end_epoch = epoch + sched.epochs_for(self.dm.n_train)
        self.store_len = len(self.dm)

    def _start_round(self, trainer: L.Trainer, pl_module) -> None:
        """After :meth:`_acquire`: the update schedule's weights and lr, the checkpoint saved, the sitting stopped
        here if its time is spent."""
        sched = self.update
        if sched.reinit:
            pl_module.reinitialize(self.seed * 1000 + self.round)
        pl_module.set_lr(sched.lr)
        self.pending_acquisition = False
        self._save(trainer)
        sitting.check(f"the end of round {self.round - 1} (|D_c| = {len(self.dm)})")
