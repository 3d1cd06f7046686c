"""Detector forward, side by side: CP on the concatenation [S_0, part_i] (the paper's form, in one block: the
code before the split) against CP with its first layer split (``CollisionDetector._cp``: the S_0 half once per
sample), in one block and in row blocks of ``CollisionDetector.inference_block`` (the default).

    python -m research.detector_forward RUN_DIR [--batch 4096] [--repeats 30] [--threads 2] [--out FILE]
    python -m research.detector_forward RUN_DIR --fast-blocks 512 1024 2048 [--batch 4096]   # FastDetector blocks

All forms run on the same detector (``RUN_DIR/detector.pt``) and the same codes, alternating repeat by repeat so
that a noisy machine slows both alike; prints (and with ``--out`` writes as JSON) the median microseconds per
sample of each, their ratios to the first, and checks that they give the same probabilities.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from bench.neural import concat_forward  # the paper's concatenated forward, also timed by `python -m bench.run`
from neuralcol.nn.detector import CollisionDetector, load_detector
from neuralcol.rundir import RunDir


def _split_one_block(net: CollisionDetector, z: torch.Tensor) -> torch.Tensor:
    net.inference_block = None  # this instance only (shadows the class attribute)
    try:
        return net(z).prob
    finally:
        del net.inference_block


def interleaved(forms: dict, batch: int, repeats: int, warmup: int) -> dict[str, list[float]]:
    """µs per sample of each call in ``forms`` (name -> callable on a batch of ``batch`` rows), the forms
    alternating call by call so that a noisy machine slows them alike; ``warmup`` untimed rounds first."""
    times: dict[str, list[float]] = {name: [] for name in forms}
    with torch.inference_mode():
        for _ in range(warmup):
            for f in forms.values():
                f()
        for _ in range(repeats):
            for name, f in forms.items():
                t0 = time.perf_counter()
                f()
                times[name].append((time.perf_counter() - t0) / batch * 1e6)
    return times


def compare(net: CollisionDetector, batch: int, repeats: int, seed: int = 0) -> dict:
    """Median µs per sample of each form at ``batch`` and the largest probability difference to the first."""
    gen = torch.Generator().manual_seed(seed)
    lo, hi = net.center - net.half_range, net.center + net.half_range
    z = lo + (hi - lo) * torch.rand(batch, net.latent_dim, generator=gen)
    forms = {"concat": lambda: concat_forward(net, z), "split": lambda: _split_one_block(net, z),
             "split_blocked": lambda: net(z).prob}
    with torch.inference_mode():
        ref = forms["concat"]()
        diff = max(float((f() - ref).abs().max()) for f in forms.values())
    times = interleaved(forms, batch, repeats, warmup=3)
    med = {name: float(np.median(t)) for name, t in times.items()}
    return {"batch": batch, "repeats": repeats, "threads": torch.get_num_threads(),
            "block": net.inference_block, **{f"{k}_us_per_sample": v for k, v in med.items()},
            "split_speedup": med["concat"] / med["split"],
            "split_blocked_speedup": med["concat"] / med["split_blocked"],
            "max_prob_difference": diff}


def compare_fast_blocks(net: CollisionDetector, batch: int, repeats: int, blocks: list[int],
                        seed: int = 0) -> dict:
    """Median µs per sample of the eager forward and of :class:`~neuralcol.nn.fast_inference.FastDetector`
    (compiled, float32 and bfloat16) at each block size, interleaved call by call; ``*_speedup``: eager / form,
    the median of the per-call ratios."""
    from neuralcol.nn.fast_inference import FastDetector

    gen = torch.Generator().manual_seed(seed)
    lo, hi = net.center - net.half_range, net.center + net.half_range
    z = lo + (hi - lo) * torch.rand(batch, net.latent_dim, generator=gen)
    forms = {"eager": lambda: net(z).prob}
    for dtype in ("float32", "bfloat16"):
        for block in blocks:
            fast = FastDetector(net, dtype, compile=True, block=block)
            forms[f"{dtype}_{block}"] = lambda f=fast: f(z).prob
    times = interleaved(forms, batch, repeats, warmup=2)
    row = {"batch": batch, "repeats": repeats, "threads": torch.get_num_threads()}
    for name, t in times.items():
        row[f"{name}_us_per_sample"] = float(np.median(t))
        if name != "eager":
            row[f"{name}_speedup"] = float(np.median(np.array(times["eager"]) / np.array(t)))
    return row


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="run directory with detector.pt")
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 4096])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--fast-blocks", type=int, nargs="+", default=None,
                    help="instead: time FastDetector (float32, bfloat16) at these block sizes against eager")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    net, _ = load_detector(RunDir(args.run).detector)
    net.eval()
    if args.fast_blocks:
        rows = [compare_fast_blocks(net, b, args.repeats, args.fast_blocks) for b in args.batch]
        for r in rows:
            print(f"batch {r['batch']}, {r['threads']} threads, {r['repeats']} interleaved repeats: eager "
                  f"{r['eager_us_per_sample']:.3f} µs/sample")
            for dtype in ("float32", "bfloat16"):
                print("  " + dtype + ": " + ", ".join(f"block {b} {r[f'{dtype}_{b}_us_per_sample']:.3f} "
                                                    f"({r[f'{dtype}_{b}_speedup']:.2f}x)" for b in args.fast_blocks))
        if args.out:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps({"run": str(args.run), "rows": rows}, indent=1))
        return
    rows = [compare(net, b, args.repeats if b > 1 else 20 * args.repeats) for b in args.batch]
    doc = {"run": str(args.run), "n_parameters": sum(p.numel() for p in net.parameters()), "rows": rows}
    for r in rows:
        print(f"batch {r['batch']}: concat {r['concat_us_per_sample']:.3f} µs/sample, split "
              f"{r['split_us_per_sample']:.3f} ({r['split_speedup']:.2f}x), split in blocks of {r['block']} "
              f"{r['split_blocked_us_per_sample']:.3f} ({r['split_blocked_speedup']:.2f}x); max |dp| "
              f"{r['max_prob_difference']:.1e}, {r['threads']} threads")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()
