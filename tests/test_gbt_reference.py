"""research/gbt_reference.py's training rows, built in place in chunks, against the plain np.hstack they replace."""

import h5py
import numpy as np
import pytest

from research.gbt_reference import training_rows


@pytest.mark.parametrize("with_geometry", [True, False])
def test_training_rows_equal_the_hstack_of_the_committed_rows(tmp_path, with_geometry):
    rng = np.random.default_rng(0)
    z = rng.normal(size=(7, 3)).astype(np.float32)
    geo = rng.normal(size=(7, 2, 2)).astype(np.float32)
    with h5py.File(tmp_path / "dc.h5", "w") as f:
        f["z"] = z
        if with_geometry:
            f["geometry"] = geo
    with h5py.File(tmp_path / "dc.h5", "r") as f:
        x = training_rows(f, 5, chunk=2)  # chunks of 2 over 5 committed rows of 7: the last chunk is short
    want = np.hstack([z[:5], geo[:5].reshape(5, -1)]) if with_geometry else z[:5]
    assert x.dtype == np.float64 and x.flags.c_contiguous
    np.testing.assert_array_equal(x, want.astype(np.float64))
