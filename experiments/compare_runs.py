"""Are two runs the same? ``python -m experiments.compare_runs RUN_A RUN_B``.

Compares the ``metrics.json`` of two run directories value by value, leaving out what measures time or says
where a value came from (keys naming seconds, ms, µs, threads, cache hits or resumption), and the arrays of
``test_predictions.npz``, ``realistic_predictions.npz`` and the detector's weights bit for bit. Prints the count
of identical values, every difference, and keys found in only one of the two; exits 1 when anything differs.
Used to check that a refactor keeps a run's numbers to the last digit (e.g. ``make run`` and
``experiment=cpu_scape``, docs/studies/same_numbers.md).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from neuralcol.rundir import RunDir
from neuralcol.utils.cli import report_user_errors
from neuralcol.utils.safe_files import read_torch_file

TIMING = ("seconds", "_s", "ms_per", "_us", "batch_", "threads", "from_cache", "labeled_now", "resumed", "source",
          "speedup")


def _is_timing(path: str) -> bool:
    # "sittings": wall time per stage and sitting (max_minutes)
    return any(t in path.split(".")[-1] for t in TIMING) or "inference_us" in path or path.startswith("sittings.")


def compare_metrics(a, b, path: str = "", out=None) -> dict:
    """``{"same": n, "diffs": [(path, a, b)], "only_a": [...], "only_b": [...]}`` over two metrics trees."""
    out = out if out is not None else {"same": 0, "diffs": [], "only_a": [], "only_b": []}
    if isinstance(a, dict) and isinstance(b, dict):
        for k in a:
            if k in b:
                compare_metrics(a[k], b[k], f"{path}{k}.", out)
            else:
                out["only_a"].append(path + k)
        out["only_b"] += [path + k for k in b if k not in a]
    elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            compare_metrics(x, y, f"{path}{i}.", out)
    elif not _is_timing(path.rstrip(".")):
        nan = isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)
        if a == b or nan:
            out["same"] += 1
        else:
            out["diffs"].append((path.rstrip("."), a, b))
    return out


def compare_arrays(a: RunDir, b: RunDir) -> list[str]:
    """Names of the prediction arrays and detector tensors that differ (or exist in one run only)."""
    import torch

    bad = []
    for name in ("test_predictions", "realistic_predictions"):
        fa, fb = getattr(a, name), getattr(b, name)
        if fa.is_file() != fb.is_file():
            bad.append(f"{fa.name}: in one run only")
        elif fa.is_file():
            za, zb = np.load(fa), np.load(fb)
            bad += [f"{fa.name}:{k}" for k in sorted(set(za.files) | set(zb.files))
                    if k not in za.files or k not in zb.files or not np.array_equal(za[k], zb[k], equal_nan=True)]
    sa, sb = (read_torch_file(rd.detector)["state"] for rd in (a, b))  # never unpickles code
    bad += [f"detector.pt:{k}" for k in sorted(set(sa) | set(sb)) if k not in sa or k not in sb
            or not torch.equal(sa[k], sb[k])]
    return bad


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.compare_runs", description=__doc__.splitlines()[0])
    parser.add_argument("run_a", type=Path)
    parser.add_argument("run_b", type=Path)
    args = parser.parse_args(argv)
    a, b = RunDir(args.run_a), RunDir(args.run_b)
    for rd in (a, b):
        if not rd.metrics.is_file() or not rd.detector.is_file():
            print(f"{rd.path}: not a finished run (needs metrics.json and detector.pt)", file=sys.stderr)
            return 2
    res = compare_metrics(json.loads(a.metrics.read_text()), json.loads(b.metrics.read_text()))
    arrays = compare_arrays(a, b)
    print(f"metrics.json: {res['same']} values identical, {len(res['diffs'])} differ (timings left out)")
    for path, x, y in res["diffs"]:
        print(f"  {path}: {x!r} vs {y!r}")
    for side, keys in (("first", res["only_a"]), ("second", res["only_b"])):
        if keys:
            print(f"  only in the {side} run: {', '.join(keys)}")
    print("arrays (predictions, detector weights): " + ("bit-identical" if not arrays else ", ".join(arrays)))
    return 1 if res["diffs"] or arrays else 0


if __name__ == "__main__":
    raise SystemExit(main())
