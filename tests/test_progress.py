"""Progress off a terminal: newline-terminated lines at a bounded rate, never ``\\r`` redraws;
bars stay on a terminal."""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
from pathlib import Path

import lightning as L
import pytest
import torch
from torch.utils.data import DataLoader, TensorDataset
from tqdm import tqdm

from neuralcol.errors import UserInputError
from neuralcol.utils.progress import (
    EpochReport,
    LineProgress,
    format_duration,
    loss_metrics,
    progress_bar,
    progress_mode,
    trainer_progress,
)

ROOT = Path(__file__).resolve().parents[1]


class FakeClock:
    """A clock that advances only when told to."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class FakeTerminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture
def auto_mode(monkeypatch):
    """The mode chosen from the stream, as for a user who set nothing."""
    monkeypatch.delenv("NEURALCOL_PROGRESS", raising=False)
    monkeypatch.delenv("NEURALCOL_PROGRESS_INTERVAL", raising=False)


def test_long_loop_writes_bounded_lines_without_carriage_returns():
    clock, out = FakeClock(), io.StringIO()
    n, step_s, interval_s = 10_000, 0.1, 30.0  # 1000 s of work
    with LineProgress(total=n, desc="labeling", unit="mesh", interval_s=interval_s, stream=out, clock=clock) as bar:
        for _ in range(n):
            clock.now += step_s
            bar.update(1)
    text = out.getvalue()
    lines = text.splitlines()
    assert "\r" not in text and text.endswith("\n")
    assert len(lines) <= n * step_s / interval_s + 2, lines
    assert len(lines) >= n * step_s / interval_s - 1  # one per interval, not one at the end only
    assert lines[0].startswith("labeling: ") and "mesh/s" in lines[0] and "ETA" in lines[0]
    assert lines[-1] == "labeling: 10000/10000 mesh in 16:40 (10 mesh/s)"


def test_short_loop_is_quiet_and_iteration_counts_every_item():
    clock, out = FakeClock(), io.StringIO()
    seen = list(LineProgress(range(5), desc="quick", interval_s=30.0, quiet_s=2.0, stream=out, clock=clock))
    assert seen == [0, 1, 2, 3, 4] and out.getvalue() == ""
    slow = LineProgress(range(3), desc="slow", interval_s=30.0, quiet_s=2.0, stream=out, clock=clock)
    for _ in slow:
        clock.now += 1.0
    assert slow.n == 3 and out.getvalue() == "slow: 3/3 it in 0:03 (1 it/s)\n"


def test_interrupted_loop_says_where_it_stopped():
    clock, out = FakeClock(), io.StringIO()
    with pytest.raises(RuntimeError), LineProgress(total=10, desc="d", unit="mesh", quiet_s=0.0, interval_s=30.0,
                                                   stream=out, clock=clock) as bar:
        bar.update(4)
        clock.now += 8.0
        raise RuntimeError("worker died")
    assert out.getvalue() == "d: stopped at 4/10 mesh in 0:08 (2 s/mesh)\n"


def test_epoch_report_bounded_by_marks_and_interval():
    clock, out = FakeClock(), io.StringIO()
    epochs, epoch_s, interval_s = 1000, 0.05, 30.0  # 50 s: the tenths decide
    rep = EpochReport("autoencoder", marks=10, interval_s=interval_s, stream=out, clock=clock)
    for e in range(1, epochs + 1):
        clock.now += epoch_s
        rep.epoch_end(e, epochs, {"train/loss": 1.0 / e, "val/loss": 2.0 / e})
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    assert len(lines) <= 10 + epochs * epoch_s / interval_s + 1, lines
    assert [ln.split(" (")[0] for ln in lines] == [f"[autoencoder] epoch {100 * k}/1000" for k in range(1, 11)]
    assert lines[-1].startswith("[autoencoder] epoch 1000/1000 (100%): train/loss 0.001, val/loss 0.002; ")
    assert lines[-1].endswith("0:50 elapsed, ETA 0:00")


def test_epoch_report_writes_at_the_interval_on_a_long_training():
    clock, out = FakeClock(), io.StringIO()
    rep = EpochReport("detector", marks=10, interval_s=30.0, stream=out, clock=clock)
    for e in range(1, 201):  # 20 s per epoch: a line every second epoch (interval), tenths included
        clock.now += 20.0
        rep.epoch_end(e, 200, {})
    assert len(out.getvalue().splitlines()) == 100


def test_mode_from_stream_and_environment(monkeypatch, auto_mode):
    assert progress_mode(FakeTerminal()) == "bar"
    assert progress_mode(io.StringIO()) == "lines"
    monkeypatch.setenv("NEURALCOL_PROGRESS", "off")
    assert progress_mode(FakeTerminal()) == "off"
    assert isinstance(progress_bar(range(3)), tqdm) and progress_bar(range(3)).disable
    monkeypatch.setenv("NEURALCOL_PROGRESS", "lines")
    assert isinstance(progress_bar(total=3, desc="x"), LineProgress)
    monkeypatch.setenv("NEURALCOL_PROGRESS", "bar")
    bar = progress_bar(total=3, disable=True)
    assert isinstance(bar, tqdm) and bar.disable


def test_bad_settings_are_one_line_user_errors(monkeypatch, auto_mode):
    monkeypatch.setenv("NEURALCOL_PROGRESS", "fancy")
    with pytest.raises(UserInputError, match=r"^NEURALCOL_PROGRESS='fancy' .*bar, lines or off") as err:
        progress_mode()
    assert "\n" not in str(err.value)
    monkeypatch.setenv("NEURALCOL_PROGRESS", "lines")
    for bad in ("soon", "0", "-3", "inf"):
        monkeypatch.setenv("NEURALCOL_PROGRESS_INTERVAL", bad)
        with pytest.raises(UserInputError, match=r"^NEURALCOL_PROGRESS_INTERVAL=.*positive number"):
            progress_bar(total=3)


def test_epoch_lines_show_the_total_losses():
    logged = {"val/loss": torch.tensor(0.5), "train/loss_pd": torch.tensor(0.1), "val/accuracy": torch.tensor(0.9),
              "train/mesh_loss": torch.tensor(0.25), "train/loss": 1.5, "train/ranked_loss": torch.zeros(3)}
    assert loss_metrics(logged) == {"train/loss": 1.5, "train/mesh_loss": 0.25, "val/loss": 0.5}


def test_format_duration():
    assert [format_duration(s) for s in (0, 59.4, 61, 3600 + 62, float("nan"))] == ["0:00", "0:59", "1:01",
                                                                                      "1:01:02", "?"]


class TinyModule(L.LightningModule):
    def __init__(self):
        super().__init__()
        self.net = torch.nn.Linear(2, 1)

    def _loss(self, batch):
        x, y = batch
        return torch.nn.functional.mse_loss(self.net(x).squeeze(-1), y)

    def training_step(self, batch, _):
        loss = self._loss(batch)
        self.log("train/loss", loss, on_epoch=True, on_step=False)
        return loss

    def validation_step(self, batch, _):
        self.log("val/loss", self._loss(batch), on_epoch=True, on_step=False)

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.1)


def _fit_tiny(log: Path, epochs: int) -> str:
    """Fit TinyModule for ``epochs`` epochs with stdout and stderr going to the file ``log`` (not a terminal)."""
    g = torch.Generator().manual_seed(0)
    x = torch.randn(64, 2, generator=g)
    data = TensorDataset(x, x @ torch.tensor([1.0, -2.0]))
    with open(log, "w") as f, contextlib.redirect_stdout(f), contextlib.redirect_stderr(f):
        trainer = L.Trainer(max_epochs=epochs, logger=False, enable_checkpointing=False, enable_model_summary=False,
                            accelerator="cpu", devices=1, check_val_every_n_epoch=10,
                            **trainer_progress(True, "tiny"))
        trainer.fit(TinyModule(), DataLoader(data, batch_size=16), DataLoader(data, batch_size=64))
    return log.read_bytes().decode()


def test_lightning_off_a_terminal_writes_epoch_lines(tmp_path, monkeypatch, auto_mode):
    monkeypatch.setenv("NEURALCOL_PROGRESS_INTERVAL", "1000")  # the tenths alone: a deterministic line count
    text = _fit_tiny(tmp_path / "lines.txt", 200)
    lines = text.splitlines()
    assert "\r" not in text and len(text) < 2500, text
    assert [ln.split(" (")[0] for ln in lines] == [f"[tiny] epoch {20 * k}/200" for k in range(1, 11)], lines
    assert all(": train/loss " in ln and ", val/loss " in ln for ln in lines), lines
    # the same training with Lightning's bar forced (what a log file got before): redraws, many times larger
    monkeypatch.setenv("NEURALCOL_PROGRESS", "bar")
    bars = _fit_tiny(tmp_path / "bars.txt", 200)
    assert "\r" in bars and len(bars) > 20 * len(text)


def test_lightning_progress_choice(monkeypatch, auto_mode):
    monkeypatch.setenv("NEURALCOL_PROGRESS", "bar")
    assert trainer_progress(True, "x", ["cb"]) == {"enable_progress_bar": True, "callbacks": ["cb"]}
    monkeypatch.setenv("NEURALCOL_PROGRESS", "off")
    assert trainer_progress(True, "x", ["cb"]) == {"enable_progress_bar": False, "callbacks": ["cb"]}
    monkeypatch.setenv("NEURALCOL_PROGRESS", "lines")
    assert trainer_progress(False, "x") == {"enable_progress_bar": False, "callbacks": []}
    kw = trainer_progress(True, "x", ["cb"])
    assert not kw["enable_progress_bar"] and kw["callbacks"][0] == "cb"
    assert isinstance(kw["callbacks"][1], L.Callback)


def test_main_run_log_off_a_terminal(tmp_path):
    """``python -m experiments.run > log 2>&1`` at tiny sizes, with the autoencoder's and the detector's progress
    switched on: a short log of whole lines that ends with the summary."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NEURALCOL_PROGRESS")}
    log = tmp_path / "log.txt"
    with open(log, "wb") as f:
        proc = subprocess.run(
            [sys.executable, "-m", "experiments.run", "autoencoder=tiny", "detector=tiny", "realistic=tiny",
             "speed_accuracy=tiny", "autoencoder.progress_bar=true",
             "detector.progress_bar=true", f"paths.cache_dir={tmp_path}/cache", f"hydra.run.dir={tmp_path}/run"],
            cwd=ROOT, env=env, stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, timeout=900)
    text = log.read_bytes().decode()
    assert proc.returncode == 0, text[-3000:]
    assert "\r" not in text, text[:3000]
    assert len(text.encode()) < 12_000, text
    assert "[autoencoder] epoch " in text and "[active] epoch " in text
    assert text.rstrip().splitlines()[-1].startswith("results: ")
