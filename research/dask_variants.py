"""dask pool settings against the local pool, side by side: ``python -m research.dask_variants [VARIANT...]``.

Variants: ``default`` (the pool's settings), ``notimeout`` (no chunk timeout, so no start events), ``inflight4``
(4 chunks in flight per worker thread instead of 2), ``chunk64`` (64 meshes per chunk instead of 32). Each
variant: a local pool (2 processes) and a dask LocalCluster (2 processes x 1 thread) label the 71 SCAPE meshes
repeated 8 times, 4 interleaved reps after a warm-up; prints local time / dask time per rep and the median
(``dask_vs_pool`` of ``python -m bench.run --only dask``). Used for the note on dask's speed (dask_vs_pool 0.77-0.80):
none of the variants was a measured improvement (the reps spread more than the variants differ).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

VARIANTS = ("default", "notimeout", "inflight4", "chunk64")


def ratio(variant: str, reps: int = 4) -> list[float]:
    """Local-pool seconds / dask seconds for ``reps`` interleaved labelings of 568 SCAPE meshes."""
    import neuralcol.collision.pool_dask as pool_dask
    from bench.context import scape_config
    from neuralcol.collision.labeler import ExactLabeler
    from neuralcol.collision.pool import LabelPool
    from neuralcol.pipeline import RunContext

    ds = RunContext(scape_config()).dataset  # SCAPE from paths.data_dir (NEURALCOL_DATA)
    verts = ds.vertices.numpy().astype(np.float64)
    batch = np.concatenate([verts] * 8)
    lab = ExactLabeler(ds.faces.numpy(), verts[0])
    kw: dict = {"chunk_size": 64 if variant == "chunk64" else 32}
    if variant == "notimeout":
        kw["timeout"] = None
    saved = pool_dask.IN_FLIGHT_PER_THREAD
    if variant == "inflight4":
        pool_dask.IN_FLIGHT_PER_THREAD = 4
    try:
        with LabelPool(lab, workers=2, chunk_size=32) as local, LabelPool(lab, executor="dask", workers=2, **kw) as dp:
            local.label(batch)
            dp.label(batch)
            out = []
            for _ in range(reps):
                t0 = time.perf_counter()
                local.label(batch)
                tl = time.perf_counter() - t0
                t0 = time.perf_counter()
                dp.label(batch)
                out.append(tl / (time.perf_counter() - t0))
            return out
    finally:
        pool_dask.IN_FLIGHT_PER_THREAD = saved


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("variants", nargs="*", metavar="VARIANT", help=f"some of {', '.join(VARIANTS)} (default: all)")
    args = ap.parse_args(argv)
    unknown = [v for v in args.variants if v not in VARIANTS]
    if unknown:
        ap.error(f"unknown variant {unknown[0]!r}; use some of {', '.join(VARIANTS)}")
    for name in args.variants or list(VARIANTS):
        r = ratio(name)
        print(f"{name:10s} dask_vs_pool per rep {np.round(r, 3).tolist()}, median {np.median(r):.3f}", flush=True)


if __name__ == "__main__":
    main()
