"""Benchmarks: ``python -m bench.run [--quick] [--only NAME ...]`` (``make bench``).

Each benchmark (one module of ``bench/``, listed in :data:`BENCHES`) measures one cost of the method on SCAPE,
repeated; every figure is reported as the median with min and max, and ratios are taken from numbers measured in
the same run. Results go to ``bench/results.json`` (flat keys with medians, plus a ``details`` object with
min/max/reps) and ``bench/results.md``. SCAPE is read from ``paths.data_dir`` (``NEURALCOL_DATA``, or
``--data-dir``): ``<data dir>/scape``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import sys
import time
from pathlib import Path

import torch

from bench import (
    acap,
    cascade,
    dask_pool,
    export,
    fcl_backend,
    gpu,
    labeler,
    labeler_body,
    large_meshes,
    memory,
    neural,
    pipeline,
    pool,
    repair,
    training,
    training_labels,
)
from bench.context import HERE, BenchContext, scape_config
from bench.markdown import write_markdown

# name (--only, results.json "sections") -> module whose measure(ctx) returns {key: summary}; run in this order
BENCHES = {"acap": acap, "labeler": labeler, "labeler_body": labeler_body, "large": large_meshes,
           "repair": repair, "pool": pool,
           "pipeline": pipeline,
           "dask": dask_pool, "fcl": fcl_backend, "neural": neural,
           "cascade": cascade, "training": training, "training_labels": training_labels, "memory": memory,
           "gpu": gpu, "export": export}


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer repetitions (development)")
    parser.add_argument("--only", nargs="*", choices=sorted(BENCHES), help="run only these benchmarks")
    parser.add_argument("--out", type=Path, default=HERE, help="folder for results.json / results.md")
    parser.add_argument("--run-dir", type=Path, default=None,
                        help="finished SCAPE run for the neural benchmarks (default: the newest under outputs/)")
    parser.add_argument("--data-dir", type=Path, default=None,
                        help="folder holding scape/ (default: paths.data_dir, i.e. $NEURALCOL_DATA or data/)")
    return parser.parse_args(argv)


def previous_results(out: Path, only: list[str] | None) -> tuple[dict, dict, dict]:
    """(details, sections, notes) of the last results.json to keep in a partial run (``--only``): the sections
    not run now."""
    path = out / "results.json"
    if not only or not path.is_file():
        return {}, {}, {}
    old = json.loads(path.read_text())
    notes = {k: v for k, v in old.get("notes", {}).items() if k not in only}
    return dict(old.get("details", {})), dict(old.get("sections", {})), notes


def write_results(out: Path, details: dict, sections: dict, notes: dict, quick: bool) -> dict:
    """``out/results.json`` (flat medians, then the run's facts and ``details``) and ``out/results.md``."""
    results = {key: (d["median"] if "median" in d else d) for key, d in details.items()}
    results.update({
        "cores": os.cpu_count(),
        "date": dt.datetime.now().isoformat(timespec="seconds"),
        "machine": f"{platform.machine()} {platform.processor() or platform.system()}",
        "torch": torch.__version__,
        "command": "python -m bench.run" + (" --quick" if quick else ""),
        "sections": sections,
        "notes": notes,
        "details": details,
    })
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=2))
    write_markdown(results, out / "results.md")
    return results


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    cfg = scape_config([f"paths.data_dir={args.data_dir.resolve()}"] if args.data_dir else [])
    scape_dir = Path(str(cfg.dataset.source.path))
    if not (scape_dir / "1.obj").is_file():
        print(f"error: SCAPE not found at {scape_dir}; set NEURALCOL_DATA (or --data-dir) to the folder holding "
              "scape/", file=sys.stderr)
        return 2
    torch.set_num_threads(os.cpu_count() or 1)
    details, sections, notes = previous_results(args.out, args.only)
    ctx = BenchContext(cfg, quick=args.quick, run_dir=args.run_dir, notes=notes)
    _ = ctx.scape  # the data set, loaded before the first benchmark
    for name in args.only or list(BENCHES):
        t0 = time.perf_counter()
        details.update(BENCHES[name].measure(ctx))
        sections[name] = {"date": dt.datetime.now().isoformat(timespec="seconds"),
                          "seconds": round(time.perf_counter() - t0, 1), "quick": args.quick}
        print(f"[bench] {name}: {time.perf_counter() - t0:.1f} s", flush=True)
    results = write_results(args.out, details, sections, ctx.notes, args.quick)
    print(json.dumps({k: v for k, v in results.items() if k != "details"}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
