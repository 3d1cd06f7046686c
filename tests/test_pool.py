"""LabelPool: same labels as a plain loop over the exact labeler, for every worker/chunk/executor setting."""

from __future__ import annotations

import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import trimesh

from neuralcol.collision.labeler import ExactLabeler, Labels
from neuralcol.collision.pool import LabelPool

ROOT = Path(__file__).resolve().parents[1]


def two_spheres(offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Two unit icospheres (subdivisions=2), the second shifted by ``offset`` along x.

    Returns:
        vertices (324, 3) float64 and faces (640, 3) int64; they overlap iff offset < 2.
    """
    s = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(s.vertices, dtype=np.float64)
    f = np.asarray(s.faces, dtype=np.int64)
    return np.concatenate([v, v + [offset, 0.0, 0.0]]), np.concatenate([f, f + len(v)])


OFFSETS = [1.5, 2.6, 1.9, 3.0, 1.2, 2.05, 1.99, 4.0]  # mixed: overlapping (< 2) and free (> 2)


@pytest.fixture(scope="module")
def setup():
    rest, faces = two_spheres(3.0)
    n = len(rest) // 2
    partition = np.repeat([0, 1], n)  # one part per sphere: pd_sub is (B, 2)
    labeler = ExactLabeler(faces, rest, partition=partition)
    rng = np.random.default_rng(0)
    batch = np.stack([two_spheres(o)[0] for o in OFFSETS])  # (B, V, 3)
    batch = batch + 1e-3 * rng.standard_normal(batch.shape)
    reference = Labels.stack([labeler.label(v) for v in batch])
    return labeler, batch, reference


def assert_labels_equal(got: Labels, want: Labels) -> None:
    for name in Labels._fields:
        g, w = getattr(got, name), getattr(want, name)
        assert g.shape == w.shape, f"{name}: shape {g.shape}, expected {w.shape}"
        assert g.dtype == w.dtype, f"{name}: dtype {g.dtype}, expected {w.dtype}"
        np.testing.assert_array_equal(g, w, err_msg=f"field {name}")


def test_batch_is_mixed(setup):
    _, _, ref = setup
    assert ref.collides.any() and not ref.collides.all()
    np.testing.assert_array_equal(ref.collides, np.array(OFFSETS) < 2.0)
    assert ref.pd_sub.shape == (len(OFFSETS), 2)
    assert ((ref.pd > 0) == ref.collides).all()


@pytest.mark.parametrize("workers", [0, 1, 2])
@pytest.mark.parametrize("chunk_size", [1, 3, 1000])
def test_pool_matches_loop(setup, workers, chunk_size):
    labeler, batch, ref = setup
    with LabelPool(labeler, workers=workers, chunk_size=chunk_size) as pool:
        assert_labels_equal(pool.label(batch), ref)
        # the process pool is reused; a reversed batch comes back reversed
        assert_labels_equal(pool.label(batch[::-1]), Labels(*(x[::-1] for x in ref)))


@pytest.mark.parametrize("chunk_size", [1, 3, 1000])
def test_user_thread_executor(setup, chunk_size):
    labeler, batch, ref = setup
    with ThreadPoolExecutor(max_workers=3) as ex:
        with LabelPool(labeler, executor=ex, chunk_size=chunk_size) as pool:
            assert_labels_equal(pool.label(batch), ref)
        # closing the LabelPool leaves the user's executor running
        assert ex.submit(int, "7").result() == 7


def test_tensor_like_input(setup):
    labeler, batch, ref = setup

    class FakeTensor:  # stands for a torch tensor: only .detach().cpu().numpy() is used
        def __init__(self, a):
            self.a = a

        def detach(self):
            return self

        def cpu(self):
            return self

        def numpy(self):
            return self.a

    assert_labels_equal(LabelPool(labeler).label(FakeTensor(batch.astype(np.float32))),
                        Labels.stack([labeler.label(v) for v in batch.astype(np.float32)]))
    assert_labels_equal(LabelPool(labeler).label(batch.tolist()), ref)


@pytest.mark.parametrize("workers", [0, 2])
def test_empty_batch(setup, workers):
    labeler, batch, _ = setup
    with LabelPool(labeler, workers=workers) as pool:
        out = pool.label(np.zeros((0,) + batch.shape[1:]))
    assert out.collides.shape == (0,) and out.collides.dtype == bool
    assert out.n_pairs.shape == (0,) and out.n_pairs.dtype == np.int64
    assert out.pd.shape == (0,) and out.pd.dtype == np.float64
    assert out.pd_sub.shape == (0, labeler.n_parts) == (0, 2)


@pytest.mark.parametrize("shape", [(324, 3), (2, 323, 3), (2, 324, 2), (2, 324, 3, 1), ()])
def test_wrong_shape(setup, shape):
    labeler, _, _ = setup
    with pytest.raises(ValueError, match=r"expected \(B, 324, 3\)"):
        LabelPool(labeler).label(np.zeros(shape))


def test_non_finite(setup):
    labeler, batch, _ = setup
    bad = batch.copy()
    bad[3, 5, 1] = np.nan
    with pytest.raises(ValueError, match=r"meshes \[3\]"):
        LabelPool(labeler).label(bad)


@pytest.mark.parametrize("kwargs, match", [({"workers": -1}, "workers"), ({"chunk_size": 0}, "chunk_size"),
                                           ({"executor": object()}, "Executor"), ({"mp_context": "nope"}, "nope")])
def test_bad_arguments(setup, kwargs, match):
    labeler, _, _ = setup
    with pytest.raises((ValueError, TypeError), match=match):
        LabelPool(labeler, **kwargs)


def test_progress_bar(setup, capsys, monkeypatch):
    monkeypatch.setenv("NEURALCOL_PROGRESS", "bar")  # the tqdm bar, as on a terminal (tests/test_progress.py: lines)
    labeler, batch, ref = setup
    with LabelPool(labeler, chunk_size=3, progress=True, desc="test-labels") as pool:
        assert_labels_equal(pool.label(batch), ref)
    err = capsys.readouterr().err
    assert "test-labels" in err and f"{len(batch)}/{len(batch)}" in err


def test_import_without_torch():
    code = ("import sys, neuralcol.collision.pool, neuralcol.collision.__main__; "
            "bad = sorted(m for m in sys.modules if m == 'torch' or m.startswith('neuralcol.data')); "
            "assert not bad, bad")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr


@pytest.mark.parametrize("workers", [0, 2])
def test_limited_labels_on_the_pool_equal_the_capped_full_labels(setup, workers):
    """pool.label(v, clearance_limit=L): every executor returns the full labels with clearances capped at L (the
    labels for training); a labeler without ``label_limited`` has its full label capped the same way."""
    from neuralcol.collision.labeler import limit_clearance

    labeler, batch, ref = setup
    limit = 0.1 * float(-ref.pd.min())
    want = Labels.stack([limit_clearance(labeler.label(v), limit) for v in batch], 2)
    assert not np.array_equal(want.pd_sub, ref.pd_sub), "the limit must change some label"
    with LabelPool(labeler, workers=workers, chunk_size=3) as pool:
        assert_labels_equal(pool.label(batch, clearance_limit=limit), want)
        assert_labels_equal(pool.label(batch), ref)  # the next call without a limit: full labels again
    with ThreadPoolExecutor(max_workers=2) as ex, LabelPool(labeler, executor=ex, chunk_size=3) as pool:
        assert_labels_equal(pool.label_report(batch, clearance_limit=limit).labels, want)

    class FullOnly:  # a backend with only the full label
        n_vertices, n_parts = labeler.n_vertices, labeler.n_parts
        label = staticmethod(labeler.label)

    with LabelPool(FullOnly(), workers=0) as pool:
        assert_labels_equal(pool.label(batch, clearance_limit=limit), want)
        with pytest.raises(ValueError, match="clearance_limit"):
            pool.label(batch, clearance_limit=-1.0)
