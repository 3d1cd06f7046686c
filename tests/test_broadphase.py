"""The grid of the labeler's far pass (``sorted_cells``) against the plain grid (``grid_cells``) and brute force."""

import numpy as np
import pytest

from neuralcol.collision.kernels.broadphase import grid_cells, grid_pairs, sorted_cells


def _boxes(n, seed):
    rng = np.random.default_rng(seed)
    lo = rng.uniform(0, 1, (n, 3))
    lo[::7, 0] = lo[3, 0]  # ties in lower x
    return lo, lo + rng.uniform(0.0, 0.08, (n, 3))


@pytest.mark.parametrize("cell", [0.1, 0.004])  # a coarse grid (counting sort) and a huge one (stable argsort)
def test_sorted_cells_holds_the_plain_grids_entries_in_lower_x_order(cell):
    lo, hi = _boxes(300, 0)
    keys, ids, ilo, dims = grid_cells(lo, hi, cell)
    cell_keys, start, ids2, ilo2, dims2 = sorted_cells(lo, hi, cell)
    assert np.array_equal(ilo, ilo2) and np.array_equal(dims, dims2)
    assert start[0] == 0 and start[-1] == len(ids) == len(ids2)
    assert np.all(np.diff(cell_keys) > 0) and np.all(np.diff(start) > 0)
    got = sorted((int(cell_keys[c]), int(f)) for c in range(len(cell_keys)) for f in ids2[start[c]:start[c + 1]])
    assert got == sorted(zip(keys.tolist(), ids.tolist()))
    for c in range(len(cell_keys)):
        f = ids2[start[c]:start[c + 1]]
        order = np.lexsort((f, lo[f, 0]))  # by lower x, ties by box index
        assert np.array_equal(order, np.arange(len(f)))


def test_grid_pairs_equal_brute_force():
    lo, hi = _boxes(200, 1)
    ov = ((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None])).all(-1)
    brute = {(a, b) for a, b in zip(*np.nonzero(np.triu(ov, 1)))}
    assert {tuple(p) for p in grid_pairs(lo, hi, 0.1).tolist()} == brute
