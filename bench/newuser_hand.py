"""A data set no preset was written for, exported as a new user would bring it: ``python -m bench.newuser_hand DIR``.

150 poses of a procedural hand built with other geometry than ``proc_hand`` (7 rings per finger instead of 9,
so another topology: 2194 vertices; other finger lengths, gap, palm thickness, thumb angle and spread range)
and another pose seed, written as ``DIR/pose_000.obj`` ... A run on it uses only ``dataset.source.path`` and
lifts the vertex-count check (docs/diagnosis.md, "A data set nobody tuned for"):

    python -m experiments.run dataset=hand dataset.source.path=DIR dataset.source.expected_vertices=null
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from neuralcol.data.procedural import make_proc_hand
from neuralcol.geometry.mesh_io import write_meshes

GEOMETRY = {"rings_per_finger": 7, "finger_lengths": (0.78, 0.95, 0.9, 0.68), "finger_gap": 0.02,
            "palm_thickness": 0.28, "thumb_angle": 40.0, "spread_range": (0.0, 30.0)}


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        raise SystemExit("usage: python -m bench.newuser_hand DIR")
    v, f = make_proc_hand(n_poses=150, seed=11, **GEOMETRY)
    write_meshes(Path(argv[0]), torch.as_tensor(v), torch.as_tensor(f), [f"pose_{i:03d}" for i in range(len(v))])
    print(f"{len(v)} meshes, {v.shape[1]} vertices, {len(f)} faces -> {argv[0]}")


if __name__ == "__main__":
    main()
