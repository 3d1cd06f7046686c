"""The round callback's checkpoint state inside a round (detector.checkpoint_minutes): the best
validation epoch so far travels with it, through a file read with weights_only=True, so a resumed round selects
the weights an uninterrupted one would. The whole-run check (stop, kill, resume, same metrics) is in
tests/test_reliability.py."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from neuralcol.active.rounds import RoundCallback, Schedule
from neuralcol.utils.safe_files import read_torch_file


def _callback(tmp_path, **kw) -> RoundCallback:
    sched = Schedule(epochs=4, lr=1e-3, batch_size=64)
    return RoundCallback(datamodule=SimpleNamespace(batch_size=64), acquire=None, evaluate=lambda m: {},
                         bootstrap=sched, update=sched, n_aug=10, max_rounds=0, stop_at_elbow=False,
                         elbow_min_points=5, elbow_sensitivity=1.0, checkpoint_path=tmp_path / "d.ckpt", seed=0, **kw)


def test_the_rounds_best_epoch_survives_a_checkpoint_file(tmp_path):
    cb = _callback(tmp_path, checkpoint_minutes=0)
    weights = {"w": torch.randn(3, 2), "b": torch.randn(2)}
    cb.round, cb.round_start_epoch, cb.round_end_epoch = 1, 4, 7
    cb._best = (0.8125, 5, weights)
    torch.save({"rounds": cb.state_dict()}, tmp_path / "d.ckpt")
    back = _callback(tmp_path)
    back.load_state_dict(read_torch_file(tmp_path / "d.ckpt")["rounds"])
    acc, epoch, got = back._best
    assert (acc, epoch, back.round, back.round_start_epoch) == (0.8125, 5, 1, 4)
    assert got.keys() == weights.keys() and all(torch.equal(got[k], weights[k]) for k in weights)
    # at a round's end there is no best epoch yet, and a checkpoint from before this field loads as none
    cb._best = None
    state = cb.state_dict()
    assert state["best"] is None
    del state["best"]
    back.load_state_dict(state)
    assert back._best is None


@pytest.mark.parametrize("bad", [-1, float("nan")])
def test_checkpoint_minutes_must_be_a_duration(tmp_path, bad):
    with pytest.raises(ValueError, match="detector.checkpoint_minutes"):
        _callback(tmp_path, checkpoint_minutes=bad)


def test_a_write_cut_off_leaves_the_previous_checkpoint_whole(tmp_path):
    """Checkpoints are written to a temporary file and moved onto the old one: a write that dies half way (here an
    exception after half the bytes; a SIGKILL leaves only the temporary file) does not truncate the checkpoint."""
    cb = _callback(tmp_path)
    good = b"the previous round's checkpoint"

    class Trainer:
        def save_checkpoint(self, path, weights_only=False):
            with open(path, "wb") as f:
                f.write(b"half of a new ")
            if self.fail:
                raise OSError("disk full")

    (tmp_path / "d.ckpt").write_bytes(good)
    trainer = Trainer()
    trainer.fail = True
    with pytest.raises(OSError, match="disk full"):
        cb._write_checkpoint(trainer)
    assert (tmp_path / "d.ckpt").read_bytes() == good
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.ckpt"], "no temporary file left behind"
    trainer.fail = False
    cb._write_checkpoint(trainer)
    assert (tmp_path / "d.ckpt").read_bytes() == b"half of a new "
