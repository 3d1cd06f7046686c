"""``acap``: ACAP encode and decode of all 71 SCAPE meshes (batched), ms per mesh: decode without a graph (the
default torch path, float64 and float32 inputs) and the opt-in numba right-hand side (``fast=True``)."""

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
    # the opt-in numba right-hand side (decode(..., fast=True)), side by side with the default
    with torch.no_grad():
        fast = repeat(lambda: acap.decode(feats, fast=True), reps)
    return {
        "acap_encode_ms": summarize(enc, 1e3 / n),
        "acap_decode_ms": summarize(dec, 1e3 / n),
        "acap_decode_float32_ms": summarize(dec32, 1e3 / n),
        "acap_decode_fast_ms": summarize(fast, 1e3 / n),
    }
