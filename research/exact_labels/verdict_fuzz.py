"""The exact-verdict test's hard cases over many random seeds: every family of ``tests/test_exact_verdict.py`` at
scales 1e-2, 1, 1e2, through the pruned labeler over each rest mesh and the reference path, against the rational
reference. Prints the disagreements (none expected) and their count.

    PYTHONPATH=. .venv/bin/python research/exact_labels/verdict_fuzz.py 20 80   # seeds 20..79
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
from test_exact_verdict import FAMILIES, SCALES, _labelers, counted_pairs_ref  # noqa: E402


def main(first: int, last: int) -> int:
    wrong = labels = 0
    for seed in range(first, last):
        for family, make in FAMILIES.items():
            for scale in SCALES:
                for verts, faces in make(np.random.default_rng(seed), scale):
                    ref = counted_pairs_ref(verts, faces)
                    for lab in _labelers(verts, faces, scale):
                        label = lab.label(verts)
                        got = (lab.verdict(verts), label.collides, label.pd > 0, label.n_pairs,
                               len(lab.intersecting_pairs(verts)))
                        labels += 1
                        if got != (ref > 0, ref > 0, ref > 0, ref, ref):
                            wrong += 1
                            print(f"seed {seed} {family} scale {scale}: got {got}, reference {ref} pairs: "
                                  f"{verts.tolist()}")
    print(f"{wrong} wrong of {labels} labels (seeds {first}-{last - 1})")
    return int(wrong > 0)


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]), int(sys.argv[2])))
