"""The report's numbers, pooled over seeds: per-round curves, Table 3, costs, Pareto points, failure breakdowns."""

from __future__ import annotations

from collections import defaultdict

import numpy as np

from experiments.reporting.discover import (
    SIZE_KEYS,
    by_dataset,
    config_label,
    dataset,
    detector_parameters,
    load_handler_inputs,
    load_predictions,
    method,
    ordered_methods,
    size_config,
)
from neuralcol.metrics.breakdown import (
    PD_BIN_NAMES,
    BinRates,
    deepest_subdomain,
    mean_std,
    pareto_front,
    pd_bins,
    rate_by_group,
)

ROUND_METRICS = ("accuracy", "fnr", "fpr", "balanced_accuracy", "majority_accuracy")


def _nested():
    return defaultdict(lambda: defaultdict(lambda: defaultdict(lambda: defaultdict(list))))


def seed_mean_std(values) -> tuple[float, float]:
    """Mean and sample std (ddof 1; 0 for one value) of a list of numbers."""
    v = np.asarray(values, dtype=float)
    return float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0


# ---------------------------------------------------------------------------------------------- cost
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
                rates.setdefault(method(run), []).append(d_label / d_size)
            prev_size, prev_label = r["dataset_size"], r["label_seconds"]
    # supv labels every new uniform sample itself (its pools are labeled by the first run that needs them);
    # the other methods take part of theirs from the cache, so their rates understate the cost
    for m in ("supv", *sorted(rates)):
        if rates.get(m):
            return float(np.median(rates[m])), f"the median labeling time per new sample of the {m} runs"
    return None, "nothing labeled in these runs: labeling time as recorded"


def label_prices(runs: list[dict]) -> dict[str, float | None]:
    """``{data set: labeling seconds per sample (None: as recorded)}``."""
    return {ds: label_cost_per_sample(rs)[0] for ds, rs in by_dataset(runs).items()}


def round_seconds(r: dict, price: float | None) -> float:
    """A round's cumulative labeling + training + projection seconds; labeling at ``price`` seconds per sample of
    D_c, or as recorded (cached samples free) when ``price`` is None."""
    label_s = r["dataset_size"] * price if price is not None else r["label_seconds"]
    return label_s + r["train_seconds"] + r.get("project_seconds", 0.0)


def cost_curves(runs: list[dict], priced: dict) -> dict:
    """``{dataset: {method: {size: {"recorded": [s], "priced": [s], "accuracy": [a]}}}}`` over seeds (priced at
    ``priced[dataset]`` seconds per sample, see :func:`round_seconds`)."""
    out = _nested()
    for run in runs:
        for r in run["rounds"]:
            cell = out[dataset(run)][method(run)][int(r["dataset_size"])]
            cell["recorded"].append(round_seconds(r, None))
            cell["priced"].append(round_seconds(r, priced.get(dataset(run))))
            cell["accuracy"].append(r["accuracy"])
    return out


# -------------------------------------------------------------------------------------- per round
def aggregate(runs: list[dict]) -> dict:
    """{dataset: {method: {size: {metric: [values over seeds]}}}}, metrics of every round (accuracy, fnr, fpr,
    balanced_accuracy, majority_accuracy, cost_seconds, handling_success) and its seed."""
    out = _nested()
    prices = label_prices(runs)
    for run in runs:
        for r in run["rounds"]:
            cell = out[dataset(run)][method(run)][int(r["dataset_size"])]
            for key in ROUND_METRICS:
                cell[key].append(float(r[key]))
            cell["cost_seconds"].append(round_seconds(r, prices[dataset(run)]))
            if r.get("handling"):
                cell["handling_success"].append(float(r["handling"]["success_rate"]))
            cell["seed"].append(run["_seed"])
    return out


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


def latent_space(run: dict) -> str | None:
    """The run's latent space (its autoencoder's cache key; None for runs that do not record it): accuracies are
    comparable only within one, each space having its own U(Z) test set."""
    return (run.get("autoencoder") or {}).get("cache_key")


def mean_curve(runs: list[dict]) -> tuple[list[int], list[float]]:
    """Sizes and the mean accuracy over ``runs`` at each (the rounds as discovered: at logit 0)."""
    cells = defaultdict(list)
    for run in runs:
        for r in run["rounds"]:
            cells[int(r["dataset_size"])].append(float(r["accuracy"]))
    sizes = sorted(cells)
    return sizes, [float(np.mean(cells[s])) for s in sizes]


def table3(runs: list[dict], agg: dict) -> list[dict]:
    """Rows of the paper's Table 3: per data set and method, final size and accuracy/FNR at logit 0 (mean ± std over
    seeds at each run's last round), equivalent supv_bd size (against the supv_bd runs on the method's latent space;
    none, noted "other latent space", when there are only others) and parameter count; and accuracy/FNR at the
    operating point over the runs that have one (``n_operating`` of them; None without)."""
    rows = []
    runs_of = by_dataset(runs)
    for ds in sorted(agg):
        ref_runs = [r for r in runs_of[ds] if method(r) == "supv_bd"]
        for m in ordered_methods(agg[ds]):
            mr = [r for r in runs_of[ds] if method(r) == m]
            final = [r["rounds"][-1] for r in mr]
            acc, fnr = [f["accuracy"] for f in final], [f["fnr"] for f in final]
            size = float(np.mean([f["dataset_size"] for f in final]))
            params = sorted({p for p in (detector_parameters(r) for r in mr) if p is not None})
            ops = [f["operating_point"] for f in final if f.get("operating_point")]
            row = {"dataset": ds, "method": m, "n_seeds": len(mr), "final_size": size,
                   "accuracy_mean": seed_mean_std(acc)[0], "accuracy_std": seed_mean_std(acc)[1],
                   "fnr_mean": seed_mean_std(fnr)[0], "fnr_std": seed_mean_std(fnr)[1],
                   "equivalent_supv_bd_size": None, "equivalent_note": "",
                   "detector_parameters": params[0] if len(params) == 1 else (params or None),
                   "n_operating": len(ops), "operating_accuracy_mean": None, "operating_accuracy_std": None,
                   "operating_fnr_mean": None, "operating_fnr_std": None}
            if ops:
                for key in ("accuracy", "fnr"):
                    row[f"operating_{key}_mean"], row[f"operating_{key}_std"] = seed_mean_std([o[key] for o in ops])
            if ref_runs and m != "supv_bd":
                spaces = {latent_space(r) for r in mr}
                same = [r for r in ref_runs if latent_space(r) in spaces]
                if same:  # supv_bd's mean accuracy curve on the method's own latent space (hence test set)
                    ref_sizes, ref_acc = mean_curve(same)
                    eq, note = equivalent_size(ref_sizes, ref_acc, row["accuracy_mean"])
                    row["equivalent_supv_bd_size"], row["equivalent_note"] = eq, note
                else:
                    row["equivalent_note"] = "other latent space"
            rows.append(row)
    return rows


def monotone_handling(agg: dict) -> dict:
    """{(ds, method): (monotone?, number of drops)} of the mean handling success vs size (drops larger than
    one point count)."""
    out = {}
    for ds, methods in agg.items():
        for m, cells in methods.items():
            sizes = [s for s in sorted(cells) if cells[s]["handling_success"]]
            if len(sizes) < 2:
                continue
            mean = [np.mean(cells[s]["handling_success"]) for s in sizes]
            drops = int(sum(b < a - 0.01 for a, b in zip(mean, mean[1:])))
            out[(ds, m)] = (drops == 0, drops)
    return out


def projection_runs(runs: list[dict]) -> dict:
    """``{run dir: [round record with the projection statistics, ...]}`` of the runs that projected samples."""
    out = {}
    for run in runs:
        rs = [{"round": r["round"], "dataset_size": r["dataset_size"], **r["projection"]}
              for r in run["rounds"] if r.get("projection")]
        if rs:
            out[run["_path"]] = rs
    return out


# ------------------------------------------------------------------------------------------- Pareto
def pareto_points(runs: list[dict]) -> list[dict]:
    """One point per (data set, method, sizes): final test accuracy, parameter count and inference time, mean and
    std over the runs (seeds)."""
    groups = defaultdict(list)
    for run in runs:
        cfg = size_config(run)
        groups[(dataset(run), method(run), *(cfg[k] for k in SIZE_KEYS))].append(run)
    points = []
    for key, rs in groups.items():
        acc = np.array([[r["rounds"][-1]["accuracy"]] for r in rs])
        params = [p for p in (detector_parameters(r) for r in rs) if p is not None]
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
        sizes_per_ds[dataset(run)].add(config_label(size_config(run)))
    per: dict = defaultdict(lambda: defaultdict(list))
    no_pred, no_hand = [], []
    for run in runs:
        ds = dataset(run)
        name = method(run) if len(sizes_per_ds[ds]) == 1 else f"{method(run)} ({config_label(size_config(run))})"
        pred, hand = load_predictions(run), load_handler_inputs(run)
        if pred is None:
            no_pred.append(run["_path"])
        if hand is None and run.get("handling"):
            no_hand.append(run["_path"])
        cell = per[(ds, name)]
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


def failure_numbers(groups: dict) -> dict:
    """The failure breakdowns for report.json: ``{"ds/label": {measure: {mean, std, count}, "pd_unit": u}}``."""
    return {f"{ds}/{name}": {m: {"mean": mean_std(v[0])[0].tolist(), "std": mean_std(v[0])[1].tolist(),
                                 "count": v[1].tolist()}
                             for m, v in g.items() if m != "pd_unit"} | {"pd_unit": g["pd_unit"]}
            for (ds, name), g in groups.items()}
