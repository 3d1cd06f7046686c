"""``pool``: labels per second of LabelPool with 1 and 2 workers on the same 142 SCAPE meshes, interleaved."""

from __future__ import annotations

import numpy as np

from bench.context import BenchContext
from bench.timing import repeat_interleaved, summarize


def measure(ctx: BenchContext) -> dict:
    """Labels per second of LabelPool with 1 and 2 workers on the same 142 SCAPE meshes, interleaved."""
    from neuralcol.collision.labeler import ExactLabeler
    from neuralcol.collision.pool import LabelPool

    ds = ctx.scape
    verts = ds.vertices.numpy().astype(np.float64)
    batch = np.concatenate([verts, verts])
    lab = ExactLabeler(ds.faces.numpy(), verts[0])
    reps = 3 if ctx.quick else 5
    with LabelPool(lab, workers=1, chunk_size=8) as one, LabelPool(lab, workers=2, chunk_size=8) as two:
        one.label(batch[:4])
        two.label(batch[:16])  # start the worker processes outside the timing
        t1, t2 = repeat_interleaved(lambda: one.label(batch), lambda: two.label(batch), reps)
    n = len(batch)
    r1 = summarize([n / t for t in t1])
    r2 = summarize([n / t for t in t2])
    return {"pool_labels_per_s_1": r1, "pool_labels_per_s_2": r2,
            "pool_speedup": summarize([a / b for a, b in zip(t1, t2)])}
