"""The report written into its output directory: ``report.md``, ``table3.csv``, ``report.json`` and the charts."""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

from experiments.reporting import plots
from experiments.reporting.aggregate import (
    aggregate,
    cost_curves,
    failure_groups,
    failure_numbers,
    label_prices,
    mark_fronts,
    pareto_points,
    projection_runs,
    table3,
)
from experiments.reporting.discover import dataset, find_runs, load_bench, load_chosen
from experiments.reporting.markdown import markdown
from experiments.reporting.speed_accuracy import write_speed_accuracy
from experiments.reporting.tradeoff_tables import tradeoff_markdown
from neuralcol.metrics.breakdown import PD_BIN_NAMES


@dataclass
class Written:
    """What :func:`write_report` wrote: the text of report.md, notes on left-out runs, the chart names."""

    text: str
    notes: list[str]
    charts: list[str]
    n_runs: int


def write_tradeoffs(runs: list[dict], dirs: list[Path], out: Path, priced: dict) -> tuple[list[str], list[str], dict]:
    """Write ``pareto.png``, ``cost.png`` and ``failures.png`` into ``out``.

    Args:
        runs: the report's runs (metrics.json dicts with ``_path``).
        dirs: the directories given to the report (searched for ``model_size.json``).
        out: output directory.
        priced: ``{dataset: labeling seconds per sample | None}``.

    Returns:
        (Markdown lines for report.md, notes on left-out runs (one line each), numbers for report.json).
    """
    chosen, chosen_path = load_chosen(dirs)
    points = pareto_points(runs)
    mark_fronts(points, chosen)
    groups, notes = failure_groups(runs)
    untimed = [r["_path"] for r in runs if not r["detector"].get("inference_us")]
    if untimed:
        notes.insert(0, f"{len(untimed)} of {len(runs)} runs have no detector.inference_us (finished before it was "
                        f"recorded) and are left out of the time panel of pareto.png: {', '.join(untimed)}")
    plots.plot_pareto(points, out / "pareto.png")
    plots.plot_cost(cost_curves(runs, priced), out / "cost.png")
    plots.plot_failures(groups, out / "failures.png")
    lines = tradeoff_markdown(points, groups, chosen, chosen_path, notes)
    numbers = {"pareto": points, "failures": failure_numbers(groups), "pd_bins": list(PD_BIN_NAMES)}
    return lines, notes, numbers


def _write_table3(rows: list[dict], path: Path) -> None:
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: (json.dumps(v) if isinstance(v, list) else v) for k, v in r.items()})


def write_report(dirs: list[Path], out: Path | None = None, bench_path: Path | None = None) -> Written:
    """Compare the runs below ``dirs`` and write the report into ``out`` (default: the first directory).

    Raises:
        UserInputError: a directory is missing, holds no run, or has a bad ``model_size.json``.
    """
    runs = find_runs(dirs)
    agg = aggregate(runs)
    rows = table3(runs, agg)
    bench = load_bench(bench_path)
    out = out or dirs[0]
    out.mkdir(parents=True, exist_ok=True)
    text = markdown(runs, agg, rows, bench)
    trade_lines, notes, trade = write_tradeoffs(runs, dirs, out, label_prices(runs))
    text += "\n" + "\n".join(trade_lines)
    speed_lines, speed_charts, speed = write_speed_accuracy(runs, out)  # runs with metrics["speed_accuracy"]
    if speed_lines:
        text += "\n" + "\n".join(speed_lines)
    (out / "report.md").write_text(text)
    _write_table3(rows, out / "table3.csv")
    plain = {ds: {m: {str(s): dict(c) for s, c in sizes.items()} for m, sizes in ms.items()} for ds, ms in agg.items()}
    (out / "report.json").write_text(json.dumps({"table3": rows, "rounds": plain, **trade, **speed},
                                                    indent=2))
    charts = ["accuracy.png", "fnr.png", "pareto.png", "cost.png", "failures.png"]
    plots.plot(agg, "accuracy", out / "accuracy.png")
    plots.plot(agg, "fnr", out / "fnr.png")
    if plots.plot(agg, "handling_success", out / "handling.png"):
        charts.append("handling.png")
    plots.plot_speed(agg, bench, out / "speed.png")
    plots.plot_stability(agg, runs, out / "stability.png")
    charts += ["speed.png", "stability.png"]
    charts += speed_charts
    proj = projection_runs(runs)
    if proj:
        from experiments.diagnose import plot as plot_diagnosis

        names = sorted({dataset(r) for r in runs})
        plot_diagnosis({"projection": proj}, out, f"{', '.join(names)}: projected samples per round")
        charts.append("projection.png")
    return Written(text, notes, charts, len(runs))
