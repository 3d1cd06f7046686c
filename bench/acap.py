"""``acap``: ACAP encode and decode of all 71 SCAPE meshes (batched), ms per mesh: decode without a graph (the
default torch path, float64 and float32 inputs), the opt-in numba right-hand side (``fast=True``), one mesh at a
time (float32, the per-sample path), and only 256 chosen vertices (``decode_vertices``, float32)."""

from __future__ import annotations

import torch

from bench.context import BenchContext
from bench.timing import repeat, repeat_interleaved, summarize


def measure(ctx: BenchContext) -> dict:
    """ACAP encode and decode of all 71 SCAPE meshes (batched), ms per mesh."""
    from neuralcol import ACAP

    ds = ctx.scape
    verts = ds.vertices.to(torch.float64)
    acap = ACAP(verts[0], ds.faces)
    n = len(verts)
    reps = ctx.reps
    enc = repeat(lambda: acap.encode(verts), reps)
    feats = acap.encode(verts)
    with torch.no_grad():
        dec = repeat(lambda: acap.decode(feats), reps)
    feats32 = feats.float()
    with torch.no_grad():
        dec32 = repeat(lambda: acap.decode(feats32), reps)
    # the opt-in numba right-hand side (decode(..., fast=True)), side by side with the default
    with torch.no_grad():
        fast = repeat(lambda: acap.decode(feats, fast=True), reps)
    # one mesh at a time against the batch, and 256 chosen vertices (same features, float32), call by call
    idx = torch.randperm(acap.n_vertices, generator=torch.Generator().manual_seed(0))[:256].numpy()
    acap.decode_vertices(feats32[:1], idx)  # the selector is built once per index set, outside the timing
    with torch.no_grad():
        single, chosen = repeat_interleaved(lambda: [acap.decode(f) for f in feats32],
                                            lambda: acap.decode_vertices(feats32, idx), reps)
    return {
        "acap_encode_ms": summarize(enc, 1e3 / n),
        "acap_decode_ms": summarize(dec, 1e3 / n),
        "acap_decode_float32_ms": summarize(dec32, 1e3 / n),
        "acap_decode_fast_ms": summarize(fast, 1e3 / n),
        "acap_decode_single_ms": summarize(single, 1e3 / n),
        "acap_decode_vertices_256_ms": summarize(chosen, 1e3 / n),
    }
