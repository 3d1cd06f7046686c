"""``pipeline``: labels per second of the exact oracle, codes in and labels out (decode in this process, labels on
the label pool), with 1 and 2 label workers interleaved, on U(Z) codes of the trained SCAPE run's latent space;
and the same codes' decode alone and label alone per sample on one core (what ``exact_ms_per_sample`` adds up)."""

from __future__ import annotations

import time

import numpy as np
import torch

from bench.context import BenchContext, where
from bench.timing import repeat, repeat_interleaved, summarize


def measure(ctx: BenchContext) -> dict:
    """The oracle's labels per second (decode + label) on 1 and 2 workers, and its per-sample parts."""
    from neuralcol import load_run
    from neuralcol.samples.oracle import LatentOracle

    run_dir = ctx.trained_run()
    run = load_run(run_dir)
    ctx_run = run.context()
    space = run.space
    n = 64 if ctx.quick else 256
    z = space.sample(n, generator=torch.Generator().manual_seed(1))
    labeler = ctx_run.sample_labeler()
    reps = 3 if ctx.quick else 5
    out: dict = {}
    with ctx_run.pool(labeler, workers=1, progress=False) as one, ctx_run.pool(labeler, workers=2,
                                                                               progress=False) as two:
        o1, o2 = LatentOracle(space, one), LatentOracle(space, two)
        o1(z[:4])
        o2(z[:16])  # start the workers outside the timing
        t1, t2 = repeat_interleaved(lambda: o1(z), lambda: o2(z), reps)
    out["pipeline_labels_per_s_1"] = summarize([n / t for t in t1])
    out["pipeline_labels_per_s_2"] = summarize([n / t for t in t2])
    out["pipeline_speedup_2_workers"] = summarize([a / b for a, b in zip(t1, t2)])
    # its parts on one core: decode (batched, as the oracle does) and the exact label of each decoded mesh
    ze = z[: 16 if ctx.quick else 48]
    with torch.no_grad():
        verts = space.decode(ze).double().numpy()
    labeler.label(verts[0])
    with torch.no_grad():
        dec = repeat(lambda: space.decode(ze), reps)
    lab = repeat(lambda: [labeler.label(v) for v in verts], reps)
    out["pipeline_decode_ms_per_sample"] = summarize(dec, 1e3 / len(ze))
    out["pipeline_label_ms_per_sample"] = summarize(lab, 1e3 / len(ze))
    colliding = float(np.mean([labeler.label(v).collides for v in verts]))
    ctx.notes["pipeline"] = (f"latent space and labeler of {where(run_dir)} ({space.n_parts} parts, {space.dim} "
                             f"entries); {n} U(Z) codes (seed 1), LatentOracle with LabelPool(workers=1) and "
                             f"(workers=2) interleaved, {reps} reps; parts on {len(ze)} codes, "
                             f"{colliding:.0%} colliding; torch threads {torch.get_num_threads()}; "
                             f"{time.strftime('%H:%M')}")
    return out
