"""How often a perfect threshold rule still lands outside ±0.02 of its FNR target, by the sizes of the calibration
and test sets (colliding meshes): the threshold is set at the calibration set's empirical FNR <= target, so the
true FNR there is an order statistic (Beta(k + 1, n_cal - k), k = floor(target * n_cal)); the test set then reads
Binomial(n_test, that FNR) / n_test. Monte Carlo, seeded.

    .venv/bin/python -m research.threshold.power [--target 0.1] [--tol 0.02]
"""

from __future__ import annotations

import argparse

import numpy as np

SIZES = [(150, 150), (300, 300), (890, 868), (1000, 1000), (2400, 1000), (1740, 1740), (2400, 2400), (4800, 4800)]


def outside(n_cal: int, n_test: int, target: float, tol: float, reps: int, rng) -> tuple[float, float]:
    k = int(np.floor(target * n_cal))
    true_fnr = rng.beta(k + 1, n_cal - k, reps)
    read = rng.binomial(n_test, true_fnr) / n_test
    return float(np.mean(np.abs(read - target) > tol)), float(np.std(read))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m research.threshold.power")
    ap.add_argument("--target", type=float, default=0.1)
    ap.add_argument("--tol", type=float, default=0.02)
    ap.add_argument("--reps", type=int, default=200_000)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    print(f"| colliding meshes: calibration / test | P(test FNR outside {a.target} ± {a.tol}) | std of the test FNR |")
    print("|---|---:|---:|")
    for n_cal, n_test in SIZES:
        p, sd = outside(n_cal, n_test, a.target, a.tol, a.reps, rng)
        print(f"| {n_cal} / {n_test} | {p:.3f} | {sd:.4f} |")


if __name__ == "__main__":
    main()
