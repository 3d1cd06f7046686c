"""Seconds per code of the collision handler with a finished run's detector, on its first handler inputs.

    python -m research.detector_transfer.handler_cost RUN_DIR [--n 64] [--no-reuse]

``--no-reuse`` searches every mesh's close pairs anew at each call (no neighbour lists; same results, the time a
detector that reads contact summaries cost before they were kept). Prints one JSON line: seconds per code, the
share the detector calls feasible, the mean outer iterations and, with summaries, the searches and reuses.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time

import numpy as np
import torch

import neuralcol.handler.resolve as resolve_module
from neuralcol.api.run import load_run
from neuralcol.geometry import contact_summary
from neuralcol.handler.resolve import alm_settings, handle_codes
from neuralcol.nn.part_geometry import DetectorOnCodes


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir")
    ap.add_argument("--n", type=int, default=64, help="handler inputs (the run's first ones)")
    ap.add_argument("--no-reuse", action="store_true", help="search every mesh anew at each call")
    args = ap.parse_args(argv)
    run = load_run(args.run_dir)
    with np.load(f"{args.run_dir}/handling/handling.npz") as f:
        z = torch.as_tensor(f["z_user"][: args.n])
    if args.no_reuse:
        resolve_module.reusing_neighbours = contextlib.nullcontext
    counts = {"searches": 0, "reuses": 0}
    original = contact_summary.NeighbourLists.candidates

    def counted(self, vs):
        before = (self.searches, self.reuses)
        out = original(self, vs)
        counts["searches"] += self.searches - before[0]
        counts["reuses"] += self.reuses - before[1]
        return out

    contact_summary.NeighbourLists.candidates = counted
    net = DetectorOnCodes(run.detector, run.space)
    handle_codes(net, z[:2], run.space.box_lo, run.space.box_hi, alm_settings(run.cfg.handler.alm))  # compile
    counts.update(searches=0, reuses=0)
    t0 = time.perf_counter()
    res = handle_codes(net, z, run.space.box_lo, run.space.box_hi, alm_settings(run.cfg.handler.alm))
    out = {"run": args.run_dir, "n": len(z), "reuse": not args.no_reuse,
           "seconds_per_code": (time.perf_counter() - t0) / max(len(z), 1),
           "feasible": float(res.feasible.float().mean()), "mean_outer": float(res.outer.float().mean()), **counts}
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
