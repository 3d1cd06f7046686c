"""One detector training step with the ranking term as before (boolean indexing of the (B, B) pair matrix) and as
now (a masked sum), interleaved in one process so that load on the machine hits both alike:
``PYTHONPATH=. python research/paper_scale/train_step_bench.py [DETECTOR_PT] [--batch 1024] [--reps 8]``.

The detector defaults to the shipped SCAPE model's (``pretrained/scape/detector.pt``: the detector over code and
mesh); inputs are random codes in its box and random pair features, targets random (the step's cost does not depend
on their values). Prints the median milliseconds of a step (forward, loss, backward, Adam) of each and their ratio.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
import torch.nn.functional as F

from neuralcol.nn.detector import detector_losses, load_detector, smooth_max


def indexed_losses(out, pd, pd_sub, subset, **kw):
    """detector_losses with the ranking term taken by boolean indexing (the earlier form)."""
    agg = smooth_max(out.s, kw["temperature"])
    less = pd[:, None] < pd[None, :]
    l_r = F.relu(kw["margin"] - (agg[None, :] - agg[:, None]))[less].mean()
    return detector_losses(out, pd, pd_sub, subset, **{**kw, "w_r": 0.0}).total + kw["w_r"] * l_r


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("detector", nargs="?", default="pretrained/scape/detector.pt")
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--reps", type=int, default=8)
    ap.add_argument("--steps", type=int, default=10)
    a = ap.parse_args(argv)
    torch.manual_seed(0)
    net, _ = load_detector(a.detector)
    b = a.batch
    z = (torch.rand(b, net.latent_dim) * 2 - 1) * net.half_range + net.center
    geo = () if net.geometry is None else (torch.randn(b, net.geometry.n_pairs, 3),)
    pd, pd_sub = torch.randn(b) * 0.2, torch.randn(b, net.n_components) * 0.2
    subset = torch.randint(0, 3, (b,))
    kw = dict(w_pd=5.0, w_pdsum=0.2, w_r=2.0, w_ce=2.0, w_b=0.5, margin=0.01, temperature=0.1)
    opt = torch.optim.Adam(net.parameters(), 1e-3)

    def step(now: bool) -> None:
        out = net(z, *geo)
        loss = detector_losses(out, pd, pd_sub, subset, **kw).total if now else indexed_losses(out, pd, pd_sub,
                                                                                               subset, **kw)
        opt.zero_grad()
        loss.backward()
        opt.step()

    ms = {False: [], True: []}
    for _ in range(a.reps):
        for now in (False, True):
            t = time.perf_counter()
            for _ in range(a.steps):
                step(now)
            ms[now].append((time.perf_counter() - t) / a.steps * 1e3)
    before, after = statistics.median(ms[False]), statistics.median(ms[True])
    print(f"batch {b}: indexed {before:.1f} ms/step, masked sum {after:.1f} ms/step, ratio {before / after:.2f}x "
          f"({torch.get_num_threads()} threads)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
