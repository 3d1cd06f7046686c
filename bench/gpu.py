"""``gpu``: the batched Warp labeler (``labeling=gpu``) on perturbed SCAPE poses, and its agreement with the exact
CPU labeler."""

from __future__ import annotations

import time

import numpy as np
import torch

from bench.context import BenchContext
from bench.timing import repeat, scalar, summarize


def measure(ctx: BenchContext) -> dict:
    """Batched Warp labeler (labeling=gpu): labels per second on a batch of perturbed SCAPE poses, and its
    agreement with the exact CPU labeler on every pose (verdict and pair count, max |PD - PD_cpu| / diag).

    On a CUDA device the rate is ``gpu_labels_per_s``; without one Warp runs the same kernels on the CPU (one
    thread) and the rate is ``gpu_labels_per_s_cpu_device``. ``gpu_ref_cpu_labels_per_s`` is the numba labeler
    on the same poses, one process.
    """
    import warp as wp

    from neuralcol.collision.labeler import ExactLabeler, Labels
    from neuralcol.collision.warp_labeler import WarpLabeler, default_device

    ds = ctx.scape
    verts = ds.vertices.numpy().astype(np.float64)
    faces = ds.faces.numpy()
    device = default_device()
    on_cuda = not wp.get_device(device).is_cpu
    n = 512 if (on_cuda or not ctx.quick) else 256
    reps = ctx.reps if on_cuda else (2 if ctx.quick else 3)
    # the 71 poses repeated, each moved a random 0-50 % of the way towards another pose (a mix of free and
    # colliding poses, as a sampler near the data produces)
    rng = np.random.default_rng(0)
    i = np.arange(n) % len(verts)
    j = rng.integers(0, len(verts), n)
    t = rng.uniform(0.0, 0.5, n)
    poses = verts[i] + t[:, None, None] * (verts[j] - verts[i])
    part = (np.arange(len(verts[0])) * 4) // len(verts[0])  # 4 blocks of vertices: PD_i is compared too
    gl = WarpLabeler(faces, verts[0], partition=part, device=device)
    ref = ExactLabeler(faces, verts[0], partition=part)
    gl.label_batch(poses[:2])  # compile / load the kernels outside the timing
    ref.label(poses[0])
    if on_cuda:
        poses_dev = torch.as_tensor(poses, device=wp.device_to_torch(device))  # the batch stays on the device

        def run():
            gl.label_batch(poses_dev)
            wp.synchronize_device(device)
    else:
        def run():
            gl.label_batch(poses)
    times = repeat(run, reps, warmup=1 if on_cuda else 0)
    got = gl.label_batch(poses)
    t0 = time.perf_counter()
    want = Labels.stack([ref.label(v) for v in poses], ref.n_parts)
    t_ref = time.perf_counter() - t0
    same = (got.collides == want.collides) & (got.n_pairs == want.n_pairs)
    err = max(np.abs(got.pd - want.pd).max(), np.abs(got.pd_sub - want.pd_sub).max()) / ref.diag
    key = "gpu_labels_per_s" if on_cuda else "gpu_labels_per_s_cpu_device"
    ctx.notes["gpu"] = (f"device {device} ({wp.get_device(device).name}), {n} poses, "
                        f"{int(want.collides.sum())} colliding, partition of 4 blocks")
    return {key: summarize([n / s for s in times]),
            "gpu_ref_cpu_labels_per_s": scalar(n / t_ref),
            "gpu_vs_cpu_max_pd_err": scalar(err),
            "gpu_verdict_agreement": scalar(same.mean()),
            "gpu_colliding_fraction": scalar(want.collides.mean())}
