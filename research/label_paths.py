"""Labels for training against the labeling path before them, each path on its own code, side by side.

    PYTHONPATH=CHECKOUT python research/label_paths.py before|now RUN_DIR

Labels 1 000 uniform codes (seed 777) of a finished SCAPE run on a 2-worker label pool and prints samples per second
(after a 64-code warm-up that starts and compiles the workers): ``before``, the earlier path (codes decoded in this
process, full labels), run from a checkout of the code before the labels-for-training work (commit 26f0965: its
full label and far pass are the earlier path's); ``now``, the current path (decoded in the workers, clearances capped
at the targets' floor), run from main. Alternate the two a few times (docs/studies/training_labels.md).
"""
import sys

from omegaconf import OmegaConf

import neuralcol
from neuralcol.samples.oracle import LatentOracle
from neuralcol.samples.uniform import uniform_codes

if __name__ == "__main__":
    path, run_dir = sys.argv[1], sys.argv[2]
    with neuralcol.load_run(run_dir, workers=2) as run:
        z = uniform_codes(run.space, 777, 0, 1000)
        pool = run.label_pool()
        full = LatentOracle(run.space, pool)
        floor = OmegaConf.select(run.cfg, "detector.targets.pd_floor")
        full(z[:64])  # workers started and compiled
        import time
        t0 = time.perf_counter()
        if path == "before":
            pool.label_report(full.decode(z))
        else:
            full.for_training(float(floor))(z)
        print(f"{path} {len(z) / (time.perf_counter() - t0):.1f} samples/s")
