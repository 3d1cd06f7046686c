"""How many exact labels it takes to put a sample within 2 eps of the true boundary (issue 15's projection target).

    python -m bench.boundary_search RUN_DIR [--picks 200] [--steps 8] [--candidates 10] [--workers 2] [--out FILE]

From a finished active run: ``picks`` uncertain codes (of ``candidates`` x picks fresh U(Z) codes, the ones
whose detector logit is closest to 0, as ``method=active`` picks them), labeled exactly. Each is paired with
the nearest row of the run's D_c (``dc.h5``, box-normalised distance) whose PD has the other sign, and the
bracket is shrunk by the Illinois variant of regula falsi on the exact signed PD (continuous across the
boundary, docs/labels.md), one exact label per step: :mod:`neuralcol.active.boundary_search`, the same code
``method.refine_steps`` runs in the acquisition. Prints, after 0..steps labels per pick, the share of
picks whose newest point lies within 1, 2 and 10 eps (``|PD| <= k eps``) and the median |PD| / eps.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import h5py
import numpy as np
import torch

from neuralcol.active.boundary_search import BracketSearch, nearest_opposite


def search(run, picks: int, steps: int, candidates: int, seed: int = 0) -> dict:
    net = run.detector.eval()
    space = run.space
    gen = torch.Generator().manual_seed(seed)
    cand = space.sample(candidates * picks, generator=gen)
    with torch.no_grad():
        logit = net(cand).logit
    z0 = cand[torch.argsort(logit.abs())[:picks]].double()
    with h5py.File(run.run_dir / "dc.h5", "r") as f:
        dz, dpd = np.asarray(f["z"], np.float64), np.asarray(f["pd"], np.float64)
    lo, hi = space.box_lo.double().numpy(), space.box_hi.double().numpy()
    pd0 = run.label(run.decode(z0.float())).pd
    eps = float(run._labeler.eps)  # boundary_eps * diag, in mesh units (the labeler exists after the first label)
    # the acquisition's own search (method.refine_steps): nearest D_c row on the other side, Illinois regula falsi
    partner = nearest_opposite(z0.numpy(), pd0, dz, dpd, lo, hi)
    search = BracketSearch(z0.numpy(), pd0, dz[partner], dpd[partner])
    hist = [np.abs(pd0)]
    for _ in range(steps):
        z = search.propose()
        search.update(z, run.label(run.decode(torch.as_tensor(z, dtype=torch.float32))).pd)
        hist.append(np.abs(search.newest))
    rows = []
    for k, h in enumerate(hist):
        rows.append({"labels_per_pick": k + 1, "within_1eps": float(np.mean(h <= eps)),
                     "within_2eps": float(np.mean(h <= 2 * eps)), "within_10eps": float(np.mean(h <= 10 * eps)),
                     "median_abs_pd_over_eps": float(np.median(h) / eps)})
    return {"run": str(run.run_dir), "eps": eps, "picks": picks, "rows": rows,
            "start_pd_sign_collides": float(np.mean(pd0 > 0))}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--picks", type=int, default=200)
    ap.add_argument("--steps", type=int, default=8)
    ap.add_argument("--candidates", type=int, default=10)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    from neuralcol import load_run

    with load_run(args.run, workers=args.workers) as run:
        res = search(run, args.picks, args.steps, args.candidates)
    print(f"{res['run']}: eps {res['eps']:.4g}, {res['picks']} picks ({100 * res['start_pd_sign_collides']:.0f} % "
          "colliding)")
    print("| labels per pick | within 1 eps | within 2 eps | within 10 eps | median abs(PD) / eps |")
    print("|---:|---:|---:|---:|---:|")
    for r in res["rows"]:
        print(f"| {r['labels_per_pick']} | {100 * r['within_1eps']:.1f} % | {100 * r['within_2eps']:.1f} % | "
              f"{100 * r['within_10eps']:.1f} % | {r['median_abs_pd_over_eps']:.2f} |")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
