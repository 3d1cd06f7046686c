"""D_c store: growth by exactly the appended rows, stable split, reopening, crash safety, clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from neuralcol.samples.store import CollisionStore, StoreCorruptedError


def _rows(rng, b, d=6, k=2):
    pd = rng.normal(size=b).astype(np.float32)
    return dict(z=rng.normal(size=(b, d)), pd=pd, pd_sub=np.stack([pd, pd - 0.1], 1), collides=(pd > 0),
                subset=np.where(pd > 0.5, 0, np.where(pd < 0, 1, 2)), origin=0)


def test_append_grows_by_exactly_the_rows_and_reopens(tmp_path):
    rng = np.random.default_rng(0)
    path = tmp_path / "dc.h5"
    with CollisionStore(path, 6, 2) as store:
        ids0 = store.append(round_=0, **_rows(rng, 10))
        assert len(store) == 10 and ids0.tolist() == list(range(10))
        first = store.read()
        store.append(round_=1, **_rows(rng, 7))
        assert len(store) == 17
        split_before = store.split_mask()[:10].copy()
    with CollisionStore(path, 6, 2) as store:
        rows = store.read()
        assert len(store) == 17 and rows.id.tolist() == list(range(17))
        assert rows.round.tolist() == [0] * 10 + [1] * 7
        np.testing.assert_array_equal(rows.z[:10], first.z)
        assert (store.split_mask()[:10] == split_before).all(), "the split of old rows does not change"
        assert store.split_mask().sum() == 3  # ids 4, 9, 14


def test_crash_mid_append_keeps_committed_rows(tmp_path):
    import h5py

    rng = np.random.default_rng(1)
    path = tmp_path / "dc.h5"
    with CollisionStore(path, 6, 2) as store:
        store.append(round_=0, **_rows(rng, 8))
    with h5py.File(path, "a") as h5:  # simulate a crash after writing rows but before committing them
        for name in h5:
            h5[name].resize(12, axis=0)
        h5["pd"][8:12] = 99.0
    with CollisionStore(path, 6, 2) as store:
        assert len(store) == 8 and (store.read().pd != 99.0).all()
        store.append(round_=1, **_rows(rng, 2))  # overwrites the uncommitted rows
        assert len(store) == 10 and store.read().id.tolist() == list(range(10))


def test_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5")
    with pytest.raises(StoreCorruptedError, match=r"bad\.h5: cannot be opened"):
        CollisionStore(bad, 6, 2)
    path = tmp_path / "dc.h5"
    CollisionStore(path, 6, 2).close()
    with pytest.raises(StoreCorruptedError, match=r"dc\.h5: holds codes of size 6"):
        CollisionStore(path, 8, 2)
    with CollisionStore(path, 6, 2) as store, pytest.raises(ValueError, match=r"expected \(B, 6\)"):
        store.append(z=np.zeros((3, 5)), pd=np.zeros(3), pd_sub=np.zeros((3, 2)), collides=np.zeros(3),
                      subset=np.zeros(3), round_=0, origin=0)


def test_truncated_or_corrupted_file_is_named(tmp_path):
    rng = np.random.default_rng(2)
    path = tmp_path / "dc.h5"
    with CollisionStore(path, 6, 2) as store:
        for r in range(3):
            store.append(round_=r, **_rows(rng, 5000))
    data = path.read_bytes()
    (tmp_path / "cut.h5").write_bytes(data[: len(data) * 9 // 10])
    with pytest.raises(StoreCorruptedError, match=r"cut\.h5: cannot be opened as HDF5 \(.*truncated file"):
        CollisionStore(tmp_path / "cut.h5", 6, 2)
    # flip bytes inside the data chunks: the checksums catch it on read
    with CollisionStore(path, 6, 2) as store:
        offset = store._h5["z"].id.get_chunk_info(0).byte_offset
    bad = bytearray(data)
    bad[offset + 100: offset + 164] = b"\xff" * 64
    (tmp_path / "flipped.h5").write_bytes(bytes(bad))
    with CollisionStore(tmp_path / "flipped.h5", 6, 2) as store, \
            pytest.raises(StoreCorruptedError, match=r"flipped\.h5: its data is corrupted"):
        store.read()


def test_pair_features_are_kept_with_their_rows_and_checked(tmp_path):
    """A store created for a detector that reads the mesh keeps each row's pair features."""
    rng = np.random.default_rng(5)
    path = tmp_path / "dc.h5"
    g1, g2 = rng.normal(size=(4, 3, 3)), rng.normal(size=(2, 3, 3))
    with CollisionStore(path, 6, 2, n_pairs=3) as store:
        store.append(round_=0, geometry=g1, **_rows(rng, 4))
        store.append(round_=1, geometry=g2, **_rows(rng, 2))
        with pytest.raises(ValueError, match=r"every row needs its pair features \(1, 3, 3\)"):
            store.append(round_=1, **_rows(rng, 1))
        with pytest.raises(ValueError, match=r"geometry has shape \(1, 2, 3\), expected \(1, 3, 3\)"):
            store.append(round_=1, geometry=g1[:1, :2], **_rows(rng, 1))
    with CollisionStore(path, 6, 2, n_pairs=None) as store:  # a reader takes what is there
        rows = store.read()
        np.testing.assert_allclose(rows.geometry, np.concatenate([g1, g2]).astype(np.float32))
        assert store.read([1, 5]).geometry.shape == (2, 3, 3) and len(store) == 6
        np.testing.assert_array_equal(rows.select(rows.round == 1).geometry, rows.geometry[4:])
        # rows read alone from the file (indices in any order, or a mask) = the same rows of the whole store
        for some in ([5, 1, 3], np.arange(6) % 2 == 1, []):
            part, whole = store.read_rows(some), rows.select(np.unique(np.flatnonzero(some) if np.asarray(some).dtype
                                                                      == bool else np.asarray(some, int)))
            for a, b in zip(part, whole):
                np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(store.column("round"), rows.round)
        with pytest.raises(KeyError, match="no column 'nope'"):
            store.column("nope")
        with pytest.raises(IndexError, match="outside the 6 committed"):
            store.read_rows([0, 6])
    with pytest.raises(StoreCorruptedError, match="3 contact pairs per row, expected 0"):
        CollisionStore(path, 6, 2)
    with CollisionStore(tmp_path / "plain.h5", 6, 2) as plain:
        plain.append(round_=0, **_rows(rng, 2))
        assert plain.read().geometry is None and plain.read().select(slice(0, 1)).geometry is None
        with pytest.raises(ValueError, match="keeps no pair features"):
            plain.append(round_=0, geometry=g2, **_rows(rng, 2))
    with pytest.raises(StoreCorruptedError, match="0 contact pairs per row, expected 3"):
        CollisionStore(tmp_path / "plain.h5", 6, 2, n_pairs=3)
