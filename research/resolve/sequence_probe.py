"""Resolve on motions: a motion of interpolated SCAPE frames with collisions, resolved as a sequence and frame by frame.

    PYTHONPATH=. python research/resolve/sequence_probe.py RUN_DIR [--frames 50] [--t0 -0.4] [--t1 1.4]
        [--min-colliding 10] [--seed 0] [--set handler.repair.method=untangle ...] [--out FILE.json]

Frames: ACAP interpolation ``(1 - t) f_a + t f_b`` of two of the data set's meshes, ``t`` from ``t0`` to ``t1`` in
``frames`` steps, decoded by the data set's ACAP transform (no autoencoder); the first pair (pairs drawn with
``seed``) with at least ``min-colliding`` colliding frames by the exact label is kept. Then
``TrainedRun.resolve_sequence`` and, beside it, ``TrainedRun.resolve`` of all frames at once (each frame alone).
Prints and writes: colliding frames in, frames free after, the correction's largest frame-to-frame change against
the input's (the bar: ratio <= 2), median and largest displacement (fractions of the diagonal), seconds.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch
from omegaconf import OmegaConf

import neuralcol
from neuralcol.handler.sequence import frame_jumps


def frames_with_collisions(run, n_frames, t0, t1, min_colliding, seed):
    ctx = run.context()
    feats = ctx.features
    f = feats.features.double()
    rng = np.random.default_rng(seed)
    t = torch.linspace(t0, t1, n_frames, dtype=torch.float64)[:, None, None]
    for _ in range(200):
        a, b = (int(i) for i in rng.choice(len(f), 2, replace=False))
        with torch.no_grad():
            x = feats.acap.decode((1 - t) * f[a] + t * f[b]).numpy().astype(np.float64)
        hit = run.label(x).collides
        if hit.sum() >= min_colliding:
            return x, hit, (a, b)
    raise SystemExit(f"no pair with {min_colliding} colliding frames among 200 draws")


def summary(x, out, collides, diag, seconds):
    corr = out - x
    moved = np.linalg.norm(corr, axis=-1) / diag
    ci, ii = frame_jumps(corr), frame_jumps(x)
    return {"frames_free": int((~collides).sum()), "frames": len(x), "jump_ratio": float(ci.max() / ii.max()),
            "correction_jump_max_frac": float(ci.max() / diag), "input_jump_max_frac": float(ii.max() / diag),
            "median_displacement_frac": float(np.median(np.median(moved, 1))),
            "largest_displacement_frac": float(moved.max()), "seconds": seconds}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir")
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--t0", type=float, default=-0.4)
    ap.add_argument("--t1", type=float, default=1.4)
    ap.add_argument("--min-colliding", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--out")
    a = ap.parse_args()
    run = neuralcol.load_run(a.run_dir)
    for kv in a.set:
        k, v = kv.split("=", 1)
        OmegaConf.update(run.cfg, k, OmegaConf.create({"v": v})["v"] if v not in ("true", "false") else v == "true")
    x, hit, pair = frames_with_collisions(run, a.frames, a.t0, a.t1, a.min_colliding, a.seed)
    print(f"pair {pair}: {int(hit.sum())} of {len(x)} frames collide", flush=True)
    diag = run.diagonal
    t = time.perf_counter()
    seq = run.resolve_sequence(x)
    report = {"pair": pair, "colliding_in": int(hit.sum()), "overrides": a.set,
              "sequence": summary(x, seq.vertices, seq.collides, diag, time.perf_counter() - t)}
    report["sequence"]["frames_resolved"] = int(seq.resolved.sum())
    t = time.perf_counter()
    alone = run.resolve(x)
    out = alone.vertices.cpu().numpy()
    report["frame_by_frame"] = summary(x, out, run.label(out).collides, diag, time.perf_counter() - t)
    for k in ("sequence", "frame_by_frame"):
        r = report[k]
        print(f"{k}: {r['frames_free']}/{r['frames']} free, jump ratio {r['jump_ratio']:.2f} (correction "
              f"{100 * r['correction_jump_max_frac']:.2f} % vs input {100 * r['input_jump_max_frac']:.2f} % of the "
              f"diagonal), median displacement {100 * r['median_displacement_frac']:.3f} %, largest "
              f"{100 * r['largest_displacement_frac']:.2f} %, {r['seconds']:.0f} s", flush=True)
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(report, fh, indent=1)


if __name__ == "__main__":
    main()
