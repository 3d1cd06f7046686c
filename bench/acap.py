"""``acap``: ACAP encode and decode of all 71 SCAPE meshes (batched), ms per mesh: decode without a graph (the
numba right-hand side, float64 and float32 inputs) and with one (the differentiable torch path)."""

from __future__ import annotations

import torch

from bench.context import BenchContext
from bench.timing import repeat, summarize


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
    # the differentiable path (torch ops; what decode ran without a graph before issue 29), side by side
    graph = repeat(lambda: acap.decode(feats.clone().requires_grad_(True)), reps)
    return {
        "acap_encode_ms": summarize(enc, 1e3 / n),
        "acap_decode_ms": summarize(dec, 1e3 / n),
        "acap_decode_float32_ms": summarize(dec32, 1e3 / n),
        "acap_decode_graph_ms": summarize(graph, 1e3 / n),
    }
