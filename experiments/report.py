"""Compare methods across runs: ``python -m experiments.report RUN_OR_SWEEP_DIR... [--out DIR]``.

Reads every ``metrics.json`` below the given directories (a Hydra multirun directory, single run directories,
or any mix), groups the runs by data set and method, and writes into ``--out`` (default: the first directory):

* ``report.md``: per data set, accuracy and false negative rate of each method at each data set size,
  mean ± std over seeds (number of seeds in brackets when not all seeds reached that size), and the
  base-rate (majority-class) accuracy of the test set;
* the collision handler with each method's final detector (runs with a ``handling`` entry): success rate,
  fully-resolved rate, mean relative PD reduction and embedding difference (successful inputs), time per
  mesh, for the detector alone (the paper's protocol) and after exact verification, mean ± std over seeds;
* ``accuracy.png`` and ``fnr.png``: the same as charts (paper Figs. 3 and 4), one panel per data set;
* ``report.json``: the aggregated numbers.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from neuralcol.errors import UserInputError
from neuralcol.utils.cli import report_user_errors

METHOD_ORDER = ("supv", "supv_bd", "active")
LABELS = {"supv": "Supv", "supv_bd": "Supv+bd", "active": "Active+bd (ours)"}


def find_runs(dirs: list[Path]) -> list[dict]:
    """metrics.json files below ``dirs`` that hold detector rounds, as dicts (with ``_path``)."""
    runs = []
    for d in dirs:
        if not d.exists():
            raise UserInputError(f"{d}: no such directory")
        for path in sorted(d.rglob("metrics.json")):
            m = json.loads(path.read_text())
            if m.get("rounds"):
                m["_path"] = str(path.parent)
                runs.append(m)
    if not runs:
        raise UserInputError(f"no metrics.json with detector rounds below {[str(d) for d in dirs]}; run "
                             "`python -m experiments.run` first")
    return runs


def _seed(run: dict) -> int | None:
    cfg = Path(run["_path"]) / ".hydra" / "config.yaml"
    if cfg.is_file():
        for line in cfg.read_text().splitlines():
            if line.startswith("seed:"):
                return int(line.split(":", 1)[1])
    return run.get("seed")


def aggregate(runs: list[dict]) -> dict:
    """{dataset: {method: {size: {metric: [values over seeds]}}, "_base": {size: [...]}}}."""
    out: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(lambda: defaultdict(list))))
    for run in runs:
        ds, method = run["dataset"]["name"], run["detector"]["method"]
        for r in run["rounds"]:
            cell = out[ds][method][int(r["dataset_size"])]
            for key in ("accuracy", "fnr", "fpr", "balanced_accuracy", "majority_accuracy"):
                cell[key].append(float(r[key]))
            cell["seed"].append(_seed(run))
    return out


HANDLING_KEYS = (("success_rate", "success"), ("resolved_rate", "resolved"), ("mean_pd_reduction", "PD reduction"),
                 ("mean_embedding_diff", "‖Z − Z_user‖"), ("seconds_per_mesh", "ms / mesh"))


def handling_markdown(runs: list[dict]) -> str:
    """Table of the handler's exact results per data set and method (final detectors), mean ± std over runs."""
    cells: dict = defaultdict(lambda: defaultdict(list))
    for run in runs:
        h = run.get("handling")
        if not h:
            continue
        ds, method = run["dataset"]["name"], run["detector"]["method"]
        cells[(ds, method, "detector only")]["_n"].append(h["n"])
        for mode, m in (("detector only", h), ("verified", h.get("verified"))):
            if m:
                for key, _ in HANDLING_KEYS:
                    scale = 1e3 if key == "seconds_per_mesh" else 1.0
                    cells[(ds, method, mode)][key].append(scale * float(m[key]))
    if not cells:
        return ""
    lines = []
    for ds in sorted({k[0] for k in cells}):
        keys = sorted((k for k in cells if k[0] == ds),
                      key=lambda k: (METHOD_ORDER.index(k[1]) if k[1] in METHOD_ORDER else 99, k[2]))
        n_in = cells[(ds, keys[0][1], "detector only")]["_n"]
        lines += [f"### {ds}: collision handler, exact PD after handling ({n_in[0]} self-penetrating test inputs; "
                  "mean ± std over seeds)", "",
                  "| method | handler | " + " | ".join(t for _, t in HANDLING_KEYS) + " |",
                  "|---|---|" + "---:|" * len(HANDLING_KEYS)]
        for k in keys:
            vals = cells[k]
            row = []
            for key, _ in HANDLING_KEYS:
                v = np.asarray(vals[key])
                pct = key in ("success_rate", "resolved_rate", "mean_pd_reduction")
                f = (lambda x: f"{100 * x:.1f}%") if pct else (lambda x: f"{x:.1f}")
                row.append(f"{f(v.mean())} ± {f(v.std(ddof=1))}" if len(v) > 1 else f(v.mean()))
            lines.append(f"| {LABELS.get(k[1], k[1])} | {k[2]} | " + " | ".join(row) + " |")
        lines.append("")
    return "\n".join(lines)


def _fmt(values: list[float], n_seeds: int) -> str:
    if not values:
        return "—"
    v = np.asarray(values)
    s = f"{v.mean():.4f} ± {v.std(ddof=1):.4f}" if len(v) > 1 else f"{v.mean():.4f}"
    return s if len(v) == n_seeds else f"{s} ({len(v)})"


def markdown(agg: dict) -> str:
    lines = []
    for ds, methods in sorted(agg.items()):
        names = [m for m in METHOD_ORDER if m in methods] + sorted(set(methods) - set(METHOD_ORDER))
        n_seeds = max(len({s for cell in methods[m].values() for s in cell["seed"]}) for m in names)
        sizes = sorted({s for m in names for s in methods[m]})
        for metric, title in (("accuracy", "accuracy"), ("fnr", "false negative rate")):
            lines += [f"### {ds}: {title} (mean ± std over {n_seeds} seeds)", "",
                      "| data set size | " + " | ".join(LABELS.get(m, m) for m in names) + " |",
                      "|---:|" + "---:|" * len(names)]
            for size in sizes:
                cells = [_fmt(methods[m].get(size, {}).get(metric, []), n_seeds) for m in names]
                lines.append(f"| {size} | " + " | ".join(cells) + " |")
            lines.append("")
        base = [v for m in names for cell in methods[m].values() for v in cell["majority_accuracy"]]
        lines += [f"Majority-class accuracy of the test set: {np.mean(base):.4f}.", ""]
    return "\n".join(lines)


def plot(agg: dict, metric: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    datasets = sorted(agg)
    fig, axes = plt.subplots(1, len(datasets), figsize=(4.5 * len(datasets), 3.4), squeeze=False)
    for ax, ds in zip(axes[0], datasets):
        for m in [m for m in METHOD_ORDER if m in agg[ds]] + sorted(set(agg[ds]) - set(METHOD_ORDER)):
            sizes = sorted(agg[ds][m])
            mean = np.array([np.mean(agg[ds][m][s][metric]) for s in sizes])
            std = np.array([np.std(agg[ds][m][s][metric]) for s in sizes])
            ax.plot(sizes, mean, marker="o", label=LABELS.get(m, m))
            ax.fill_between(sizes, mean - std, mean + std, alpha=0.2)
        ax.set_title(ds)
        ax.set_xlabel("data set size |D_c|")
        ax.set_ylabel({"accuracy": "test accuracy", "fnr": "false negative rate"}[metric])
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.report", description=__doc__.splitlines()[0])
    parser.add_argument("dirs", nargs="+", type=Path, help="run or multirun directories")
    parser.add_argument("--out", type=Path, default=None, help="output directory (default: the first DIR)")
    args = parser.parse_args(argv)
    runs = find_runs(args.dirs)
    agg = aggregate(runs)
    out = args.out or args.dirs[0]
    out.mkdir(parents=True, exist_ok=True)
    text = markdown(agg) + "\n" + handling_markdown(runs)
    (out / "report.md").write_text(text)
    plain = {ds: {m: {str(s): dict(c) for s, c in sizes.items()} for m, sizes in ms.items()} for ds, ms in agg.items()}
    (out / "report.json").write_text(json.dumps(plain, indent=2))
    plot(agg, "accuracy", out / "accuracy.png")
    plot(agg, "fnr", out / "fnr.png")
    print(text)
    print(f"{len(runs)} runs; wrote {out / 'report.md'}, accuracy.png, fnr.png, report.json", file=sys.stderr)


if __name__ == "__main__":
    main()
