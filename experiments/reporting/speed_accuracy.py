"""Speed against accuracy: the chart of one run (``speed_accuracy.png`` in its run directory) and the
report's section (per data set a table and ``speed_accuracy_<data set>.png``, medians over the runs).

A point is one entry of ``metrics["speed_accuracy"]["points"]`` (:mod:`neuralcol.stages.speed`): ``method``,
``variant``, ``samples_per_s`` (code in, verdict out, one process), ``accuracy`` and ``fnr`` on the run's U(Z) test
set (None: not measured), ``n_timed``, ``n_scored``. The chart: two panels side by side, x = samples per second (log),
y = accuracy (left) and FNR (right); one colour and marker per method, every point labelled with its variant, the
cascade's targets joined by a line (cheapest target FNR last).
"""

from __future__ import annotations

import statistics
from pathlib import Path

from experiments.reporting.discover import by_dataset, method
from experiments.reporting.markdown import row

STYLES = {"exact": ("k", "s"), "meshlab": ("C1", "D"), "fcl": ("C2", "^"), "latent detector": ("C0", "o"),
          "mesh detector": ("C4", "v"),  # (the separate mesh detector: points of older runs)
          "code+mesh detector": ("C5", "o"), "cascade": ("C3", "P")}  # method -> (colour, marker)
# methods whose accuracy depends on the trained detector (the report keeps them apart per training method)
TRAINED = ("latent detector", "mesh detector", "code+mesh detector", "cascade")


def _style_of(name: str, i: int) -> tuple[str, str]:
    base = name.split(" (")[0]
    return STYLES.get(base, (f"C{5 + i % 5}", "X"))


def _target(p: dict) -> float:
    """The target FNR of a cascade point (its variant ``FNR<=t``)."""
    try:
        return float(p["variant"].split("<=", 1)[1])
    except (IndexError, ValueError):
        return float("inf")


# label offsets from the point, in points, tried in turn (beyond the first two with a leader line to the point)
MARKER_SIZE = 55  # scatter marker area, points²
OFFSETS = [(6, 3), (6, -3)] + [(dx, sign * dy) for dx in (10, -10) for dy in (16, 29, 42, 55, 68) for sign in (1, -1)]


def _place_labels(ax, items: list[tuple[float, float, str, str]]) -> None:
    """Annotate (x, y, text, colour) items, fastest point first, each at the first offset of :data:`OFFSETS` whose
    text box lies inside the axes and covers no marker and no label placed before it (else the first offset that
    covers none, else the first), so the labels of a cluster stack instead of overlapping."""
    from matplotlib.transforms import Bbox

    renderer = ax.figure.canvas.get_renderer()
    frame = ax.get_window_extent(renderer)
    r = MARKER_SIZE ** 0.5 / 2 * ax.figure.dpi / 72 + 1  # a marker's radius in pixels: no label covers one
    placed = [Bbox.from_bounds(px - r, py - r, 2 * r, 2 * r) for px, py in
              ax.transData.transform([(x, y) for x, y, _, _ in items])] if items else []

    def annotate(x, y, text, colour, k: int, lead: bool = True):
        dx, dy = OFFSETS[k]
        lead = dict(arrowstyle="-", lw=0.6, color=colour, alpha=0.7, shrinkA=0, shrinkB=3) if lead and k > 1 else None
        return ax.annotate(text, (x, y), fontsize=9, color=colour, xytext=(dx, dy), textcoords="offset points",
                           ha="left" if dx > 0 else "right", va="bottom" if dy > 0 else "top", annotation_clip=False,
                           arrowprops=lead)

    def box_at(x, y, text, colour, k: int):
        ann = annotate(x, y, text, colour, k, lead=False)  # the text's box (with a leader line it spans the point)
        box = ann.get_window_extent(renderer).expanded(1.02, 1.1)
        ann.remove()
        return box

    for item in sorted(items, key=lambda t: (-t[0], -t[1])):
        boxes = [box_at(*item, k) for k in range(len(OFFSETS))]
        free = [not any(b.overlaps(p) for p in placed) for b in boxes]
        inside = [frame.x0 <= b.x0 and b.x1 <= frame.x1 and frame.y0 <= b.y0 and b.y1 <= frame.y1 for b in boxes]
        k = next((k for k in range(len(OFFSETS)) if free[k] and inside[k]), None)
        k = next((k for k in range(len(OFFSETS)) if free[k]), 0) if k is None else k
        annotate(*item, k)
        placed.append(boxes[k])


def plot_speed_accuracy(points: list[dict], path: str | Path, title: str) -> None:
    """Accuracy (left) and FNR (right) against samples per second (log x) of ``points``, written to ``path``.

    Points without a throughput are left out; a point without accuracy (or FNR) is left out of that panel.
    """
    from experiments.reporting.plots import figure

    pts = [p for p in points if p.get("samples_per_s")]
    methods = list(dict.fromkeys(p["method"] for p in pts))
    with figure(Path(path), 1, 2, (13, 5.2)) as axes:
        fig = axes[0][0].figure
        fig.suptitle(title, fontsize=11)
        panels = ((axes[0][0], "accuracy", "accuracy on the U(Z) test set"),
                  (axes[0][1], "fnr", "false negative rate (colliding judged free)"))
        labels = {}
        for ax, key, ylabel in panels:
            labels[key] = []
            for i, m in enumerate(methods):
                colour, marker = _style_of(m, i)
                mp = [p for p in pts if p["method"] == m and p.get(key) is not None]
                if not mp:
                    continue
                if m.split(" (")[0] == "cascade":
                    mp = sorted(mp, key=_target)
                    ax.plot([p["samples_per_s"] for p in mp], [p[key] for p in mp], "-", color=colour, alpha=0.7)
                ax.scatter([p["samples_per_s"] for p in mp], [p[key] for p in mp], s=MARKER_SIZE, color=colour,
                           marker=marker, edgecolor="k", linewidths=0.5, zorder=3, label=m)
                labels[key] += [(p["samples_per_s"], p[key], p["variant"].replace("bfloat16_checked", "bf16 checked"),
                                 colour) for p in mp]
            ax.set_xscale("log")
            ax.margins(y=0.12)
            if pts:  # room for the labels: a factor 3 left of the slowest, 100 right of the fastest
                ax.set_xlim(min(p["samples_per_s"] for p in pts) / 3, max(p["samples_per_s"] for p in pts) * 100)
            if key == "fnr":
                ax.set_ylim(bottom=min(0.0, ax.get_ylim()[0]))
            ax.set_xlabel("samples per second, code → verdict, one process (log)")
            ax.set_ylabel(ylabel)
            ax.grid(alpha=0.3, which="both")
        handles = axes[0][0].get_legend_handles_labels()
        if handles[0]:  # one legend: where the left panel has no points (slow and inaccurate)
            axes[0][0].legend(*handles, fontsize=9, loc="lower left")
        fig.tight_layout()  # the final layout before the labels are placed by their text boxes
        for ax, key, _ in panels:
            _place_labels(ax, labels[key])


# ----------------------------------------------------------------------------------------------- report
def speed_accuracy_groups(runs: list[dict]) -> tuple[dict[str, list[dict]], list[str]]:
    """Per data set, the points of its runs pooled: medians over the runs (seeds) of every method and variant.

    Points of the trained methods (:data:`TRAINED`) are kept apart per training method when a data set has runs of
    several (``latent detector (active)``). Returns ``({data set: points}, notes on runs without the stage)``.
    """
    out, notes = {}, []
    for ds, ds_runs in by_dataset(runs).items():
        have = [r for r in ds_runs if (r.get("speed_accuracy") or {}).get("points")]
        if len(have) < len(ds_runs):
            notes.append(f"{len(ds_runs) - len(have)} of {len(ds_runs)} {ds} runs have no speed_accuracy (finished "
                         "before the stage existed, or speed_accuracy.enabled=false) and are left out of its chart")
        if not have:
            continue
        several = len({method(r) for r in have}) > 1
        cells: dict[tuple[str, str], list[tuple[dict, dict]]] = {}
        for r in have:
            for p in r["speed_accuracy"]["points"]:
                name = f"{p['method']} ({method(r)})" if several and p["method"] in TRAINED else p["method"]
                cells.setdefault((name, p["variant"]), []).append((p, r))
        pts = []
        for (name, variant), got in cells.items():
            pts.append({"method": name, "variant": variant, "samples_per_s": _median(got, "samples_per_s"),
                        "accuracy": _median(got, "accuracy"), "fnr": _median(got, "fnr"),
                        "n_timed": got[0][0]["n_timed"], "n_scored": got[0][0]["n_scored"], "n_runs": len(got),
                        "threads": sorted({r["speed_accuracy"]["threads"] for _, r in got})})
        out[ds] = pts
    return out, notes


def _median(got: list[tuple[dict, dict]], key: str) -> float | None:
    vals = [p[key] for p, _ in got if p.get(key) is not None]
    return statistics.median(vals) if vals else None


def _fmt(x, spec: str) -> str:
    return "—" if x is None else format(x, spec)


def speed_accuracy_markdown(groups: dict[str, list[dict]], notes: list[str]) -> list[str]:
    """The section of report.md: per data set a table (fastest first) and its chart."""
    lines = ["## Speed against accuracy (speed_accuracy_<data set>.png)", "",
             "Samples per second of code → verdict in one process (decoding included where the mesh is judged; the "
             "latent detector on batches of speed_accuracy.batch rows, 4096 by default; timed side by side within "
             "each run, torch threads as the run had them), against accuracy and FNR on the run's U(Z) test set; "
             "medians over the runs. Cascade: one row per target FNR (the cascade stage's own throughput figure). "
             "Scored on: test codes the accuracy is measured on.",
             ""]
    for ds, pts in groups.items():
        threads = sorted({t for p in pts for t in p["threads"]})
        lines += [f"### {ds}: speed against accuracy (medians over runs; torch threads {threads})", "",
                  "| method | variant | runs | samples / s | accuracy | FNR | scored on |",
                  "|---|---|---:|---:|---:|---:|---:|"]
        for p in sorted(pts, key=lambda p: -(p["samples_per_s"] or 0)):
            lines.append(row(p["method"], p["variant"], p["n_runs"], _fmt(p["samples_per_s"], ".4g"),
                             _fmt(p["accuracy"], ".4f"), _fmt(p["fnr"], ".4f"), p["n_scored"]))
        lines += ["", f"![{ds}: speed against accuracy](speed_accuracy_{ds}.png)", ""]
    return lines + [f"Left out: {n}" for n in notes] + ([""] if notes else [])


def write_speed_accuracy(runs: list[dict], out: Path) -> tuple[list[str], list[str], dict]:
    """Write ``speed_accuracy_<data set>.png`` into ``out``; returns (Markdown lines, chart names, numbers)."""
    groups, notes = speed_accuracy_groups(runs)
    charts = []
    for ds, pts in groups.items():
        name = f"speed_accuracy_{ds}.png"
        n = max(p["n_runs"] for p in pts)
        plot_speed_accuracy(pts, out / name, f"{ds}: speed against accuracy (median over {n} run{'s' * (n > 1)})")
        charts.append(name)
    lines = speed_accuracy_markdown(groups, notes) if groups else []  # no run has it: no section at all
    return lines, charts, {"speed_accuracy": groups}
