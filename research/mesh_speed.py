"""The one detector on users' meshes against the exact label of the same meshes, timed side by side.

    python -m research.mesh_speed RUN_DIR [--n 512] [--reps 3]

Meshes: decoded codes of the run's U(Z) box, perturbed by 0.1 % of the diagonal (so they are meshes, not codes).
Times ``run.detect(meshes)`` (encode + the mesh's pair features + the network, eager float32, one batch), the same
compiled (``run.detect(meshes, fast="float32")``, :meth:`~neuralcol.nn.fast_inference.FastDetector.on_meshes`) and the
exact labeler's verdict and full label (one mesh at a time, this process), torch on one thread; medians of ``reps``,
the methods round-robin within each repetition.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir")
    ap.add_argument("--n", type=int, default=512)
    ap.add_argument("--n-exact", type=int, default=32)
    ap.add_argument("--reps", type=int, default=3)
    a = ap.parse_args()
    from neuralcol import load_run

    torch.set_num_threads(1)
    run = load_run(a.run_dir)
    g = torch.Generator().manual_seed(0)
    lo, hi = run.space.box_lo.cpu(), run.space.box_hi.cpu()
    z = lo + (hi - lo) * torch.rand(a.n, run.dim, generator=g)
    v = run.decode(z).double()
    v = v + 1e-3 * run.diagonal * torch.randn(v.shape, generator=g, dtype=torch.float64)
    run.detect(v[:8])
    exact = run.labeler
    meshes = v[: a.n_exact].numpy()
    exact.verdict(meshes[0])
    exact.label(meshes[0])

    run.detect(v[:8], fast="float32")  # compiles
    fns = {"detector": lambda: run.detect(v), "compiled": lambda: run.detect(v, fast="float32"),
           "verdict": lambda: [exact.verdict(m) for m in meshes], "label": lambda: [exact.label(m) for m in meshes]}
    per = {"detector": a.n, "compiled": a.n, "verdict": len(meshes), "label": len(meshes)}
    times = {k: [] for k in fns}
    for _ in range(a.reps):  # round-robin: a busy machine slows every method alike
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k].append((time.perf_counter() - t0) / per[k])
    t = {k: float(np.median(v)) for k, v in times.items()}
    out = {"run": a.run_dir, "inputs": run.metrics["detector"].get("inputs", "latent"), "n": a.n,
           "detector_us_per_mesh": 1e6 * t["detector"], "compiled_us_per_mesh": 1e6 * t["compiled"],
           "exact_verdict_us": 1e6 * t["verdict"], "exact_label_us": 1e6 * t["label"],
           "x_verdict": t["verdict"] / t["detector"], "x_label": t["label"] / t["detector"],
           "compiled_x_verdict": t["verdict"] / t["compiled"], "compiled_x_label": t["label"] / t["compiled"],
           "threads": torch.get_num_threads()}
    print(json.dumps(out, indent=2))
    run.close()


if __name__ == "__main__":
    main()
