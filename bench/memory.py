"""``memory``: peak resident memory while labeling decoded SCAPE samples, and the size of D_c on disk."""

from __future__ import annotations

import os
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import torch

from bench.context import BenchContext
from bench.timing import summarize


def tree_rss_mb(pid: int) -> float:
    """Resident memory of a process and its descendants (Linux /proc), MB."""
    total, stack = 0, [pid]
    while stack:
        p = stack.pop()
        try:
            with open(f"/proc/{p}/status") as f:
                for line in f:
                    if line.startswith("VmRSS:"):
                        total += int(line.split()[1])
                        break
            with open(f"/proc/{p}/task/{p}/children") as f:
                stack += [int(c) for c in f.read().split()]
        except (FileNotFoundError, ProcessLookupError):
            continue
    return total / 1024


def measure(ctx: BenchContext) -> dict:
    """Peak resident memory (this process + its 2 workers) while labeling decoded SCAPE samples, and the size
    of the HDF5 D_c per 10 000 rows."""
    from neuralcol import load_run
    from neuralcol.collision.backends import build_labeler
    from neuralcol.samples.store import CollisionStore

    run = load_run(ctx.trained_run())
    cfg, space = run.cfg, run.space
    pipeline = run.context()
    labeler = build_labeler(cfg.labeling, space.faces.numpy(), space.rest_vertices.numpy(),
                            partition=space.partition.numpy())
    n = 2000 if ctx.quick else 10_000
    z = space.sample(n, generator=torch.Generator().manual_seed(1))
    peak, stop = [0.0], threading.Event()

    def watch():
        while not stop.is_set():
            peak[0] = max(peak[0], tree_rss_mb(os.getpid()))
            time.sleep(0.1)

    before = tree_rss_mb(os.getpid())
    t = threading.Thread(target=watch, daemon=True)
    t.start()
    t0 = time.perf_counter()
    # LabelPool's own settings (2 local workers, chunks of 32, no chunk timeout), not the run's labeling.pool
    with pipeline.pool(labeler, executor="local", scheduler=None, workers=2, chunk_size=32, timeout=None,
                       max_restarts=10, progress=False) as pool:
        lab = pipeline.oracle(pool)(z, desc="bench")
    seconds = time.perf_counter() - t0
    stop.set()
    t.join()
    with tempfile.TemporaryDirectory() as tmp:
        store = CollisionStore(Path(tmp) / "dc.h5", space.dim, space.n_parts)
        store.append(lab.z, lab.pd, lab.pd_sub, lab.collides, lab.subset, 0, np.zeros(len(lab.z)))
        store.close()
        size_mb = (Path(tmp) / "dc.h5").stat().st_size / 2 ** 20
    ctx.notes["memory"] = (f"{n} uniform SCAPE codes decoded and labeled by LabelPool(workers=2) in "
                           f"{seconds:.0f} s; RSS of this process and its workers sampled every 0.1 s "
                           f"({before:.0f} MB before labeling)")
    return {"label_peak_rss_mb": summarize([peak[0]]), "dc_mb_per_10k": summarize([size_mb * 10_000 / n]),
            "label_oracle_per_s": summarize([n / seconds])}
