"""``training_labels``: samples per second of D_c's labels for training as the detector stage makes them
(clearances capped at the targets' floor, codes decoded in the pool's workers) against the path before it (codes
decoded here, full labels on the workers), one 2-worker LabelPool, interleaved, on uniform codes of a finished
SCAPE run's latent space; and whether verdicts, subsets and clipped targets are identical."""

from __future__ import annotations

import numpy as np

from bench.context import BenchContext, where
from bench.timing import ratio, repeat_interleaved, summarize


def measure(ctx: BenchContext) -> dict:
    """Full oracle against the training oracle on the same codes, 2 workers, interleaved repetitions."""
    import torch

    from neuralcol.api.run import load_run
    from neuralcol.collision.pool import LabelPool
    from neuralcol.samples.datamodule import detector_targets
    from neuralcol.samples.oracle import LatentOracle
    from neuralcol.samples.store import CollisionRows
    from neuralcol.samples.uniform import uniform_codes

    run_dir = ctx.trained_run()
    run = load_run(run_dir)
    targets = run.cfg.detector.targets
    floor, clip = float(targets.pd_floor), float(targets.pd_clip)
    n = 300 if ctx.quick else 1000
    z = uniform_codes(run.space, 12345, 0, n)
    with LabelPool(run.labeler, workers=2, chunk_size=32) as pool:
        full = LatentOracle(run.space, pool)
        train = full.for_training(floor)
        full(z[:64])
        train(z[:64])  # workers started and warm outside the timing
        out = {}

        def before():  # the earlier path: decode here, full labels on the workers
            out["full"] = pool.label_report(full.decode(z)).labels

        def now():
            out["train"] = train(z)

        tf, tt = repeat_interleaved(before, now, 3 if ctx.quick else 5)
    a, b = out["full"], out["train"]

    def rows(lab, subset):
        m = len(lab.pd)
        return CollisionRows(z.numpy(), lab.pd, lab.pd_sub, lab.collides, subset, np.zeros(m, np.int16),
                             np.zeros(m, np.int8), np.arange(m))

    sub_a = run.labeler.subsets(a.pd)

    cap = run.labeler.cap
    same_targets = all(torch.equal(x, y) for x, y in zip(detector_targets(rows(a, sub_a), cap, clip, pd_floor=floor),
                                                         detector_targets(rows(b, b.subset), cap, clip,
                                                                          pd_floor=floor)))
    identical = bool(np.array_equal(a.collides, b.collides) and np.array_equal(sub_a, b.subset) and same_targets)
    ctx.notes["training_labels"] = (
        f"{n} uniform codes of {where(run_dir)} (SCAPE), the earlier path (decoded here, full labels; today's "
        f"labeler) against labels for training (clearances capped at {-floor:g} caps, decoded in the workers), "
        f"one 2-worker LabelPool, "
        f"interleaved; verdicts, subsets and clipped targets identical: {identical}; colliding share "
        f"{float(np.mean(a.collides)):.3f}")
    if not identical:
        raise AssertionError("training labels: verdicts, subsets or clipped targets differ from the full labels")
    full_r = summarize([n / t for t in tf])
    train_r = summarize([n / t for t in tt])
    return {"training_labels_full_per_s": full_r, "training_labels_per_s": train_r,
            "training_labels_speedup": ratio(train_r, full_r)}
