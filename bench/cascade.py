"""``cascade``: the certified cascade end to end (``run.detect(codes, certify=t)``: detector, then decode + exact
label of the band's codes in this process) against the exact path alone (decode + exact label of every code), on
the same U(Z) codes of a finished SCAPE run with a calibration set (``cascade.npz``), interleaved."""

from __future__ import annotations

import torch

from bench.context import BenchContext, where
from bench.timing import repeat_interleaved, summarize

TARGETS = (0.01, 0.05)


def measure(ctx: BenchContext) -> dict:
    """Samples per second of the cascade per target FNR and of the exact path, side by side."""
    from neuralcol import load_run

    run_dir = ctx.trained_run()
    out: dict = {}
    with load_run(run_dir, workers=0) as run:
        n = 64 if ctx.quick else 256
        z = run.space.sample(n, generator=torch.Generator().manual_seed(2))
        reps = 2 if ctx.quick else 3

        def exact():
            return run.label(run.decode(z).double())

        run.label(run.decode(z[:2]).double())  # the label pool and numba outside the timing
        notes = []
        for t in TARGETS:
            run.detect(z[:2], certify=t)
            share = float(run.detect(z, certify=t).exact.float().mean())
            tc, te = repeat_interleaved(lambda t=t: run.detect(z, certify=t), exact, reps)
            key = f"{t:g}".replace(".", "p")
            out[f"cascade_samples_per_s_fnr_{key}"] = summarize([n / s for s in tc])
            out[f"cascade_vs_exact_fnr_{key}"] = summarize([b / a for a, b in zip(tc, te)])
            out[f"cascade_exact_share_fnr_{key}"] = summarize([share])
            notes.append(f"{t:g}: {share:.0%} exact")
        out["cascade_exact_path_samples_per_s"] = summarize([n / s for s in te])
    ctx.notes["cascade"] = (f"run.detect(codes, certify=t) of {where(run_dir)} (its calibration set and settings) "
                            f"against decode + exact label of the same {n} U(Z) codes (seed 2), in this process "
                            f"(label pool workers=0), {reps} interleaved reps; exact share {', '.join(notes)}")
    return out
