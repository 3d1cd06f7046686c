"""Atomic cache writes shared by concurrent runs (neuralcol.utils.files)."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from neuralcol.data import features as features_mod
from neuralcol.utils.files import atomic_path


def test_atomic_path_moves_on_success_and_cleans_on_error(tmp_path):
    target = tmp_path / "a.npz"
    with atomic_path(target) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".npz" and tmp != target
        np.savez(tmp, x=np.arange(3))
    assert np.load(target)["x"].tolist() == [0, 1, 2]
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        np.savez(tmp, x=np.arange(5))
        raise RuntimeError("writer failed")
    assert np.load(target)["x"].tolist() == [0, 1, 2]  # the old file stays; no temporary left behind
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz"]


def test_two_writers_of_one_feature_cache(tmp_path, monkeypatch, tube_dataset):
    """Two runs of one new data set started together both encode its features and write the same cache
    entry; with one shared temporary name the second writer's rename failed."""
    barrier = threading.Barrier(2, timeout=30)
    savez = np.savez

    def savez_together(file, **arrays):  # both writers have written their file before either moves it
        savez(file, **arrays)
        barrier.wait()

    monkeypatch.setattr(np, "savez", savez_together)
    ds = tube_dataset.subset([0, 1, 2])
    results, errors = [], []

    def job():
        try:
            results.append(features_mod.dataset_features(ds, 0, cache_dir=tmp_path))
        except Exception as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=job) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == [] and len(results) == 2
    assert torch.equal(results[0].features, results[1].features)
    assert [p.suffix for p in tmp_path.iterdir()] == [".npz"]  # one cache file, no temporary left
