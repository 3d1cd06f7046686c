"""The report's charts: curves per size, cost, stability, Pareto front and failure breakdowns (matplotlib, Agg)."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

import numpy as np

from experiments.reporting.aggregate import latent_key, seed_mean_std
from experiments.reporting.discover import (
    PAPER_TABLE3,
    dataset,
    label,
    method,
    method_order,
    ordered_methods,
    paper_figures,
)
from neuralcol.metrics.breakdown import PD_BIN_EDGES, PD_BIN_NAMES, mean_std

N_COLLIDING_BINS = sum(e >= 0 for e in PD_BIN_EDGES)  # bins above PD 0: where the handler's inputs lie
METRIC_LABELS = {"accuracy": "test accuracy", "fnr": "false negative rate", "handling_success": "handling success rate"}


# ------------------------------------------------------------------------------------------- helpers
@contextmanager
def figure(path: Path, nrows: int, ncols: int, figsize: tuple[float, float]):
    """A grid of axes (always 2-D), laid out, saved to ``path`` at 120 dpi and closed on exit."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(nrows, ncols, figsize=figsize, squeeze=False)
    try:
        yield axes
        fig.tight_layout()
        fig.savefig(path, dpi=120)
    finally:
        plt.close(fig)


def _style(ax, xlabel: str, ylabel: str, title: str, grid: str = "both") -> None:
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3, axis=grid)


def _unique_legend(ax, **kw) -> None:
    """A legend with each label once."""
    handles, labels = ax.get_legend_handles_labels()
    uniq = dict(zip(labels, handles))
    ax.legend(uniq.values(), uniq.keys(), **kw)


def _no_data(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes)


# ------------------------------------------------------------------------------------- per method
PAPER_NAMES = {"supv": "Supv", "supv_bd": "Supv+bd", "active": "Active+bd", "active_paper": "Active+bd"}


def plot(agg: dict, metric: str, path: Path) -> bool:
    """``metric`` vs data set size per method, mean ± std band (sample std over seeds), one panel per data set;
    accuracy and FNR also show the paper's Table 3 figure of each method at its final size (a star in the method's
    colour); False if no data."""
    datasets = [ds for ds in sorted(agg) if any(c[metric] for m in agg[ds].values() for c in m.values())]
    if not datasets:
        return False
    column = {"accuracy": 0, "fnr": 1}.get(metric)
    with figure(path, 1, len(datasets), (6.4 * len(datasets), 3.4)) as axes:
        for ax, ds in zip(axes[0], datasets):
            shown = set()
            for m in ordered_methods(agg[ds]):
                sizes = [s for s in sorted(agg[ds][m]) if agg[ds][m][s][metric]]
                if not sizes:
                    continue
                mean, std = np.array([seed_mean_std(agg[ds][m][s][metric]) for s in sizes]).T
                (line,) = ax.plot(sizes, mean, marker="o", label=label(m))
                ax.fill_between(sizes, mean - std, mean + std, alpha=0.2)
                paper = paper_figures(ds, m) if column is not None else None
                if paper is not None and PAPER_NAMES.get(m) not in shown:
                    shown.add(PAPER_NAMES.get(m))
                    ax.plot([PAPER_TABLE3[ds]["final_size"]], [paper[column]], marker="*", markersize=13,
                            linestyle="none", color=line.get_color(), markeredgecolor="black",
                            label=f"paper: {PAPER_NAMES.get(m, m)}")
            _style(ax, "data set size |D_c|", METRIC_LABELS[metric], ds)
            ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4))  # 2e5..5.5e5 overlapped in full
            ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.02, 1))  # beside: curves and stars free
    return True


def plot_speed(agg: dict, bench: dict | None, path: Path) -> None:
    """Accuracy vs cumulative cost per method (one panel per data set) + neural vs exact time per sample."""
    datasets = sorted(agg)
    n = len(datasets) + (1 if bench else 0)
    with figure(path, 1, n, (4.5 * n, 3.4)) as axes:
        for ax, ds in zip(axes[0], datasets):
            for m in ordered_methods(agg[ds]):
                sizes = sorted(agg[ds][m])
                cost = np.array([np.mean(agg[ds][m][s]["cost_seconds"]) for s in sizes]) / 60
                acc = np.array([np.mean(agg[ds][m][s]["accuracy"]) for s in sizes])
                ax.plot(cost, acc, marker="o", label=label(m))
            _style(ax, "cumulative labeling + training time (min)", "test accuracy", f"{ds}: accuracy vs cost")
            ax.legend()
        if bench:
            ax = axes[0][-1]
            names = ["neural\nbatch 4096", "neural\nbatch 1", "exact\n(decode + label)"]
            vals = [bench["detector_us_per_sample_b4096"], bench["detector_us_per_sample_b1"],
                    1e3 * bench["exact_ms_per_sample"]]
            bars = ax.bar(names, vals, color=["C2", "C1", "C3"])
            ax.set_yscale("log")
            ax.set_ylabel("µs per sample (log)")
            ax.set_title(f"detection time: {bench['neural_vs_exact_speedup']:.0f}× at batch 4096")
            for b, v in zip(bars, vals):
                ax.annotate(f"{v:.3g}", (b.get_x() + b.get_width() / 2, v), ha="center", va="bottom", fontsize=8)


def plot_stability(agg: dict, runs: list[dict], path: Path) -> None:
    """Per data set: accuracy std across seeds vs size per method; handling success vs size per seed."""
    datasets = sorted(agg)
    with figure(path, 2, len(datasets), (4.5 * len(datasets), 6.4)) as axes:
        for j, ds in enumerate(datasets):
            ax = axes[0][j]
            for m in ordered_methods(agg[ds]):
                sizes = [s for s in sorted(agg[ds][m]) if len(agg[ds][m][s]["accuracy"]) > 1]
                ax.plot(sizes, [np.std(agg[ds][m][s]["accuracy"], ddof=1) for s in sizes], marker="o", label=label(m))
            _style(ax, "data set size |D_c|", "std of test accuracy", f"{ds}: spread across seeds")
            ax.legend()
            ax = axes[1][j]
            any_h = False
            for i, m in enumerate(ordered_methods(agg[ds])):
                for run in (r for r in runs if dataset(r) == ds and method(r) == m):
                    pts = [(r["dataset_size"], r["handling"]["success_rate"]) for r in run["rounds"]
                           if r.get("handling")]
                    if pts:
                        any_h = True
                        x, y = zip(*pts)
                        ax.plot(x, y, marker=".", color=f"C{i}", alpha=0.7, label=label(m))
            if any_h:
                _unique_legend(ax)
            else:
                _no_data(ax, "no per-round handling\n(handler.eval_every_round=true)")
            _style(ax, "data set size |D_c|", "handling success rate", f"{ds}: handling success per seed")


# ---------------------------------------------------------------------------------------- trade-offs
def plot_pareto(points: list[dict], path: Path) -> None:
    """Per data set: accuracy against parameter count (log x) and against µs per sample at batch 4096."""
    datasets = sorted({p["dataset"] for p in points})
    methods = sorted({p["method"] for p in points}, key=method_order)
    with figure(path, len(datasets), 2, (10, 3.8 * len(datasets))) as axes:
        for row, ds in zip(axes, datasets):
            pts = [p for p in points if p["dataset"] == ds]
            for ax, key, front, xlabel in ((row[0], "n_parameters", "front_parameters", "detector parameters (log)"),
                                           (row[1], "us_b4096_mean", "front_time",
                                            "CPU inference, µs per sample at batch 4096 (log)")):
                have = [p for p in pts if p[key] is not None]
                for i, m in enumerate(methods):
                    mp = [p for p in have if p["method"] == m]
                    if mp:
                        ax.errorbar([p[key] for p in mp], [p["accuracy_mean"] for p in mp],
                                    yerr=[p["accuracy_std"] for p in mp], fmt="o", color=f"C{i}", capsize=3, label=m)
                for lat in sorted({latent_key(p) for p in have}):  # one front per latent space
                    on = sorted((p for p in have if p[front] and latent_key(p) == lat), key=lambda p: p[key])
                    if len(on) > 1:
                        ax.step([p[key] for p in on], [p["accuracy_mean"] for p in on], where="post", color="k",
                                alpha=0.6, label="Pareto front (per latent space)")
                for p in have:
                    ax.annotate(p["label"], (p[key], p["accuracy_mean"]), fontsize=7, xytext=(3, 3),
                                textcoords="offset points")
                    if p["chosen"]:
                        ax.scatter([p[key]], [p["accuracy_mean"]], s=220, marker="*", color="gold", edgecolor="k",
                                   zorder=5, label="chosen")
                if not have:
                    _no_data(ax, "no run records it\n(older metrics.json)")
                else:
                    ax.set_xscale("log")
                    from matplotlib.ticker import NullFormatter

                    ax.xaxis.set_minor_formatter(NullFormatter())  # minor log labels overlap on short ranges
                    _unique_legend(ax, fontsize=8)
                _style(ax, xlabel, "final test accuracy", ds)


def plot_cost(curves: dict, path: Path) -> None:
    """Per data set: accuracy against recorded and against priced cumulative seconds, mean ± std over seeds."""
    datasets = sorted(curves)
    with figure(path, len(datasets), 2, (10, 3.8 * len(datasets))) as axes:
        for row, ds in zip(axes, datasets):
            for ax, key, title in ((row[0], "recorded", "as recorded (cached samples free)"),
                                   (row[1], "priced", "every sample of D_c priced")):
                for i, m in enumerate(sorted(curves[ds], key=method_order)):
                    cells = [curves[ds][m][s] for s in sorted(curves[ds][m])]
                    x = np.array([[np.mean(c[key]), np.std(c[key])] for c in cells])
                    y = np.array([[np.mean(c["accuracy"]), np.std(c["accuracy"])] for c in cells])
                    ax.errorbar(x[:, 0], y[:, 0], xerr=x[:, 1], yerr=y[:, 1], marker="o", capsize=3, color=f"C{i}",
                                label=m)
                ax.set_xscale("log")
                _style(ax, "cumulative labeling + training + projection (s, log)", "test accuracy", f"{ds}: {title}")
                ax.legend(fontsize=8)


def plot_failures(groups: dict, path: Path) -> None:
    """Per data set: accuracy by PD bin, recall by deepest sub-domain, handler success by input PD bin; bars
    are means over seeds, error bars their std."""
    datasets = sorted({k[0] for k in groups})
    with figure(path, len(datasets), 3, (15, 3.8 * len(datasets))) as axes:
        for row, ds in zip(axes, datasets):
            keys = sorted((k for k in groups if k[0] == ds), key=lambda k: method_order(k[1]))
            width = 0.8 / max(len(keys), 1)
            unit = groups[keys[0]]["pd_unit"]
            panels = ((row[0], "accuracy", PD_BIN_NAMES, "detector accuracy"),
                      (row[1], "recall", None, "recall (colliding rows)"),
                      (row[2], "handler", PD_BIN_NAMES[-N_COLLIDING_BINS:], "handler success (detector only)"))
            for ax, measure, names, ylabel in panels:
                drawn = False
                for i, k in enumerate(keys):
                    if measure not in groups[k]:
                        continue
                    rate = groups[k][measure][0]
                    if measure == "handler":
                        rate = rate[:, -N_COLLIDING_BINS:]
                    mean, std, _ = mean_std(rate)
                    x = np.arange(len(mean)) + (i - (len(keys) - 1) / 2) * width
                    ax.bar(x, np.nan_to_num(mean), width, yerr=np.nan_to_num(std), capsize=3, color=f"C{i}",
                           label=k[1])
                    drawn = True
                    if names is None:
                        names = [str(j) for j in range(len(mean))]
                if drawn:
                    ax.set_xticks(np.arange(len(names)), names, fontsize=7, rotation=15)
                    ax.legend(fontsize=7)
                else:
                    _no_data(ax, "no per-run files\n(older runs)")
                ax.set_ylim(0, 1.05)
                _style(ax, "deepest sub-domain" if measure == "recall" else f"exact PD (units of {unit:.3g})", ylabel,
                       ds, grid="y")
