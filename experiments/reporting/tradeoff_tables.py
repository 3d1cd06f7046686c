"""The size, cost and failure section of ``report.md`` (next to ``pareto.png``, ``cost.png``, ``failures.png``).

* Pareto table: final test accuracy against the detector's parameter count and its CPU inference time per
  sample at batch 4096 (``metrics["detector"]["inference_us"]``), one row per configuration (data set, method,
  latent sizes K and L, detector widths; mean ± std over seeds), whether it is on the Pareto front (higher
  accuracy, lower cost) and whether it is the choice of a ``model_size.json``;
* failure tables: detector accuracy by exact-PD bin of the test rows
  (:data:`neuralcol.metrics.breakdown.PD_BIN_EDGES`, in units of the run's ``pd_unit``), recall by the deepest
  sub-domain (argmax of ``pd_sub``) of the colliding test rows, and the detector-only handler's success by PD
  bin of its inputs; mean ± std over seeds.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from experiments.reporting.discover import method_order
from experiments.reporting.markdown import pm, row
from neuralcol.metrics.breakdown import PD_BIN_NAMES, mean_std


def _pm(mean: float, std: float, n: int) -> str:
    return pm(mean, std, n, ".3f") if np.isfinite(mean) else "—"


def tradeoff_markdown(points: list[dict], groups: dict, chosen: dict | None, chosen_path: Path | None,
                      notes: list[str]) -> list[str]:
    """The whole section: the choice, the Pareto tables, the failure tables and the left-out runs."""
    lines = ["## Size, cost and failures (pareto.png, cost.png, failures.png)", ""]
    if chosen_path is not None:
        lines += [f"Chosen configuration ({chosen_path}): {json.dumps(chosen)}.", ""]
    lines += pareto_markdown(points, chosen_path) + failure_markdown(groups)
    return lines + [f"Left out: {n}" for n in notes] + ([""] if notes else [])


def failure_markdown(groups: dict) -> list[str]:
    """Tables per data set: one row per method and PD bin, and one per method and sub-domain."""
    lines = []
    for ds in sorted({k[0] for k in groups}):
        keys = sorted((k for k in groups if k[0] == ds), key=lambda k: method_order(k[1]))
        unit = groups[keys[0]]["pd_unit"]
        lines += [f"### {ds}: where each method fails, by exact PD (mean ± std over seeds)", "",
                  f"PD in units of pd_unit = {unit:.4g} (the labeler's clearance cap); bins are right-closed. "
                  "Detector accuracy over the test rows of each bin (on the free bins 1 − FPR, on the colliding "
                  "ones recall); handler success (detector only) over the self-penetrating handler inputs.", "",
                  "| method | PD bin | test rows | detector accuracy | handler inputs | handler success |",
                  "|---|---|---:|---:|---:|---:|"]
        for k in keys:
            g = groups[k]
            acc = mean_std(g["accuracy"][0]) if "accuracy" in g else None
            hand = mean_std(g["handler"][0]) if "handler" in g else None
            for b, name in enumerate(PD_BIN_NAMES):
                a_txt = _pm(acc[0][b], acc[1][b], acc[2][b]) if acc else "—"
                rows = f"{g['accuracy'][1][b]}" if acc else "—"
                h_txt = _pm(hand[0][b], hand[1][b], hand[2][b]) if hand else "—"
                h_rows = f"{g['handler'][1][b]}" if hand else "—"
                lines.append(row(k[1], name, rows, a_txt, h_rows, h_txt))
        lines += ["", f"### {ds}: recall by the deepest sub-domain of the colliding test rows (mean ± std over seeds)",
                  "", "| method | sub-domain | colliding rows | recall |", "|---|---:|---:|---:|"]
        for k in keys:
            g = groups[k]
            if "recall" not in g:
                lines.append(row(k[1], "—", "—", "—"))
                continue
            m, s, n = mean_std(g["recall"][0])
            for i in range(len(m)):
                lines.append(row(k[1], i, g["recall"][1][i], _pm(m[i], s[i], n[i])))
        lines.append("")
    return lines


def pareto_markdown(points: list[dict], chosen_path: Path | None) -> list[str]:
    """Per data set a table of the configurations, cheapest first (then in method order)."""
    lines = []
    for ds in sorted({p["dataset"] for p in points}):
        pts = sorted((p for p in points if p["dataset"] == ds),
                     key=lambda p: (p["n_parameters"] or 0, method_order(p["method"])))
        lines += [f"### {ds}: accuracy against detector size and inference time (mean ± std over seeds)", "",
                  "Configuration: K sub-domains, L level-2 size, detector state / hidden width. Inference: CPU, "
                  "µs per sample of the final detector's forward pass (median of 5 after a warm-up). Front: on the "
                  "Pareto front (no other configuration of the same latent space is as accurate for less: each latent "
                  "space has its own box U(Z), test set and collision rate, so accuracy compares only within one).",
                  "",
                  "| configuration | method | seeds | parameters | µs / sample, batch 4096 | µs / sample, batch 1 "
                  "| accuracy | front (parameters) | front (time) | chosen |",
                  "|---|---|---:|---:|---:|---:|---:|---|---|---|"]
        for p in pts:
            us = "—" if p["us_b4096_mean"] is None else pm(p["us_b4096_mean"], p["us_b4096_std"], p["n_timed"], ".2f")
            us1 = "—" if p["us_b1_mean"] is None else f"{p['us_b1_mean']:.0f}"
            params = "—" if p["n_parameters"] is None else f"{p['n_parameters']:.0f}"
            lines.append(row(p["label"], p["method"], p["n_seeds"], params, us, us1,
                             _pm(p["accuracy_mean"], p["accuracy_std"], p["n_seeds"]),
                             "yes" if p["front_parameters"] else "", "yes" if p["front_time"] else "",
                             "**chosen**" if p["chosen"] else ""))
        if chosen_path is not None and not any(p["chosen"] for p in pts):
            lines.append(f"\nThe choice in {chosen_path} matches no configuration of {ds}.")
        lines.append("")
    return lines
