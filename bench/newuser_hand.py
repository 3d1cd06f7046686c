"""A data set no preset was written for, exported as a new user would bring it:
``python -m bench.newuser_hand DIR [--poses N]``.

150 poses of a procedural hand built with other geometry than ``proc_hand`` (7 rings per finger instead of 9,
so another topology: 2194 vertices; other finger lengths, gap, palm thickness, thumb angle and spread range)
and another pose seed, written as ``DIR/pose_000.obj`` ... (``--poses N`` writes N poses instead of 150; the
tutorial's test uses 24). A run on it uses only ``dataset.source.path`` and
lifts the vertex-count check (docs/diagnosis.md, "A data set nobody tuned for"):

    python -m experiments.run dataset=hand dataset.source.path=DIR dataset.source.expected_vertices=null
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from neuralcol.data.procedural import make_proc_hand
from neuralcol.geometry.mesh_io import write_meshes

GEOMETRY = {"rings_per_finger": 7, "finger_lengths": (0.78, 0.95, 0.9, 0.68), "finger_gap": 0.02,
            "palm_thickness": 0.28, "thumb_angle": 40.0, "spread_range": (0.0, 30.0)}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m bench.newuser_hand", description=__doc__.splitlines()[0])
    parser.add_argument("dir", type=Path, help="output folder (created)")
    parser.add_argument("--poses", type=int, default=150, help="number of poses (default 150)")
    args = parser.parse_args(argv)
    if args.poses < 1:
        parser.error(f"--poses {args.poses}: use 1 or more")
    v, f = make_proc_hand(n_poses=args.poses, seed=11, **GEOMETRY)
    write_meshes(args.dir, torch.as_tensor(v), torch.as_tensor(f), [f"pose_{i:03d}" for i in range(len(v))])
    print(f"{len(v)} meshes, {v.shape[1]} vertices, {len(f)} faces -> {args.dir}")


if __name__ == "__main__":
    main()
