"""``gpu``: the batched Warp labeler (``labeling=gpu``) on perturbed SCAPE poses, and its agreement with the exact
CPU labeler. :func:`compare_labelers` is shared with the GPU kit (``python -m bench.gpu_check``)."""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np
import torch

from bench.context import BenchContext
from bench.timing import repeat_within, scalar, summarize


class LabelerComparison(NamedTuple):
    """The Warp labeler against :class:`~neuralcol.collision.labeler.ExactLabeler` on the same poses.

    ``warp_seconds``: per timed ``label_batch`` call on all ``n`` poses; ``ref_seconds``: the CPU labeler on all of
    them, one process; ``verdict_agreement``: fraction of poses with the same verdict and pair count;
    ``max_pd_err``: largest |PD - PD_cpu| and |PD_i - PD_i_cpu| over the poses, over the bbox diagonal."""

    device: str
    device_name: str
    on_cuda: bool
    n: int
    n_colliding: int
    warp_seconds: list[float]
    ref_seconds: float
    verdict_agreement: float
    max_pd_err: float

    @property
    def warp_labels_per_s(self) -> list[float]:
        return [self.n / s for s in self.warp_seconds]

    @property
    def ref_labels_per_s(self) -> float:
        return self.n / self.ref_seconds


def perturbed_poses(verts: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """(n, V, 3) float64 poses: the data set's (N, V, 3) poses repeated, each moved a random 0-50 % of the way
    towards another pose (a mix of free and colliding poses, as a sampler near the data produces)."""
    rng = np.random.default_rng(seed)
    i = np.arange(n) % len(verts)
    j = rng.integers(0, len(verts), n)
    t = rng.uniform(0.0, 0.5, n)
    return verts[i] + t[:, None, None] * (verts[j] - verts[i])


def compare_labelers(verts: np.ndarray, faces: np.ndarray, n: int, reps: int, device: str | None = None,
                     budget_s: float = math.inf) -> LabelerComparison:
    """Time the Warp labeler on ``n`` perturbed poses of ``verts`` (N, V, 3) (``reps`` calls, fewer once they took
    ``budget_s`` seconds) and compare its labels with the CPU labeler's, pose by pose (partition: 4 blocks of
    vertices, so PD_i is compared too). ``device``: Warp device, None: ``cuda:0`` if there is one, else ``cpu``.
    On CUDA the batch is handed over as a CUDA tensor (it stays on the device) and each call is synchronised."""
    import warp as wp

    from neuralcol.collision.labeler import ExactLabeler, Labels
    from neuralcol.collision.warp_labeler import WarpLabeler, default_device

    device = device or default_device()
    on_cuda = not wp.get_device(device).is_cpu
    poses = perturbed_poses(verts, n)
    part = (np.arange(len(verts[0])) * 4) // len(verts[0])  # 4 blocks of vertices: PD_i is compared too
    gl = WarpLabeler(faces, verts[0], partition=part, device=device)
    ref = ExactLabeler(faces, verts[0], partition=part)
    gl.label_batch(poses[:2])  # compile / load the kernels outside the timing
    ref.label(poses[0])
    batch = torch.as_tensor(poses, device=wp.device_to_torch(device)) if on_cuda else poses  # stays on the device
    last = []

    def run():
        last[:] = [gl.label_batch(batch)]  # the labels of the last timed pass are the ones compared
        wp.synchronize_device(device)

    times = repeat_within(run, reps, budget_s, warmup=1 if on_cuda else 0)
    got = last[0]
    t0 = time.perf_counter()
    want = Labels.stack([ref.label(v) for v in poses], ref.n_parts)
    t_ref = time.perf_counter() - t0
    same = (got.collides == want.collides) & (got.n_pairs == want.n_pairs)
    err = max(np.abs(got.pd - want.pd).max(), np.abs(got.pd_sub - want.pd_sub).max()) / ref.diag
    return LabelerComparison(device, wp.get_device(device).name, on_cuda, n, int(want.collides.sum()), times, t_ref,
                             float(same.mean()), float(err))


def measure(ctx: BenchContext) -> dict:
    """Batched Warp labeler (labeling=gpu): labels per second on a batch of perturbed SCAPE poses, and its
    agreement with the exact CPU labeler on every pose (verdict and pair count, max |PD - PD_cpu| / diag).

    On a CUDA device the rate is ``gpu_labels_per_s``; without one Warp runs the same kernels on the CPU (one
    thread) and the rate is ``gpu_labels_per_s_cpu_device``. ``gpu_ref_cpu_labels_per_s`` is the numba labeler
    on the same poses, one process.
    """
    import warp as wp

    from neuralcol.collision.warp_labeler import default_device

    ds = ctx.scape
    on_cuda = not wp.get_device(default_device()).is_cpu
    n = 512 if (on_cuda or not ctx.quick) else 256
    reps = ctx.reps if on_cuda else (2 if ctx.quick else 3)
    c = compare_labelers(ds.vertices.numpy().astype(np.float64), ds.faces.numpy(), n, reps)
    key = "gpu_labels_per_s" if c.on_cuda else "gpu_labels_per_s_cpu_device"
    ctx.notes["gpu"] = (f"device {c.device} ({c.device_name}), {c.n} poses, {c.n_colliding} colliding, "
                        "partition of 4 blocks")
    return {key: summarize(c.warp_labels_per_s),
            "gpu_ref_cpu_labels_per_s": scalar(c.ref_labels_per_s),
            "gpu_vs_cpu_max_pd_err": scalar(c.max_pd_err),
            "gpu_verdict_agreement": scalar(c.verdict_agreement),
            "gpu_colliding_fraction": scalar(c.n_colliding / c.n)}
