"""Issue 41: the one detector on users' meshes against the exact label of the same meshes, timed side by side.

    python -m research.mesh_speed RUN_DIR [--n 512] [--reps 3]

Meshes: decoded codes of the run's U(Z) box, perturbed by 0.1 % of the diagonal (so they are meshes, not codes).
Times ``run.detect(meshes)`` (encode + the mesh's pair features + the network, eager float32, one batch) and the exact
labeler's verdict and full label (one mesh at a time, this process), torch on one thread; medians of ``reps``.
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

    def median(fn, reps):
        ts = []
        for _ in range(reps):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        return float(np.median(ts))

    t_det = median(lambda: run.detect(v), a.reps) / a.n
    t_ver = median(lambda: [exact.verdict(m) for m in meshes], a.reps) / len(meshes)
    t_lab = median(lambda: [exact.label(m) for m in meshes], a.reps) / len(meshes)
    out = {"run": a.run_dir, "inputs": run.metrics["detector"].get("inputs", "latent"), "n": a.n,
           "detector_us_per_mesh": 1e6 * t_det, "exact_verdict_us": 1e6 * t_ver, "exact_label_us": 1e6 * t_lab,
           "x_verdict": t_ver / t_det, "x_label": t_lab / t_det, "threads": torch.get_num_threads()}
    print(json.dumps(out, indent=2))
    run.close()


if __name__ == "__main__":
    main()
