"""Benchmarks: ``python -m bench.run [--quick] [--only NAME ...]`` (``make bench``).

Each benchmark measures one cost of the method on SCAPE, repeated; every figure is reported as the median
with min and max, and ratios are taken from numbers measured in the same run. Results go to
``bench/results.json`` (flat keys with medians, plus a ``details`` object with min/max/reps) and
``bench/results.md``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SCAPE_DIR = Path(os.environ.get("NEURALCOL_DATA", ROOT.parent / "shared" / "data")) / "scape"


class Timing(dict):
    """median / min / max of repeated measurements (in the unit named by the key)."""


def repeat(fn: Callable[[], object], reps: int, warmup: int = 1) -> list[float]:
    """Wall-clock seconds of ``reps`` calls of ``fn`` after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def summarize(values: list[float], scale: float = 1.0) -> dict:
    vals = [v * scale for v in values]
    return {"median": statistics.median(vals), "min": min(vals), "max": max(vals), "reps": len(vals)}


# ---------------------------------------------------------------------------------------------- benches
def bench_acap(ctx: dict) -> dict:
    """ACAP encode and decode of all 71 SCAPE meshes (batched), ms per mesh."""
    from neuralcol import ACAP

    ds = ctx["scape"]
    verts = ds.vertices.to(torch.float64)
    acap = ACAP(verts[0], ds.faces)
    n = len(verts)
    reps = ctx["reps"]
    enc = repeat(lambda: acap.encode(verts), reps)
    feats = acap.encode(verts)
    with torch.no_grad():
        dec = repeat(lambda: acap.decode(feats), reps)
    feats32 = feats.float()
    with torch.no_grad():
        dec32 = repeat(lambda: acap.decode(feats32), reps)
    return {
        "acap_encode_ms": summarize(enc, 1e3 / n),
        "acap_decode_ms": summarize(dec, 1e3 / n),
        "acap_decode_float32_ms": summarize(dec32, 1e3 / n),
    }


BENCHES: dict[str, Callable[[dict], dict]] = {"acap": bench_acap}


def write_markdown(results: dict, path: Path) -> None:
    lines = [
        "# Benchmark results",
        "",
        f"Date {results['date']}, {results['cores']} cores, {results['machine']}, torch {results['torch']}. "
        f"Command: `{results['command']}`. Each figure: median (min–max) over the repetitions.",
        "",
        "| key | median | min | max | reps |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for key, d in results["details"].items():
        lines.append(f"| `{key}` | {d['median']:.4g} | {d['min']:.4g} | {d['max']:.4g} | {d['reps']} |")
    path.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer repetitions (development)")
    parser.add_argument("--only", nargs="*", choices=sorted(BENCHES), help="run only these benchmarks")
    parser.add_argument("--out", type=Path, default=HERE, help="folder for results.json / results.md")
    args = parser.parse_args(argv)
    if not (SCAPE_DIR / "1.obj").is_file():
        print(f"error: SCAPE not found at {SCAPE_DIR}; set NEURALCOL_DATA to the folder holding scape/",
              file=sys.stderr)
        return 2
    from neuralcol import load_mesh_dataset

    torch.set_num_threads(os.cpu_count() or 1)
    ctx = {"scape": load_mesh_dataset(SCAPE_DIR), "reps": 3 if args.quick else 7}
    details: dict = {}
    for name in args.only or list(BENCHES):
        t0 = time.perf_counter()
        details.update(BENCHES[name](ctx))
        print(f"[bench] {name}: {time.perf_counter() - t0:.1f} s", flush=True)
    results = {key: d["median"] for key, d in details.items()}
    results.update({
        "cores": os.cpu_count(),
        "date": dt.datetime.now().isoformat(timespec="seconds"),
        "machine": f"{platform.machine()} {platform.processor() or platform.system()}",
        "torch": torch.__version__,
        "command": "python -m bench.run" + (" --quick" if args.quick else ""),
        "details": details,
    })
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(results, indent=2))
    write_markdown(results, args.out / "results.md")
    print(json.dumps({k: v for k, v in results.items() if k != "details"}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
