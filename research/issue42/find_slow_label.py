"""Find the codes of a seed's uniform sequence whose training label is slow (issue 42, round 4 of neuralcol_s0:
a chunk of rows 295480:297528 hung past the pool's 600 s timeout).

``PYTHONPATH=. python research/issue42/find_slow_label.py RUN_DIR START STOP [--limit-s 30]``

Decodes rows START:STOP of the run's uniform sequence (seed from the run's config) and labels them one at a time
in a child process, as the pool's workers do (``label_code_chunk`` with the training clearance limit); prints
each mesh that takes over 1 s, and the one the child is stuck on when it passes ``--limit-s`` (then killed).
The stuck mesh's vertices are saved to ``--out`` (npz) for a test case.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf


def child(run_dir: str, start: int, stop: int, queue) -> None:
    torch.set_num_threads(1)
    from neuralcol.pipeline import RunContext
    from neuralcol.samples.oracle import SpaceDecoder, training_clearance_limit
    from neuralcol.samples.uniform import uniform_codes

    cfg = OmegaConf.load(Path(run_dir) / ".hydra" / "config.yaml")
    pipe = RunContext(cfg)
    space = pipe.space
    labeler = pipe.sample_labeler()
    limit = training_clearance_limit(float(labeler.cap), float(cfg.detector.targets.pd_floor))
    codes = uniform_codes(space, int(cfg.seed), start, stop)
    verts = SpaceDecoder(space)(codes.numpy())
    queue.put(("ready", limit, None))
    for i, v in enumerate(verts):
        queue.put(("start", start + i, v))
        t0 = time.perf_counter()
        lab = labeler.label_limited(v, clearance_limit=limit)
        queue.put(("done", start + i, (time.perf_counter() - t0, bool(lab.collides), float(lab.pd))))
    queue.put(("end", None, None))


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir")
    ap.add_argument("start", type=int)
    ap.add_argument("stop", type=int)
    ap.add_argument("--limit-s", type=float, default=30.0)
    ap.add_argument("--out", default="outputs/issue42/slow_mesh.npz")
    a = ap.parse_args()
    q = mp.get_context("spawn").Queue()
    p = mp.get_context("spawn").Process(target=child, args=(a.run_dir, a.start, a.stop, q), daemon=True)
    p.start()
    current, cur_v, t_start = None, None, time.monotonic()
    while True:
        try:
            kind, i, x = q.get(timeout=max(0.1, a.limit_s - (time.monotonic() - t_start)))
        except Exception:
            if current is None:
                print("child not ready", flush=True)
                return 1
            print(f"row {current}: still labeling after {a.limit_s:g} s; killed", flush=True)
            Path(a.out).parent.mkdir(parents=True, exist_ok=True)
            np.savez(a.out, vertices=cur_v, row=current)
            p.kill()
            return 0
        if kind == "ready":
            print(f"decoded rows {a.start}:{a.stop}; clearance limit {i:.6g}", flush=True)
        elif kind == "start":
            current, cur_v, t_start = i, x, time.monotonic()
        elif kind == "done":
            if x[0] > 1.0:
                print(f"row {i}: {x[0]:.2f} s collides={x[1]} pd={x[2]:.4g}", flush=True)
        elif kind == "end":
            print("all labeled", flush=True)
            return 0


if __name__ == "__main__":
    raise SystemExit(main())
