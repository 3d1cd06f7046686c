"""The report's cost and failure charts (``experiments.report`` calls :func:`write_tradeoffs`).

* ``pareto.png`` + a table: final test accuracy against the detector's parameter count and against its CPU
  inference time per sample at batch 4096 (``metrics["detector"]["inference_us"]``), one point per
  configuration (data set, method, latent sizes K and L, detector widths; mean ± std over seeds), the Pareto
  front (higher accuracy, lower cost) as a step line, and the chosen configuration of ``model_size.json``
  marked when a given directory holds one;
* ``cost.png``: accuracy against cumulative labeling + training + projection seconds, one line per method
  (mean ± std over seeds): as recorded by each run (samples taken from the shared cache cost nothing) and with
  every sample of D_c priced at the data set's labeling time per sample (as ``speed.png``);
* ``failures.png`` + tables: detector accuracy by exact-PD bin of the test rows
  (:data:`neuralcol.metrics.breakdown.PD_BIN_EDGES`, in units of the run's ``pd_unit``), recall by the deepest
  sub-domain (argmax of ``pd_sub``) of the colliding test rows, and the detector-only handler's success by PD
  bin of its inputs; mean ± std over seeds.

Inputs per run: ``metrics.json``, ``test_predictions.npz`` and ``handling/per_input.npz`` (written since issue
17; for the handler, the older ``handling/handling.npz`` holds the same two arrays). A run without a file is left
out of the chart that needs it, with one line saying so.

``model_size.json`` (in any directory given to the report)::

    {"chosen": {"n_components": 8, "level2_dim": 3, "detector_width": 1.0}}

(as ``model_size=auto`` and ``experiments.model_size`` write it). ``chosen`` holds any non-empty subset of the
keys of :data:`CHOSEN_KEYS`; every configuration whose values
equal all given ones is marked.
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from neuralcol.errors import UserInputError
from neuralcol.metrics.breakdown import (
    PD_BIN_EDGES,
    PD_BIN_NAMES,
    BinRates,
    deepest_subdomain,
    mean_std,
    pareto_front,
    pd_bins,
    rate_by_group,
)

CHOSEN_KEYS = ("dataset", "method", "n_components", "level2_dim", "state_dim", "hidden", "detector_width",
               "n_parameters")
SIZE_KEYS = ("n_components", "level2_dim", "state_dim", "hidden", "detector_width")
N_COLLIDING_BINS = sum(e >= 0 for e in PD_BIN_EDGES)  # bins above PD 0: where the handler's inputs lie


# ------------------------------------------------------------------------------------------- loading
def size_config(run: dict) -> dict:
    """The run's sizes: n_components K, level2_dim L (from ``latent``), the detector's state_dim, hidden and width
    multiplier (from ``metrics["detector"]["net"]``, else the run's ``.hydra/config.yaml``; None when neither has
    them)."""
    k = int(run["latent"]["n_parts"])
    net = run["detector"].get("net")
    cfg_path = Path(run["_path"]) / ".hydra" / "config.yaml"
    if net is None and cfg_path.is_file():
        from omegaconf import OmegaConf

        net = OmegaConf.to_container(OmegaConf.load(cfg_path).detector.net, resolve=True)
    net = net or {}
    return {"n_components": k, "level2_dim": int(run["latent"]["dim"]) // k - 1,
            "state_dim": net.get("state_dim"), "hidden": net.get("hidden"),
            "detector_width": float(net.get("width", 1.0))}  # detector.net.width (issue 17; 1 before it)


def config_label(cfg: dict) -> str:
    """``K8 L3 64/128``: sub-domains, level-2 size, detector state width / hidden width."""
    return f"K{cfg['n_components']} L{cfg['level2_dim']} {cfg['state_dim']}/{cfg['hidden']}"


def load_chosen(dirs: list[Path]) -> tuple[dict | None, Path | None]:
    """The ``chosen`` entry of the first ``model_size.json`` directly in ``dirs`` (None, None if there is none).

    Raises:
        UserInputError: the file is not JSON, has no ``chosen`` object, or names an unknown key.
    """
    for d in dirs:
        path = Path(d) / "model_size.json"
        if not path.is_file():
            continue
        try:
            chosen = json.loads(path.read_text()).get("chosen")
        except (json.JSONDecodeError, AttributeError) as e:
            raise UserInputError(f"{path}: not a JSON object ({e}); write "
                                 '{"chosen": {"n_components": K, "level2_dim": L, "state_dim": S, "hidden": H}}') from e
        if not isinstance(chosen, dict) or not chosen:
            raise UserInputError(f"{path}: needs a non-empty object under \"chosen\", e.g. "
                                 '{"chosen": {"n_components": 8, "level2_dim": 3, "state_dim": 64, "hidden": 128}}')
        unknown = sorted(set(chosen) - set(CHOSEN_KEYS))
        if unknown:
            raise UserInputError(f"{path}: unknown key(s) {unknown} under \"chosen\"; use some of {list(CHOSEN_KEYS)}")
        return chosen, path
    return None, None


def _load_npz(path: Path, keys: tuple[str, ...]) -> dict | None:
    if not path.is_file():
        return None
    with np.load(path) as f:
        if not all(k in f for k in keys):
            return None
        return {k: f[k] for k in f.files}


def load_predictions(run: dict) -> dict | None:
    """``test_predictions.npz`` of the run (None when the run predates it)."""
    return _load_npz(Path(run["_path"]) / "test_predictions.npz", ("prob", "pd", "pd_sub", "collides"))


def load_handler_inputs(run: dict) -> dict | None:
    """pd_before and success per handler input: ``handling/per_input.npz``, else the older ``handling.npz``."""
    h = Path(run["_path"]) / "handling"
    return _load_npz(h / "per_input.npz", ("pd_before", "success")) or \
        _load_npz(h / "handling.npz", ("pd_before", "success"))


# ------------------------------------------------------------------------------------------- Pareto
def pareto_points(runs: list[dict], parameters) -> list[dict]:
    """One point per (data set, method, sizes): final test accuracy, parameter count and inference time, mean and
    std over the runs (seeds). ``parameters``: ``run -> int | None`` (the report's ``detector_parameters``)."""
    groups = defaultdict(list)
    for run in runs:
        cfg = size_config(run)
        groups[(run["dataset"]["name"], run["detector"]["method"], *(cfg[k] for k in SIZE_KEYS))].append(run)
    points = []
    for key, rs in groups.items():
        acc = np.array([[r["rounds"][-1]["accuracy"]] for r in rs])
        params = [p for p in (parameters(r) for r in rs) if p is not None]
        timed = [r["detector"]["inference_us"] for r in rs if r["detector"].get("inference_us")]
        b4096 = np.array([[t.get("batch_4096", np.nan)] for t in timed]).reshape(-1, 1)
        b1 = np.array([[t.get("batch_1", np.nan)] for t in timed]).reshape(-1, 1)
        cfg = dict(zip(SIZE_KEYS, key[2:]))
        points.append({"dataset": key[0], "method": key[1], **cfg, "label": config_label(cfg), "n_seeds": len(rs),
                       "n_parameters": float(np.mean(params)) if params else None,
                       "accuracy_mean": float(mean_std(acc)[0][0]), "accuracy_std": float(mean_std(acc)[1][0]),
                       "us_b4096_mean": float(mean_std(b4096)[0][0]) if timed else None,
                       "us_b4096_std": float(mean_std(b4096)[1][0]) if timed else None,
                       "us_b1_mean": float(mean_std(b1)[0][0]) if timed else None, "n_timed": len(timed)})
    return sorted(points, key=lambda p: (p["dataset"], p["n_parameters"] or 0, p["method"]))


def latent_key(p: dict) -> tuple:
    """The (data set, latent space) a point belongs to: accuracy is comparable only within one, since each
    latent space has its own box U(Z), hence its own test set and collision rate."""
    return p["dataset"], p["n_components"], p["level2_dim"]


def mark_fronts(points: list[dict], chosen: dict | None) -> None:
    """Add ``front_parameters``, ``front_time`` (on the Pareto front of accuracy against parameter count /
    inference time within the point's data set and latent space) and ``chosen`` (matches every key of
    ``chosen``) to each point, in place."""
    for key in {latent_key(p) for p in points}:
        pts = [p for p in points if latent_key(p) == key]
        acc = np.array([p["accuracy_mean"] for p in pts])
        for name, key in (("front_parameters", "n_parameters"), ("front_time", "us_b4096_mean")):
            cost = np.array([np.nan if p[key] is None else p[key] for p in pts], dtype=np.float64)
            for p, on in zip(pts, pareto_front(cost, acc)):
                p[name] = bool(on)
    for p in points:
        p["chosen"] = bool(chosen) and all(p.get(k) == v for k, v in chosen.items())


# ------------------------------------------------------------------------------------------ failures
def run_failure_rates(run: dict, pred: dict | None, handler: dict | None) -> dict:
    """One run's breakdown: ``accuracy`` by PD bin of the test rows and ``recall`` by deepest sub-domain of the
    colliding ones (from ``pred``), ``handler`` success by PD bin of the inputs (from ``handler``); each a
    :class:`BinRates`, or absent without its file."""
    unit = float(run["detector"]["pd_unit"])
    out = {}
    if pred is not None:
        collides = np.asarray(pred["collides"], bool)
        said = pred["logit"] > 0 if "logit" in pred else pred["prob"] > 0.5  # logit > 0: as the metrics
        out["accuracy"] = rate_by_group(said == collides, pd_bins(pred["pd"], unit), len(PD_BIN_NAMES))
        k = pred["pd_sub"].shape[1]
        out["recall"] = rate_by_group(said[collides], deepest_subdomain(pred["pd_sub"][collides]), k)
    if handler is not None:
        out["handler"] = rate_by_group(handler["success"], pd_bins(handler["pd_before"], unit), len(PD_BIN_NAMES))
    return out


def failure_groups(runs: list[dict]) -> tuple[dict, list[str]]:
    """Per (data set, group label) the runs' breakdowns, stacked over seeds: ``{measure: (rate (S, M),
    count (M,))}``, with ``pd_unit``; and one line per kind of missing file. The group label is the method,
    with the sizes added where a data set has runs of more than one size."""
    sizes_per_ds = defaultdict(set)
    for run in runs:
        sizes_per_ds[run["dataset"]["name"]].add(config_label(size_config(run)))
    per: dict = defaultdict(lambda: defaultdict(list))
    no_pred, no_hand = [], []
    for run in runs:
        ds, method = run["dataset"]["name"], run["detector"]["method"]
        label = method if len(sizes_per_ds[ds]) == 1 else f"{method} ({config_label(size_config(run))})"
        pred, hand = load_predictions(run), load_handler_inputs(run)
        if pred is None:
            no_pred.append(run["_path"])
        if hand is None and run.get("handling"):
            no_hand.append(run["_path"])
        cell = per[(ds, label)]
        cell["pd_unit"].append(float(run["detector"]["pd_unit"]))
        for measure, r in run_failure_rates(run, pred, hand).items():
            cell[measure].append(r)
    groups = {}
    for key, cell in per.items():
        g = {"pd_unit": float(np.mean(cell["pd_unit"]))}
        for measure in ("accuracy", "recall", "handler"):
            rs: list[BinRates] = cell.get(measure, [])
            if rs and len({len(r.rate) for r in rs}) == 1:
                g[measure] = (np.stack([r.rate for r in rs]), rs[0].count)
        groups[key] = g
    notes = []
    if no_pred:
        notes.append(f"{len(no_pred)} of {len(runs)} runs have no test_predictions.npz (finished before it was "
                     f"written) and are left out of the detector breakdown: {', '.join(no_pred)}")
    if no_hand:
        notes.append(f"{len(no_hand)} runs have no handling/per_input.npz or handling.npz and are left out of "
                     f"the handler breakdown: {', '.join(no_hand)}")
    return groups, notes


def _pm(mean: float, std: float, n: int) -> str:
    if not np.isfinite(mean):
        return "—"
    return f"{mean:.3f} ± {std:.3f}" if n > 1 else f"{mean:.3f}"


def failure_markdown(groups: dict, method_order) -> list[str]:
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
                lines.append(f"| {k[1]} | {name} | {rows} | {a_txt} | {h_rows} | {h_txt} |")
        lines += ["", f"### {ds}: recall by the deepest sub-domain of the colliding test rows (mean ± std over seeds)",
                  "", "| method | sub-domain | colliding rows | recall |", "|---|---:|---:|---:|"]
        for k in keys:
            g = groups[k]
            if "recall" not in g:
                lines.append(f"| {k[1]} | — | — | — |")
                continue
            m, s, n = mean_std(g["recall"][0])
            for i in range(len(m)):
                lines.append(f"| {k[1]} | {i} | {g['recall'][1][i]} | {_pm(m[i], s[i], n[i])} |")
        lines.append("")
    return lines


def pareto_markdown(points: list[dict], chosen_path: Path | None, method_order) -> list[str]:
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
            us = "—" if p["us_b4096_mean"] is None else f"{p['us_b4096_mean']:.2f}" + \
                (f" ± {p['us_b4096_std']:.2f}" if p["n_timed"] > 1 else "")
            us1 = "—" if p["us_b1_mean"] is None else f"{p['us_b1_mean']:.0f}"
            params = "—" if p["n_parameters"] is None else f"{p['n_parameters']:.0f}"
            lines.append(f"| {p['label']} | {p['method']} | {p['n_seeds']} | {params} | {us} | {us1} | "
                         f"{_pm(p['accuracy_mean'], p['accuracy_std'], p['n_seeds'])} | "
                         f"{'yes' if p['front_parameters'] else ''} | {'yes' if p['front_time'] else ''} | "
                         f"{'**chosen**' if p['chosen'] else ''} |")
        if chosen_path is not None and not any(p["chosen"] for p in pts):
            lines.append(f"\nThe choice in {chosen_path} matches no configuration of {ds}.")
        lines.append("")
    return lines


# ------------------------------------------------------------------------------------------- charts
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_pareto(points: list[dict], method_order, path: Path) -> None:
    """Per data set: accuracy against parameter count (log x) and against µs per sample at batch 4096."""
    plt = _plt()
    datasets = sorted({p["dataset"] for p in points})
    fig, axes = plt.subplots(len(datasets), 2, figsize=(10, 3.8 * len(datasets)), squeeze=False)
    methods = sorted({p["method"] for p in points}, key=method_order)
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
                ax.text(0.5, 0.5, "no run records it\n(metrics.json before issue 17)", ha="center", va="center",
                        transform=ax.transAxes)
            else:
                ax.set_xscale("log")
                from matplotlib.ticker import NullFormatter

                ax.xaxis.set_minor_formatter(NullFormatter())  # minor log labels overlap on short ranges
                handles, labels = ax.get_legend_handles_labels()
                uniq = dict(zip(labels, handles))
                ax.legend(uniq.values(), uniq.keys(), fontsize=8)
            ax.set_xlabel(xlabel)
            ax.set_ylabel("final test accuracy")
            ax.set_title(ds)
            ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def cost_curves(runs: list[dict], priced: dict) -> dict:
    """``{dataset: {method: {size: {"recorded": [s], "priced": [s], "accuracy": [a]}}}}`` over seeds.

    Recorded: the run's own cumulative ``label_seconds + train_seconds + project_seconds``; priced: the same with
    labeling at ``priced[dataset]`` seconds per sample of D_c (None: as recorded)."""
    out: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(lambda: defaultdict(list))))
    for run in runs:
        ds = run["dataset"]["name"]
        for r in run["rounds"]:
            rest = r["train_seconds"] + r.get("project_seconds", 0.0)
            cell = out[ds][run["detector"]["method"]][int(r["dataset_size"])]
            cell["recorded"].append(r["label_seconds"] + rest)
            c = priced.get(ds)
            cell["priced"].append((r["dataset_size"] * c if c is not None else r["label_seconds"]) + rest)
            cell["accuracy"].append(r["accuracy"])
    return out


def plot_cost(curves: dict, method_order, path: Path) -> None:
    """Per data set: accuracy against recorded and against priced cumulative seconds, mean ± std over seeds."""
    plt = _plt()
    datasets = sorted(curves)
    fig, axes = plt.subplots(len(datasets), 2, figsize=(10, 3.8 * len(datasets)), squeeze=False)
    for row, ds in zip(axes, datasets):
        for ax, key, title in ((row[0], "recorded", "as recorded (cached samples free)"),
                               (row[1], "priced", "every sample of D_c priced")):
            for i, m in enumerate(sorted(curves[ds], key=method_order)):
                sizes = sorted(curves[ds][m])
                x = np.array([[np.mean(curves[ds][m][s][key]), np.std(curves[ds][m][s][key])] for s in sizes])
                y = np.array([[np.mean(curves[ds][m][s]["accuracy"]), np.std(curves[ds][m][s]["accuracy"])]
                              for s in sizes])
                ax.errorbar(x[:, 0], y[:, 0], xerr=x[:, 1], yerr=y[:, 1], marker="o", capsize=3, color=f"C{i}",
                            label=m)
            ax.set_xscale("log")
            ax.set_xlabel("cumulative labeling + training + projection (s, log)")
            ax.set_ylabel("test accuracy")
            ax.set_title(f"{ds}: {title}")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_failures(groups: dict, method_order, path: Path) -> None:
    """Per data set: accuracy by PD bin, recall by deepest sub-domain, handler success by input PD bin; bars
    are means over seeds, error bars their std."""
    plt = _plt()
    datasets = sorted({k[0] for k in groups})
    fig, axes = plt.subplots(len(datasets), 3, figsize=(15, 3.8 * len(datasets)), squeeze=False)
    for row, ds in zip(axes, datasets):
        keys = sorted((k for k in groups if k[0] == ds), key=lambda k: method_order(k[1]))
        width = 0.8 / max(len(keys), 1)
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
                ax.bar(x, np.nan_to_num(mean), width, yerr=np.nan_to_num(std), capsize=3, color=f"C{i}", label=k[1])
                drawn = True
                if names is None:
                    names = [str(j) for j in range(len(mean))]
            if drawn:
                ax.set_xticks(np.arange(len(names)), names, fontsize=7, rotation=15)
                ax.legend(fontsize=7)
            else:
                ax.text(0.5, 0.5, "no per-run files\n(runs before issue 17)", ha="center", va="center",
                        transform=ax.transAxes)
            ax.set_ylim(0, 1.05)
            ax.set_ylabel(ylabel)
            unit = groups[keys[0]]["pd_unit"]
            ax.set_xlabel("deepest sub-domain" if measure == "recall" else f"exact PD (units of {unit:.3g})")
            ax.set_title(ds)
            ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# -------------------------------------------------------------------------------------------- entry
def write_tradeoffs(runs: list[dict], dirs: list[Path], out: Path, parameters, priced: dict,
                    method_order) -> tuple[list[str], list[str], dict]:
    """Write ``pareto.png``, ``cost.png`` and ``failures.png`` into ``out``.

    Args:
        runs: the report's runs (metrics.json dicts with ``_path``).
        dirs: the directories given to the report (searched for ``model_size.json``).
        out: output directory.
        parameters: ``run -> detector parameter count | None``.
        priced: ``{dataset: labeling seconds per sample | None}``.
        method_order: sort key of a method name.

    Returns:
        (Markdown lines for report.md, notes on left-out runs (one line each), numbers for report.json).
    """
    chosen, chosen_path = load_chosen(dirs)
    points = pareto_points(runs, parameters)
    mark_fronts(points, chosen)
    groups, notes = failure_groups(runs)
    untimed = [r["_path"] for r in runs if not r["detector"].get("inference_us")]
    if untimed:
        notes.insert(0, f"{len(untimed)} of {len(runs)} runs have no detector.inference_us (finished before it was "
                        f"recorded) and are left out of the time panel of pareto.png: {', '.join(untimed)}")
    plot_pareto(points, method_order, out / "pareto.png")
    plot_cost(cost_curves(runs, priced), method_order, out / "cost.png")
    plot_failures(groups, method_order, out / "failures.png")
    lines = ["## Size, cost and failures (pareto.png, cost.png, failures.png)", ""]
    if chosen_path is not None:
        lines += [f"Chosen configuration ({chosen_path}): {json.dumps(chosen)}.", ""]
    lines += pareto_markdown(points, chosen_path, method_order) + failure_markdown(groups, method_order)
    lines += [f"Left out: {n}" for n in notes] + ([""] if notes else [])
    numbers = {"pareto": points, "failures": {
        f"{ds}/{label}": {m: {"mean": mean_std(v[0])[0].tolist(), "std": mean_std(v[0])[1].tolist(),
                              "count": v[1].tolist()}
                          for m, v in g.items() if m != "pd_unit"} | {"pd_unit": g["pd_unit"]}
        for (ds, label), g in groups.items()}, "pd_bins": list(PD_BIN_NAMES)}
    return lines, notes, numbers
