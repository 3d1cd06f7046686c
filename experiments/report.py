"""Compare methods across runs: ``python -m experiments.report RUN_OR_SWEEP_DIR... [--out DIR]``.

Reads every ``metrics.json`` below the given directories (a Hydra multirun directory, single run directories,
or any mix), groups the runs by data set and method (seeds are pooled: mean ± std), and writes into ``--out``
(default: the first directory):

* ``report.md`` and ``table3.csv``: the paper's Table 3 layout per data set — final data set size, accuracy
  and false negative rate of each method, the equivalent data set size (the size supv_bd needs to reach the
  method's final accuracy, linearly interpolated on supv_bd's mean accuracy curve, as in the paper), and the
  detector's parameter count; then accuracy and FNR at every size, the collision handler's exact results,
  the speed figures and the stability checks;
* ``accuracy.png``, ``fnr.png``, ``handling.png``: accuracy, FNR and handling success (runs with
  ``handler.eval_every_round=true``) vs data set size, mean ± std bands over seeds (paper Figs. 3-5);
* ``speed.png``: accuracy against cumulative labeling + training time per method, and neural vs exact
  detection time per sample (from ``bench/results.json`` when present);
* ``stability.png``: the spread of accuracy across seeds per method and size, and handling success vs size
  per seed (is it monotone?);
* ``projection.png`` and a table in ``report.md`` (active runs): where the projected samples of each round
  landed: share within eps and 2 eps of the true boundary, next to the round's uniform samples, and how far
  each latent level moved (docs/diagnosis.md);
* ``pareto.png``, ``cost.png``, ``failures.png`` and their tables (:mod:`experiments.report_tradeoffs`): accuracy
  against detector size and CPU inference time with the Pareto front (and the choice of a ``model_size.json``
  in a given directory marked), accuracy against cumulative seconds per method, and where each method fails:
  detector accuracy by exact-PD bin and recall by sub-domain of the test rows, handler success by PD bin of its
  inputs, mean ± std over seeds;
* ``report.json``: the aggregated numbers.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from neuralcol.errors import UserInputError
from neuralcol.utils.cli import report_user_errors

ROOT = Path(__file__).resolve().parents[1]
METHOD_ORDER = ("supv", "supv_bd", "active_paper", "active")
LABELS = {"supv": "Supv", "supv_bd": "Supv+bd", "active_paper": "Active+bd (paper's text)",
          "active": "Active+bd (ours)"}
HANDLING_KEYS = (("success_rate", "success"), ("resolved_rate", "resolved"), ("mean_pd_reduction", "PD reduction"),
                 ("mean_embedding_diff", "‖Z − Z_user‖"), ("seconds_per_mesh", "ms / mesh"))


# ------------------------------------------------------------------------------------------------ loading
def find_runs(dirs: list[Path]) -> list[dict]:
    """metrics.json files below ``dirs`` that hold detector rounds, as dicts (with ``_path`` and ``_seed``)."""
    runs = []
    for d in dirs:
        if not d.exists():
            raise UserInputError(f"{d}: no such directory")
        for path in sorted(d.rglob("metrics.json")):
            m = json.loads(path.read_text())
            if m.get("rounds"):
                m["_path"] = str(path.parent)
                m["_seed"] = _seed(m)
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


def detector_parameters(run: dict) -> int | None:
    """The run's detector parameter count (metrics.json, or counted from ``detector.pt`` for older runs)."""
    n = run["detector"].get("n_parameters")
    if n is None and (Path(run["_path"]) / "detector.pt").is_file():
        from neuralcol.stages.detector import load_detector

        net, _ = load_detector(Path(run["_path"]) / "detector.pt")
        n = int(sum(p.numel() for p in net.parameters()))
    return n


def method_order(name: str) -> tuple[int, str]:
    """Sort key of a method name, or of a label that starts with one (``"active (K8 L3 64/128)"``)."""
    m = name.split(" (")[0]
    return (METHOD_ORDER.index(m) if m in METHOD_ORDER else len(METHOD_ORDER), name)


def _methods(names) -> list[str]:
    return [m for m in METHOD_ORDER if m in names] + sorted(set(names) - set(METHOD_ORDER))


def label_cost_per_sample(runs: list[dict]) -> tuple[float | None, str]:
    """Seconds per exactly labeled sample on this data set (for the cost axis; cached samples were paid for
    once, by whichever run labeled them first): from a run that labeled the test set, else from the rounds."""
    for run in runs:
        t = run["detector"].get("test_set", {})
        if t.get("labeled_now"):
            return t["label_seconds"] / t["labeled_now"], "test-set labeling"
    rates = {}
    for run in runs:
        prev_size, prev_label = 0, 0.0
        for r in run["rounds"]:
            d_label, d_size = r["label_seconds"] - prev_label, r["dataset_size"] - prev_size
            if d_label > 0 and d_size > 0:
                rates.setdefault(run["detector"]["method"], []).append(d_label / d_size)
            prev_size, prev_label = r["dataset_size"], r["label_seconds"]
    # supv labels every new uniform sample itself (its pools are labeled by the first run that needs them);
    # the other methods take part of theirs from the cache, so their rates understate the cost
    for method in ("supv", *sorted(rates)):
        if rates.get(method):
            return float(np.median(rates[method])), f"the median labeling time per new sample of the {method} runs"
    return None, "nothing labeled in these runs: labeling time as recorded"


# ------------------------------------------------------------------------------------------ aggregation
def aggregate(runs: list[dict]) -> dict:
    """{dataset: {method: {size: {metric: [values over seeds]}}}}, metrics of every round (accuracy, fnr, fpr,
    balanced_accuracy, majority_accuracy, cost_seconds, handling_success) and its seed."""
    out: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(lambda: defaultdict(list))))
    by_ds = defaultdict(list)
    for run in runs:
        by_ds[run["dataset"]["name"]].append(run)
    for ds, ds_runs in by_ds.items():
        c, _ = label_cost_per_sample(ds_runs)
        for run in ds_runs:
            method = run["detector"]["method"]
            for r in run["rounds"]:
                cell = out[ds][method][int(r["dataset_size"])]
                for key in ("accuracy", "fnr", "fpr", "balanced_accuracy", "majority_accuracy"):
                    cell[key].append(float(r[key]))
                label_s = r["dataset_size"] * c if c is not None else r["label_seconds"]
                cell["cost_seconds"].append(label_s + r["train_seconds"] + r.get("project_seconds", 0.0))
                if r.get("handling"):
                    cell["handling_success"].append(float(r["handling"]["success_rate"]))
                cell["seed"].append(run["_seed"])
    return out


def _mean_std(values) -> tuple[float, float]:
    v = np.asarray(values, dtype=float)
    return float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0


def _fmt(values: list[float], n_seeds: int) -> str:
    if not values:
        return "—"
    mean, std = _mean_std(values)
    s = f"{mean:.4f} ± {std:.4f}" if len(values) > 1 else f"{mean:.4f}"
    return s if len(values) == n_seeds else f"{s} ({len(values)})"


def equivalent_size(sizes: list[int], accuracy: list[float], target: float) -> tuple[float | None, str]:
    """Size at which the curve (sizes, accuracy) first reaches ``target``, linearly interpolated between the
    two sizes around it (paper Table 3, last row). Returns (size, note): note is "" when interpolated,
    "≤" when the first size already reaches it, ">" when the curve never does (size = last size)."""
    if not sizes:
        return None, ""
    if accuracy[0] >= target:
        return float(sizes[0]), "≤"
    for i in range(1, len(sizes)):
        if accuracy[i] >= target:
            s0, s1, a0, a1 = sizes[i - 1], sizes[i], accuracy[i - 1], accuracy[i]
            return float(s0 + (target - a0) / (a1 - a0) * (s1 - s0)), ""
    return float(sizes[-1]), ">"


def table3(runs: list[dict], agg: dict) -> list[dict]:
    """Rows of the paper's Table 3: per data set and method, final size and accuracy/FNR (mean ± std over
    seeds at each run's last round), equivalent supv_bd size and parameter count."""
    rows = []
    for ds in sorted(agg):
        ds_runs = [r for r in runs if r["dataset"]["name"] == ds]
        ref = agg[ds].get("supv_bd")
        ref_sizes = sorted(ref) if ref else []
        ref_acc = [float(np.mean(ref[s]["accuracy"])) for s in ref_sizes] if ref else []
        for method in _methods(agg[ds]):
            mr = [r for r in ds_runs if r["detector"]["method"] == method]
            final = [r["rounds"][-1] for r in mr]
            acc, fnr = [f["accuracy"] for f in final], [f["fnr"] for f in final]
            size = float(np.mean([f["dataset_size"] for f in final]))
            params = sorted({p for p in (detector_parameters(r) for r in mr) if p is not None})
            row = {"dataset": ds, "method": method, "n_seeds": len(mr), "final_size": size,
                   "accuracy_mean": _mean_std(acc)[0], "accuracy_std": _mean_std(acc)[1],
                   "fnr_mean": _mean_std(fnr)[0], "fnr_std": _mean_std(fnr)[1],
                   "equivalent_supv_bd_size": None, "equivalent_note": "",
                   "detector_parameters": params[0] if len(params) == 1 else (params or None)}
            if ref_sizes and method != "supv_bd":
                eq, note = equivalent_size(ref_sizes, ref_acc, row["accuracy_mean"])
                row["equivalent_supv_bd_size"], row["equivalent_note"] = eq, note
            rows.append(row)
    return rows


def monotone_handling(agg: dict) -> dict:
    """{(ds, method): (monotone?, number of drops)} of the mean handling success vs size (drops larger than
    one point count)."""
    out = {}
    for ds, methods in agg.items():
        for method, cells in methods.items():
            sizes = [s for s in sorted(cells) if cells[s]["handling_success"]]
            if len(sizes) < 2:
                continue
            mean = [np.mean(cells[s]["handling_success"]) for s in sizes]
            drops = int(sum(b < a - 0.01 for a, b in zip(mean, mean[1:])))
            out[(ds, method)] = (drops == 0, drops)
    return out


# ------------------------------------------------------------------------------------------- markdown
def markdown(runs: list[dict], agg: dict, rows: list[dict], bench: dict | None) -> str:
    lines = []
    for ds in sorted(agg):
        methods = agg[ds]
        names = _methods(methods)
        n_seeds = max(len({s for cell in methods[m].values() for s in cell["seed"]}) for m in names)
        lines += [f"## {ds}", "", f"### Table 3 layout (mean ± std over {n_seeds} seeds, last round of each run)", "",
                  "| | " + " | ".join(LABELS.get(m, m) for m in names) + " |", "|---|" + "---:|" * len(names)]
        ds_rows = {r["method"]: r for r in rows if r["dataset"] == ds}

        def eq(r):
            if r["equivalent_supv_bd_size"] is None:
                return "—"
            return f"{r['equivalent_note']}{r['equivalent_supv_bd_size']:.0f}"

        for title, f in (("data set size", lambda r: f"{r['final_size']:.0f}"),
                         ("accuracy", lambda r: f"{100 * r['accuracy_mean']:.2f}% ± {100 * r['accuracy_std']:.2f}"),
                         ("false negative rate", lambda r: f"{100 * r['fnr_mean']:.2f}% ± {100 * r['fnr_std']:.2f}"),
                         ("equivalent supv_bd size", eq),
                         ("detector parameters", lambda r: f"{r['detector_parameters']}")):
            lines.append(f"| {title} | " + " | ".join(f(ds_rows[m]) if m in ds_rows else "—" for m in names) + " |")
        lines += realistic_rows([r for r in runs if r["dataset"]["name"] == ds], names)
        ae = sorted({r["autoencoder"].get("n_parameters") for r in runs if r["dataset"]["name"] == ds} - {None})
        lines += ["", "Equivalent size: the data set size supv_bd needs to reach the method's final mean accuracy "
                  "(linear interpolation on supv_bd's mean accuracy curve; `>`: never reached within the sizes run, "
                  "`≤`: reached at the first size). Autoencoder parameters: "
                  f"{', '.join(str(a) for a in ae) or '—'}.", ""]
        sizes = sorted({s for m in names for s in methods[m]})
        for metric, title in (("accuracy", "accuracy"), ("fnr", "false negative rate")):
            lines += [f"### {title} vs data set size (mean ± std over seeds; (k): seeds that reached it)", "",
                      "| data set size | " + " | ".join(LABELS.get(m, m) for m in names) + " |",
                      "|---:|" + "---:|" * len(names)]
            for size in sizes:
                cells = [_fmt(methods[m].get(size, {}).get(metric, []), n_seeds) for m in names]
                lines.append(f"| {size} | " + " | ".join(cells) + " |")
            lines.append("")
        base = [v for m in names for c in methods[m].values() for v in c["majority_accuracy"]]
        lines += [f"Majority-class accuracy of the test set: {np.mean(base):.4f}.", ""]
        lines += [handling_markdown([r for r in runs if r["dataset"]["name"] == ds])]
        lines += speed_markdown(ds, [r for r in runs if r["dataset"]["name"] == ds], agg)
        lines += stability_markdown(ds, agg)
        lines += projection_markdown([r for r in runs if r["dataset"]["name"] == ds])
    if bench:
        lines += ["## Detection time per sample (bench/results.json)", "",
                  f"Neural detector {bench['detector_us_per_sample_b4096']:.1f} µs at batch 4096 and "
                  f"{bench['detector_us_per_sample_b1']:.0f} µs at batch 1; exact (decode + label, one core) "
                  f"{bench['exact_ms_per_sample']:.1f} ms: {bench['neural_vs_exact_speedup']:.0f}× "
                  f"(measured {bench.get('date', '?')})." + "".join(
                      f" {label}: {bench[f'detector_{key}_us_per_sample_b4096']:.2f} µs, "
                      f"{bench[f'neural_vs_exact_speedup_{key}']:.0f}×."
                      for key, label in (("compiled", "Compiled (`fast=\"float32\"`)"),
                                         ("compiled_bf16", "Compiled bfloat16 (`fast=\"bfloat16\"`)"),
                                         ("compiled_bf16_checked", "With a float32 recheck near 0 "
                                          "(`fast=\"bfloat16_checked\"`)"))
                      if f"neural_vs_exact_speedup_{key}" in bench), ""]
    return "\n".join(lines)


REALISTIC_ROWS = (  # (title, path into metrics["realistic"] or metrics, percent?)
    ("real meshes: accuracy, latent detector", ("realistic", "detection", "accuracy"), True),
    ("real meshes: FNR, latent detector", ("realistic", "detection", "fnr"), True),
    ("real meshes: accuracy, mesh detector", ("realistic", "detection_mesh", "accuracy"), True),
    ("real meshes: FNR, mesh detector", ("realistic", "detection_mesh", "fnr"), True),
    ("U(Z): accuracy, mesh detector", ("mesh_detector", "test", "accuracy"), True),
    ("real meshes: round trip keeps the label", ("realistic", "round_trip", "agreement"), True),
    ("real meshes: resolve, collision-free (detector-guided)",
     ("realistic", "handling", "detector_only", "resolved_rate"), True),
    ("real meshes: resolve, collision-free (verified)", ("realistic", "handling", "verified", "resolved_rate"), True),
    ("real meshes: resolve, median displacement (% diag)",
     ("realistic", "handling", "displacement_median_frac"), True),
    ("real meshes: contact repair alone, collision-free", ("realistic", "handling", "repair_only", "resolved_rate"),
     True),
)


def _dig(d, path):
    for k in path:
        if not isinstance(d, dict) or d.get(k) is None:
            return None
        d = d[k]
    return d


def realistic_rows(runs: list[dict], names: list[str]) -> list[str]:
    """The "real meshes" block of the Table 3 layout (issue 27): the realistic set's clear cases, mean ± std over
    the runs of each method; nothing when no run has a realistic evaluation."""
    if not any(r.get("realistic") for r in runs):
        return []
    out = []
    for title, path, pct in REALISTIC_ROWS:
        cells = []
        for m in names:
            vals = [v for r in runs if r["detector"]["method"] == m
                    for v in [_dig(r, path)] if v is not None and np.isfinite(v)]
            if not vals:
                cells.append("—")
                continue
            mean, std = _mean_std(vals)
            cells.append(f"{100 * mean:.2f}% ± {100 * std:.2f}" if pct else f"{mean:.3g} ± {std:.2g}")
        if any(c != "—" for c in cells):
            out.append(f"| {title} | " + " | ".join(cells) + " |")
    n = [r["realistic"]["n_clear"] for r in runs if r.get("realistic")]
    count = str(min(n)) if min(n) == max(n) else f"{min(n)}-{max(n)}"
    return out + ["", f"Real meshes: the realistic set's clear cases ({count} meshes nobody trained on, "
                  "labeled exactly, about half colliding; docs/real_meshes.md)."] if out else []


def projection_runs(runs: list[dict]) -> dict:
    """``{run dir: [round record with the projection statistics, ...]}`` of the runs that projected samples."""
    out = {}
    for run in runs:
        rs = [{"round": r["round"], "dataset_size": r["dataset_size"], **r["projection"]}
              for r in run["rounds"] if r.get("projection")]
        if rs:
            out[run["_path"]] = rs
    return out


def projection_markdown(runs: list[dict]) -> list[str]:
    """Per data set, the projection statistics per round (mean over the active runs)."""
    lines = []
    for ds in sorted({r["dataset"]["name"] for r in runs}):
        proj = projection_runs([r for r in runs if r["dataset"]["name"] == ds])
        if not proj:
            continue
        by_size: dict = defaultdict(list)
        for rs in proj.values():
            for r in rs:
                by_size[r["dataset_size"]].append(r)
        lines += [f"### {ds}: where the acquired samples landed (mean over {len(proj)} active runs)", "",
                  "The non-uniform half of each round: codes projected onto the detector's 0.5 level set "
                  "(`method.project: true`, `active_paper`) or the most uncertain candidates as drawn "
                  "(`project: false`, `active`'s default: they do not move). eps: the labeler's `boundary_eps`.", "",
                  "| \\|D_c\\| of the projecting detector | within eps | within 2 eps | uniform samples within 2 eps "
                  "| colliding | moved level 1 / level 2 (half-ranges) | on a box face (level 1 / 2) "
                  "| boundary search within 2 eps: last points / all (`method.refine_steps`) |",
                  "|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for size in sorted(by_size):
            rs = by_size[size]

            def m(key, rs=rs):
                vals = [r[key] for r in rs if r.get(key) is not None]
                return float(np.mean(vals)) if vals else float("nan")

            def sub(group, rs=rs):
                vals = [r[group]["within_2eps"] for r in rs if r.get(group)]
                return float(np.mean(vals)) if vals else float("nan")

            searched = (f"{sub('refined'):.3f} / {sub('refined_all'):.3f}" if any(r.get("refined") for r in rs)
                        else "–")
            lines.append(f"| {size} | {m('within_eps'):.3f} | {m('within_2eps'):.3f} | "
                         f"{sub('uniform'):.3f} | {m('colliding'):.3f} | "
                         f"{m('moved_level1'):.3f} / {m('moved_level2'):.3f} | "
                         f"{m('on_face_level1'):.3f} / {m('on_face_level2'):.3f} | {searched} |")
        lines.append("")
    return lines


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
        lines += [f"### collision handler, exact PD after handling ({n_in[0]} self-penetrating test inputs; "
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


def speed_markdown(ds: str, runs: list[dict], agg: dict) -> list[str]:
    c, source = label_cost_per_sample(runs)
    lines = ["### cost (cumulative labeling + training + projection, mean over seeds)", ""]
    if c is not None:
        lines += [f"Labeling priced at {1e3 * c:.1f} ms per sample (from {source}), for every sample of D_c, "
                  "whether this run labeled it or took it from the shared cache.", ""]
    lines += ["| method | final size | cost (min) | accuracy |", "|---|---:|---:|---:|"]
    for m in _methods(agg[ds]):
        last = max(agg[ds][m])
        cell = agg[ds][m][last]
        lines.append(f"| {LABELS.get(m, m)} | {last} | {np.mean(cell['cost_seconds']) / 60:.1f} | "
                     f"{np.mean(cell['accuracy']):.4f} |")
    return lines + [""]


def stability_markdown(ds: str, agg: dict) -> list[str]:
    lines = ["### stability (spread across seeds; handling success vs size)", "",
             "| method | seeds | largest accuracy std over sizes | handling success monotone in size |",
             "|---|---:|---:|---|"]
    mono = monotone_handling(agg)
    for m in _methods(agg[ds]):
        cells = agg[ds][m]
        stds = [np.std(c["accuracy"], ddof=1) for c in cells.values() if len(c["accuracy"]) > 1]
        n = max(len(c["seed"]) for c in cells.values())
        mo = mono.get((ds, m))
        mtxt = "— (no per-round handling; `handler.eval_every_round=true`)" if mo is None else \
            ("yes" if mo[0] else f"no ({mo[1]} drop{'s' if mo[1] > 1 else ''} > 1 point)")
        lines.append(f"| {LABELS.get(m, m)} | {n} | {max(stds) if stds else float('nan'):.4f} | {mtxt} |")
    return lines + [""]


# ---------------------------------------------------------------------------------------------- charts
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot(agg: dict, metric: str, path: Path) -> bool:
    """``metric`` vs data set size per method, mean ± std band, one panel per data set; False if no data."""
    datasets = [ds for ds in sorted(agg) if any(c[metric] for m in agg[ds].values() for c in m.values())]
    if not datasets:
        return False
    plt = _plt()
    fig, axes = plt.subplots(1, len(datasets), figsize=(4.5 * len(datasets), 3.4), squeeze=False)
    for ax, ds in zip(axes[0], datasets):
        for m in _methods(agg[ds]):
            sizes = [s for s in sorted(agg[ds][m]) if agg[ds][m][s][metric]]
            if not sizes:
                continue
            mean = np.array([np.mean(agg[ds][m][s][metric]) for s in sizes])
            std = np.array([np.std(agg[ds][m][s][metric]) for s in sizes])
            ax.plot(sizes, mean, marker="o", label=LABELS.get(m, m))
            ax.fill_between(sizes, mean - std, mean + std, alpha=0.2)
        ax.set_title(ds)
        ax.set_xlabel("data set size |D_c|")
        ax.set_ylabel({"accuracy": "test accuracy", "fnr": "false negative rate",
                       "handling_success": "handling success rate"}[metric])
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def plot_speed(agg: dict, bench: dict | None, path: Path) -> None:
    """Accuracy vs cumulative cost per method (one panel per data set) + neural vs exact time per sample."""
    plt = _plt()
    datasets = sorted(agg)
    n = len(datasets) + (1 if bench else 0)
    fig, axes = plt.subplots(1, n, figsize=(4.5 * n, 3.4), squeeze=False)
    for ax, ds in zip(axes[0], datasets):
        for m in _methods(agg[ds]):
            sizes = sorted(agg[ds][m])
            cost = np.array([np.mean(agg[ds][m][s]["cost_seconds"]) for s in sizes]) / 60
            acc = np.array([np.mean(agg[ds][m][s]["accuracy"]) for s in sizes])
            ax.plot(cost, acc, marker="o", label=LABELS.get(m, m))
        ax.set_title(f"{ds}: accuracy vs cost")
        ax.set_xlabel("cumulative labeling + training time (min)")
        ax.set_ylabel("test accuracy")
        ax.grid(alpha=0.3)
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
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_stability(agg: dict, runs: list[dict], path: Path) -> None:
    """Per data set: accuracy std across seeds vs size per method; handling success vs size per seed."""
    plt = _plt()
    datasets = sorted(agg)
    fig, axes = plt.subplots(2, len(datasets), figsize=(4.5 * len(datasets), 6.4), squeeze=False)
    for j, ds in enumerate(datasets):
        ax = axes[0][j]
        for m in _methods(agg[ds]):
            sizes = [s for s in sorted(agg[ds][m]) if len(agg[ds][m][s]["accuracy"]) > 1]
            ax.plot(sizes, [np.std(agg[ds][m][s]["accuracy"], ddof=1) for s in sizes], marker="o",
                    label=LABELS.get(m, m))
        ax.set_title(f"{ds}: spread across seeds")
        ax.set_xlabel("data set size |D_c|")
        ax.set_ylabel("std of test accuracy")
        ax.grid(alpha=0.3)
        ax.legend()
        ax = axes[1][j]
        any_h = False
        for i, m in enumerate(_methods(agg[ds])):
            for run in (r for r in runs if r["dataset"]["name"] == ds and r["detector"]["method"] == m):
                pts = [(r["dataset_size"], r["handling"]["success_rate"]) for r in run["rounds"] if r.get("handling")]
                if pts:
                    any_h = True
                    x, y = zip(*pts)
                    ax.plot(x, y, marker=".", color=f"C{i}", alpha=0.7,
                            label=f"{LABELS.get(m, m)}" if run is not None else None)
        if any_h:
            handles, labels = ax.get_legend_handles_labels()
            uniq = dict(zip(labels, handles))
            ax.legend(uniq.values(), uniq.keys())
        else:
            ax.text(0.5, 0.5, "no per-round handling\n(handler.eval_every_round=true)", ha="center", va="center",
                    transform=ax.transAxes)
        ax.set_title(f"{ds}: handling success per seed")
        ax.set_xlabel("data set size |D_c|")
        ax.set_ylabel("handling success rate")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def load_bench(path: Path | None) -> dict | None:
    path = path or ROOT / "bench" / "results.json"
    if not path.is_file():
        return None
    b = json.loads(path.read_text())
    keys = ("detector_us_per_sample_b1", "detector_us_per_sample_b4096", "exact_ms_per_sample",
            "neural_vs_exact_speedup")
    return b if all(k in b for k in keys) else None


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.report", description=__doc__.splitlines()[0])
    parser.add_argument("dirs", nargs="+", type=Path, help="run or multirun directories")
    parser.add_argument("--out", type=Path, default=None, help="output directory (default: the first DIR)")
    parser.add_argument("--bench", type=Path, default=None,
                        help="benchmark results for the detection-time panel (default: bench/results.json)")
    args = parser.parse_args(argv)
    runs = find_runs(args.dirs)
    agg = aggregate(runs)
    rows = table3(runs, agg)
    bench = load_bench(args.bench)
    out = args.out or args.dirs[0]
    out.mkdir(parents=True, exist_ok=True)
    text = markdown(runs, agg, rows, bench)
    from experiments.report_tradeoffs import write_tradeoffs

    priced = {ds: label_cost_per_sample([r for r in runs if r["dataset"]["name"] == ds])[0]
              for ds in {r["dataset"]["name"] for r in runs}}
    trade_lines, notes, trade = write_tradeoffs(runs, args.dirs, out, detector_parameters, priced, method_order)
    text += "\n" + "\n".join(trade_lines)
    (out / "report.md").write_text(text)
    with open(out / "table3.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: (json.dumps(v) if isinstance(v, list) else v) for k, v in r.items()})
    plain = {ds: {m: {str(s): dict(c) for s, c in sizes.items()} for m, sizes in ms.items()} for ds, ms in agg.items()}
    (out / "report.json").write_text(json.dumps({"table3": rows, "rounds": plain, **trade}, indent=2))
    charts = ["accuracy.png", "fnr.png", "pareto.png", "cost.png", "failures.png"]
    plot(agg, "accuracy", out / "accuracy.png")
    plot(agg, "fnr", out / "fnr.png")
    if plot(agg, "handling_success", out / "handling.png"):
        charts.append("handling.png")
    plot_speed(agg, bench, out / "speed.png")
    plot_stability(agg, runs, out / "stability.png")
    charts += ["speed.png", "stability.png"]
    proj = projection_runs(runs)
    if proj:
        from experiments.diagnose import plot as plot_diagnosis

        names = sorted({r["dataset"]["name"] for r in runs})
        plot_diagnosis({"projection": proj}, out, f"{', '.join(names)}: projected samples per round")
        charts.append("projection.png")
    print(text)
    for note in notes:
        print(f"left out: {note}", file=sys.stderr)
    print(f"{len(runs)} runs; wrote {out / 'report.md'}, table3.csv, report.json, {', '.join(charts)}",
          file=sys.stderr)


if __name__ == "__main__":
    main()
