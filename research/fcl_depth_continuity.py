"""Why python-fcl's contact depth is not used for PD: ``python -m research.fcl_depth_continuity``.

A triangle slides sideways into another (entering through its edge). FCL's contact depth for the pair
jumps from 'no contact' to about the piercing triangle's height; the SAT translational depth used by
neuralcol grows continuously from 0. Prints one row per offset.
"""

from __future__ import annotations

import argparse

import fcl
import numpy as np

from neuralcol.collision.kernels.depth import triangle_pair_depth


def _bvh(v: np.ndarray, f: np.ndarray) -> fcl.BVHModel:
    m = fcl.BVHModel()
    m.beginModel(len(v), len(f))
    m.addSubModel(v, f)
    m.endModel()
    return m


def main(argv: list[str] | None = None) -> None:
    argparse.ArgumentParser(description=__doc__).parse_args(argv)
    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    face = np.array([[0, 1, 2]])
    print(f"{'offset':>8} {'fcl_contact':>12} {'fcl_depth':>10} {'sat_depth':>10}")
    for s in np.linspace(-0.1, 0.1, 9):
        other = np.array([[s, 0.3, -0.5], [s, 0.3, 0.5], [s - 0.1, 0.4, 0.0]])
        req = fcl.CollisionRequest(enable_contact=True, num_max_contacts=10)
        res = fcl.CollisionResult()
        n = fcl.collide(fcl.CollisionObject(_bvh(tri, face)), fcl.CollisionObject(_bvh(other, face)), req, res)
        depth = max((c.penetration_depth for c in res.contacts), default=float("nan"))
        sat = triangle_pair_depth(*map(tuple, tri), *map(tuple, other), 1.0)
        print(f"{s:8.3f} {n > 0!s:>12} {depth:10.4f} {sat:10.4f}")


if __name__ == "__main__":
    main()
