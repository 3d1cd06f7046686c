"""``TrainedRun.resolve`` on collision-free meshes: how many come back bit for bit, and what a free mesh costs.

    python -m research.resolve_free [--run pretrained/scape] [--data ../shared/data/scape] [--mesh 2] [--repeats 20]

Labels every mesh of the data set folder exactly, resolves the free ones in one batch and one by one and counts the
results equal to the input (``np.array_equal`` on the float64 values), then times ``resolve`` of one free mesh
(``--mesh``, a file stem): one warm-up call, then the median of ``--repeats`` calls, beside the median of one exact
label of the same mesh (``run.label``, what the free check costs). Result in docs/studies/resolve_free_meshes.md.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]


def median_ms(call, repeats: int) -> float:
    """One warm-up call, then the median wall time of ``repeats`` calls, in ms."""
    call()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        call()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def main(argv: list[str] | None = None) -> None:
    import neuralcol
    from neuralcol import load_mesh_dataset

    parser = argparse.ArgumentParser(prog="python -m research.resolve_free", description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=ROOT / "pretrained" / "scape")
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "scape")
    parser.add_argument("--mesh", default="2", help="file stem of the free mesh to time")
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args(argv)
    ds = load_mesh_dataset(args.data, dtype=torch.float64)
    v = ds.vertices.numpy()
    with neuralcol.load_run(args.run) as run:
        pd = run.label(v).pd
        free = np.flatnonzero(pd <= 0)
        batch = run.resolve(v[free]).vertices.cpu().numpy()
        same_batch = sum(np.array_equal(batch[k], v[i]) for k, i in enumerate(free))
        same_one = sum(np.array_equal(run.resolve(v[i]).vertices[0].cpu().numpy(), v[i]) for i in free)
        print(f"{args.data}: {len(free)} of {len(v)} meshes free by the exact label; bit-identical after resolve: "
              f"{same_batch} of {len(free)} in one batch, {same_one} of {len(free)} one by one")
        i = ds.names.index(args.mesh)
        if pd[i] > 0:
            print(f"{args.mesh}: collides (PD {pd[i]:.4g}); give a free mesh to time")
            return
        mesh = v[i]
        t_resolve = median_ms(lambda: run.resolve(mesh), args.repeats)
        t_label = median_ms(lambda: run.label(mesh), args.repeats)
        print(f"resolve({args.mesh}.obj, {v.shape[1]} vertices): median {t_resolve:.1f} ms over {args.repeats} calls "
              f"after one warm-up; one exact label of it: {t_label:.1f} ms")


if __name__ == "__main__":
    main()
