"""``dask``: labels per second of LabelPool on a dask LocalCluster against the local pool, interleaved."""

from __future__ import annotations

import numpy as np

from bench.context import BenchContext
from bench.timing import repeat_interleaved, summarize


def measure(ctx: BenchContext) -> dict:
    """Labels per second of LabelPool on a dask LocalCluster (2 worker processes x 1 thread) and of the local pool
    (2 worker processes), interleaved on the 71 SCAPE meshes repeated 8 times (568 meshes), both with the runs'
    chunk size (``labeling.pool.chunk_size``, 32); ``dask_vs_pool``: their ratio."""
    from neuralcol.collision.labeler import ExactLabeler
    from neuralcol.collision.pool import LabelPool

    ds = ctx.scape
    verts = ds.vertices.numpy().astype(np.float64)
    batch = np.concatenate([verts] * 8)
    lab = ExactLabeler(ds.faces.numpy(), verts[0])
    reps = 3 if ctx.quick else 5
    with LabelPool(lab, workers=2, chunk_size=32) as local, \
            LabelPool(lab, executor="dask", workers=2, chunk_size=32) as dask_pool:
        local.label(batch)  # start the workers (and the cluster) and load the kernels outside the timing
        dask_pool.label(batch)
        tl, td = repeat_interleaved(lambda: local.label(batch), lambda: dask_pool.label(batch), reps)
    n = len(batch)
    ctx.notes["dask"] = ("LocalCluster of 2 worker processes x 1 thread on this machine (executor=dask, "
                         "scheduler=null), 568 SCAPE meshes, chunk_size 32, vs the local pool with workers=2; "
                         "target dask_vs_pool >= 0.8")
    return {"dask_labels_per_s": summarize([n / t for t in td]),
            "dask_local_pool_labels_per_s": summarize([n / t for t in tl]),
            "dask_vs_pool": summarize([a / b for a, b in zip(tl, td)])}
