"""experiments.compare_runs: two runs are the same when every non-timing value and every array is."""

from __future__ import annotations

import json

import numpy as np
import torch

from experiments.compare_runs import main


def _run(path, acc=0.9, seconds=1.0, weight=0.0):
    path.mkdir()
    (path / "metrics.json").write_text(json.dumps({"rounds": [{"accuracy": acc, "train_seconds": seconds,
                                                                "fnr": float("nan")}],
                                                    "detector": {"inference_us": {"batch_1": seconds}}}))
    torch.save({"state": {"w": torch.full((2,), weight)}}, path / "detector.pt")
    np.savez(path / "test_predictions.npz", prob=np.array([0.1, 0.9]))
    return path


def test_same_runs_differ_only_in_time(tmp_path, capsys):
    a, b = _run(tmp_path / "a"), _run(tmp_path / "b", seconds=5.0)
    assert main([str(a), str(b)]) == 0
    assert "2 values identical, 0 differ" in capsys.readouterr().out


def test_a_changed_value_or_weight_is_a_difference(tmp_path, capsys):
    a, b, c = _run(tmp_path / "a"), _run(tmp_path / "b", acc=0.91), _run(tmp_path / "c", weight=1.0)
    assert main([str(a), str(b)]) == 1
    assert "rounds.0.accuracy: 0.9 vs 0.91" in capsys.readouterr().out
    assert main([str(a), str(c)]) == 1
    assert "detector.pt:w" in capsys.readouterr().out
    assert main([str(a), str(tmp_path / "missing")]) == 2
