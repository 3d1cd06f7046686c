"""A data set no preset was written for, exported as a new user would bring it:
``python -m bench.newuser_hand DIR [--poses N] [--variant b]``.

150 poses of a procedural hand built with other geometry than ``proc_hand`` (7 rings per finger instead of 9,
so another topology: 2194 vertices; other finger lengths, gap, palm thickness, thumb angle and spread range)
and another pose seed, written as ``DIR/pose_000.obj`` ... (``--poses N`` writes N poses instead of 150; the
tutorial's test uses 24). ``--variant b`` is a second hand written after the model sizes were chosen by rule, so no
setting was tried on it before its pre-registered test (docs/studies/unseen_hand.md): 8 rings per finger
(2354 vertices), stubbier wider fingers with a wider gap, a thicker palm, a lower thumb, wider flexion and
spread ranges and pose seed 29. A run on it uses only ``dataset.source.path`` and
lifts the vertex-count check (docs/studies/unseen_hand.md):

    python -m experiments.run dataset=hand dataset.source.path=DIR dataset.source.expected_vertices=null
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from neuralcol.data.procedural.hand import make_proc_hand
from neuralcol.geometry.mesh_io import write_meshes

GEOMETRY = {"rings_per_finger": 7, "finger_lengths": (0.78, 0.95, 0.9, 0.68), "finger_gap": 0.02,
            "palm_thickness": 0.28, "thumb_angle": 40.0, "spread_range": (0.0, 30.0)}
VARIANTS = {
    "a": (11, GEOMETRY),
    "b": (29, {"rings_per_finger": 8, "finger_widths": (0.24, 0.25, 0.24, 0.2),
               "finger_lengths": (0.76, 0.86, 0.82, 0.72), "finger_gap": 0.03, "finger_thickness": 0.21,
               "palm_thickness": 0.34, "thumb_base_y": 0.05, "thumb_angle": 30.0, "mcp_range": (-10.0, 80.0),
               "pip_range": (0.0, 95.0), "spread_range": (0.0, 35.0)}),
}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m bench.newuser_hand", description=__doc__.splitlines()[0])
    parser.add_argument("dir", type=Path, help="output folder (created)")
    parser.add_argument("--poses", type=int, default=150, help="number of poses (default 150)")
    parser.add_argument("--variant", choices=sorted(VARIANTS), default="a",
                        help="which hand: a (default, the hand of docs/studies/model_size_checks.md) or b (a hand "
                             "nobody tuned on)")
    args = parser.parse_args(argv)
    if args.poses < 1:
        parser.error(f"--poses {args.poses}: use 1 or more")
    seed, geometry = VARIANTS[args.variant]
    v, f = make_proc_hand(n_poses=args.poses, seed=seed, **geometry)
    write_meshes(args.dir, torch.as_tensor(v), torch.as_tensor(f), [f"pose_{i:03d}" for i in range(len(v))])
    print(f"{len(v)} meshes, {v.shape[1]} vertices, {len(f)} faces -> {args.dir}")


if __name__ == "__main__":
    main()
