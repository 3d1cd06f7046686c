"""The methods side by side at equal data set sizes (the claim "active ≥ supv_bd ≥ supv at equal size").

The baselines are re-trained at a few sizes and the active methods stop at their own (the elbow), so the sizes of
two methods seldom coincide: at every size one of them ran, each method's mean accuracy over seeds is read there,
linearly interpolated between its two neighbouring sizes (marked ``~``) and left out outside its range (no
extrapolation). Only methods on one latent space are compared: each space has its own U(Z) test set.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np

from experiments.reporting.aggregate import latent_space, mean_curve
from experiments.reporting.discover import label, method, ordered_methods


def value_at(sizes: list[int], values: list[float], size: int) -> tuple[float | None, bool]:
    """(value, exact?) of the piecewise-linear curve at ``size``; (None, False) outside its sizes."""
    if size in sizes:
        return values[sizes.index(size)], True
    if not sizes or size < sizes[0] or size > sizes[-1]:
        return None, False
    return float(np.interp(size, sizes, values)), False


def order_text(cells: dict[str, float], digits: int = 4) -> str:
    """``A > B = C``: the methods by value, highest first, ``=`` where equal to ``digits`` decimals."""
    ranked = sorted(cells.items(), key=lambda kv: -kv[1])
    out = label(ranked[0][0])
    for (_, prev), (m, v) in zip(ranked, ranked[1:]):
        out += (" = " if round(prev, digits) == round(v, digits) else " > ") + label(m)
    return out


def equal_size_markdown(runs: list[dict]) -> list[str]:
    """One table per latent space of a data set's runs holding two methods or more: mean accuracy at logit 0 of
    each method at each size any of them ran, and their order there."""
    by_space = defaultdict(list)
    for r in runs:
        by_space[latent_space(r)].append(r)
    lines = []
    for space, rs in by_space.items():
        names = ordered_methods({method(r) for r in rs})
        if len(names) < 2:
            continue
        curves = {m: mean_curve([r for r in rs if method(r) == m]) for m in names}
        sizes = sorted({s for sz, _ in curves.values() for s in sz})
        lines += [f"### methods at equal size (latent space {space or 'unrecorded'}; mean accuracy at logit 0, "
                  "`~`: interpolated between the method's neighbouring sizes)", "",
                  "| data set size | " + " | ".join(label(m) for m in names) + " | order |",
                  "|---:|" + "---:|" * len(names) + "---|"]
        for size in sizes:
            cells, texts = {}, []
            for m in names:
                v, exact = value_at(*curves[m], size)
                if v is not None:
                    cells[m] = v
                texts.append("—" if v is None else f"{'' if exact else '~'}{v:.4f}")
            lines.append(f"| {size} | " + " | ".join(texts) + f" | {order_text(cells) if len(cells) > 1 else ''} |")
        lines.append("")
    return lines
