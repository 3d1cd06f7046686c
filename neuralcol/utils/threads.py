"""One thread count for everything a run's numbers depend on (same command, same numbers).

A float sum split over threads is added in another order than the same sum on one thread, so torch's intra-op
reductions (autoencoder and detector training), and BLAS/OpenMP kernels, give other bits on a machine with
another core count; after a few thousand optimizer steps the trained autoencoder is another latent space, with
another test set and other numbers (measured: proc_hand's autoencoder after 40 epochs differs by up to 1.27 in
its weights between ``OMP_NUM_THREADS=1`` and ``=2``). A run therefore pins the count (``threads`` in
``conf/config.yaml``, default 1) instead of taking it from the machine, and the autoencoder cache key records
it.

    pin_threads(1)              # this process, and the worker processes it starts later
    with threads_pinned(1): ... # the same for a block, restored afterwards

``None`` leaves the machine's defaults (faster on many cores; numbers then depend on the core count).
"""

from __future__ import annotations

import os
from contextlib import contextmanager

import torch

# variables the BLAS/OpenMP runtimes of worker processes read when they start (spawned label workers, dask)
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _check(threads) -> int | None:
    if threads is None:
        return None
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"threads: {threads!r} is not a thread count; give a positive integer (the "
                         "default 1 gives the same numbers on every machine) or null for the machine's default")
    return threads


def pin_threads(threads: int | None) -> int | None:
    """Use ``threads`` threads for torch's intra-op work and the BLAS/OpenMP pools of this process, and set the
    environment that worker processes started later read. ``None`` changes nothing. Returns ``threads``."""
    threads = _check(threads)
    if threads is None:
        return None
    torch.set_num_threads(threads)
    for name in THREAD_ENV:
        os.environ[name] = str(threads)
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl comes with scikit-learn
        return threads
    threadpool_limits(threads)  # numpy's and scipy's BLAS, OpenMP runtimes loaded in this process
    return threads


@contextmanager
def threads_pinned(threads: int | None):
    """:func:`pin_threads` for a block; torch's count and the environment are restored afterwards."""
    threads = _check(threads)
    if threads is None:
        yield None
        return
    before = torch.get_num_threads()
    env = {name: os.environ.get(name) for name in THREAD_ENV}
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover
        threadpool_limits = None
    limits = threadpool_limits(threads) if threadpool_limits is not None else None
    try:
        torch.set_num_threads(threads)
        for name in THREAD_ENV:
            os.environ[name] = str(threads)
        yield threads
    finally:
        torch.set_num_threads(before)
        for name, value in env.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        if limits is not None:
            limits.restore_original_limits()
