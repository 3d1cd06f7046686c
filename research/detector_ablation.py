"""Ablation of two training choices of the detector that the paper does not make
(docs/studies/detector_training_choices.md).

``python -m research.detector_ablation [--dataset-key KEY] [--sizes 2000 6000] [--seeds 0 1]``

Trains the detector (paper loss weights, Adam lr 1e-3, batch 512, 100 epochs) on the first N rows of a cached
pool of labeled uniform samples (written by ``python -m experiments.run``, ``<cache>/collision/<key>/
uniform_s0.h5``) and reports the accuracy on the cached test set, for the four combinations of

* raw latent codes vs codes mapped from the box Z to [-1, 1] (``detector.net.normalize_inputs``), and
* the last epoch's weights vs the weights of the epoch with the best validation accuracy
  (``detector.select_best_val``; validation = rows with id % 5 == 4, as in D_c).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from neuralcol.nn.detector import CollisionDetector, detector_losses
from neuralcol.samples.datamodule import detector_targets
from neuralcol.samples.store import CollisionStore


def _read(path: Path):
    import h5py

    with h5py.File(path, "r") as h5:
        d, k = h5["z"].shape[1], h5["pd_sub"].shape[1]
    with CollisionStore(path, d, k) as store:
        return store.read(), d, k


def train_once(pool, test, n, k, d2, normalize, pd_unit, seed, epochs=100):
    torch.manual_seed(seed)
    rows = pool.select(slice(0, n))
    z, pd, pd_sub, subset = detector_targets(rows, pd_unit, 3.0)
    lo, hi = torch.as_tensor(pool.z.min(0)), torch.as_tensor(pool.z.max(0))
    net = CollisionDetector(k, d2, 64, 128, *((lo, hi) if normalize else (None, None)))
    opt = torch.optim.Adam(net.parameters(), 1e-3)
    val = torch.as_tensor(np.arange(n) % 5 == 4)
    train_idx = torch.nonzero(~val).flatten()
    gen = torch.Generator().manual_seed(seed)
    tz, ty = torch.as_tensor(test.z), torch.as_tensor(test.collides.astype(bool))
    best = (-1.0, None)
    for _ in range(epochs):
        for b in train_idx[torch.randperm(len(train_idx), generator=gen)].split(512):
            loss = detector_losses(net(z[b]), pd[b], pd_sub[b], subset[b], 5.0, 0.2, 2.0, 2.0, 0.5, 0.01, 0.1).total
            opt.zero_grad()
            loss.backward()
            opt.step()
        with torch.no_grad():
            acc = float(((net(z[val]).logit > 0) == (pd[val] > 0)).float().mean())
            if acc > best[0]:
                best = (acc, float(((net(tz).logit > 0) == ty).float().mean()))
    with torch.no_grad():
        last = float(((net(tz).logit > 0) == ty).float().mean())
    return last, best[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, default=Path(".cache"))
    parser.add_argument("--dataset-key", default=None, help="folder under <cache>/collision (default: the only one)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[2000, 6000])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "detector_ablation.json")
    args = parser.parse_args()
    root = args.cache / "collision"
    keys = [args.dataset_key] if args.dataset_key else sorted(p.name for p in root.iterdir() if p.is_dir())
    if len(keys) != 1:
        raise SystemExit(f"error: pick one of {keys} with --dataset-key")
    folder = root / keys[0]
    pool, d, k = _read(folder / "uniform_s0.h5")
    test, _, _ = _read(next(folder.glob("test_s*.h5")))
    d2 = (d - k) // k
    pd_unit = float(json.loads((folder / "labeler.json").read_text())["cap"]) if (folder / "labeler.json").is_file() \
        else float(np.abs(pool.pd[pool.pd < 0]).max())
    results = []
    for n in args.sizes:
        if n > len(pool.z):
            raise SystemExit(f"error: the pool holds {len(pool.z)} rows, fewer than {n}")
        for normalize in (False, True):
            accs = [train_once(pool, test, n, k, d2, normalize, pd_unit, s) for s in args.seeds]
            t = time.strftime("%H:%M:%S")
            res = {"n": n, "normalize_inputs": normalize, "seeds": args.seeds,
                   "last_epoch": [a[0] for a in accs], "best_val_epoch": [a[1] for a in accs]}
            results.append(res)
            print(f"[{t}] N={n} normalize={normalize}: test accuracy last epoch "
                  f"{np.mean(res['last_epoch']):.4f}, best-validation epoch {np.mean(res['best_val_epoch']):.4f} "
                  f"(mean of seeds {args.seeds})", flush=True)
    args.out.write_text(json.dumps({"test_size": len(test.z), "pool": str(folder), "results": results}, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
