"""The method tables of ``report.md``: Table 3 layout, curves per size, handler, cost, stability, projection."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from experiments.reporting.aggregate import (
    label_cost_per_sample,
    latent_space,
    monotone_handling,
    projection_runs,
    seed_mean_std,
)
from experiments.reporting.discover import (
    PAPER_TABLE3,
    by_dataset,
    dataset,
    label,
    method,
    method_rank,
    ordered_methods,
    paper_figures,
)
from experiments.reporting.equal_size import equal_size_markdown

HANDLING_KEYS = (("success_rate", "success"), ("resolved_rate", "resolved"), ("mean_pd_reduction", "PD reduction"),
                 ("mean_embedding_diff", "‖Z − Z_user‖"), ("seconds_per_mesh", "ms / mesh"))
# (title, path into metrics, percent? ("small": a percentage to two significant digits, for values far under
# 0.01 %)); the separate mesh detector's entries of older runs
# (metrics "mesh_detector", realistic "detection_mesh") are not reported
REALISTIC_ROWS = (
    ("real meshes: accuracy, detector", ("realistic", "detection", "accuracy"), True),
    ("real meshes: FNR, detector", ("realistic", "detection", "fnr"), True),
    ("real meshes: round trip keeps the label", ("realistic", "round_trip", "agreement"), True),
    ("real meshes: resolve, collision-free (detector-guided)",
     ("realistic", "handling", "detector_only", "resolved_rate"), True),
    ("real meshes: resolve, collision-free (verified)", ("realistic", "handling", "verified", "resolved_rate"), True),
    ("real meshes: resolve, median displacement (% diag)",
     ("realistic", "handling", "displacement_median_frac"), "small"),
    ("real meshes: contact repair alone, collision-free", ("realistic", "handling", "repair_only", "resolved_rate"),
     True),
)
BENCH_VARIANTS = (("compiled", "Compiled (`fast=\"float32\"`)"),
                  ("compiled_bf16", "Compiled bfloat16 (`fast=\"bfloat16\"`)"),
                  ("compiled_bf16_checked", "With a float32 recheck near 0 (`fast=\"bfloat16_checked\"`)"))


# ------------------------------------------------------------------------------------------- helpers
def row(*cells) -> str:
    """A Markdown table row."""
    return "| " + " | ".join(str(c) for c in cells) + " |"


def pm(mean: float, std: float, n: int, fmt=".4f") -> str:
    """``mean ± std``, or the mean alone for one value; ``fmt``: a format spec or a function of a number."""
    f = fmt if callable(fmt) else (lambda x: format(x, fmt))
    return f"{f(mean)} ± {f(std)}" if n > 1 else f(mean)


def pct_pm(mean: float, std: float, fmt: str = ".2f", n: int | None = None) -> str:
    """``62.00% ± 1.41`` (``fmt=".2g"``: ``0.00043% ± 0``, for fractions too small for two decimals); ``n=1`` (one
    seed): the value alone, a std of 0 over one value would read as a spread measured."""
    if n == 1:
        return f"{100 * mean:{fmt}}%"
    return f"{100 * mean:{fmt}}% ± {100 * std:{fmt}}"


def cell_text(values: list[float], n_seeds: int) -> str:
    """Mean ± std of a cell, with ``(k)`` when only k of the ``n_seeds`` seeds have a value; ``—`` for none."""
    if not values:
        return "—"
    s = pm(*seed_mean_std(values), len(values))
    return s if len(values) == n_seeds else f"{s} ({len(values)})"


def _dig(d, path):
    for k in path:
        if not isinstance(d, dict) or d.get(k) is None:
            return None
        d = d[k]
    return d


# ------------------------------------------------------------------------------------------- report
def markdown(runs: list[dict], agg: dict, rows: list[dict], bench: dict | None) -> str:
    """``report.md`` up to the size, cost and failure section: one part per data set, then the bench figures."""
    lines = []
    runs_of = by_dataset(runs)
    for ds in sorted(agg):
        methods, ds_runs = agg[ds], runs_of[ds]
        names = ordered_methods(methods)
        n_seeds = max(len({s for cell in methods[m].values() for s in cell["seed"]}) for m in names)
        lines += [f"## {ds}", "", "### Table 3 layout (mean ± std over each method's seeds, up to "
                  f"{n_seeds}: row `seeds`; last round of each run)", "",
                  "| | " + " | ".join(label(m) for m in names) + " |", "|---|" + "---:|" * len(names)]
        ds_rows = {r["method"]: r for r in rows if r["dataset"] == ds}

        def eq(r):
            if r["equivalent_supv_bd_size"] is None:
                return "— (supv_bd ran on another latent space)" if r["equivalent_note"] else "—"
            return f"{r['equivalent_note']}{r['equivalent_supv_bd_size']:.0f}"

        for title, f in (("data set size", lambda r: f"{r['final_size']:.0f}"),
                         ("seeds", lambda r: f"{r['n_seeds']}"),
                         ("accuracy", lambda r: pct_pm(r["accuracy_mean"], r["accuracy_std"], n=r["n_seeds"])),
                         ("false negative rate", lambda r: pct_pm(r["fnr_mean"], r["fnr_std"], n=r["n_seeds"])),
                         ("equivalent supv_bd size", eq),
                         ("detector parameters", lambda r: f"{r['detector_parameters']}")):
            lines.append(row(title, *(f(ds_rows[m]) if m in ds_rows else "—" for m in names)))
        lines += operating_rows(ds_rows, names) + paper_rows(ds, names)
        lines += realistic_rows(ds_runs, names)
        ae = sorted({r["autoencoder"].get("n_parameters") for r in ds_runs} - {None})
        lines += ["", "Accuracy and FNR at logit 0 (each round's decision, and the paper's); a run with an operating "
                  "point (`detector.operating_fnr`) also at its threshold, over the seeds that have one (k)."
                  + (" Paper: its Table 3 (Active+bd for both active methods)." if ds in PAPER_TABLE3 else ""),
                  "", "Equivalent size: the data set size supv_bd needs to reach the method's final mean accuracy "
                  "(linear interpolation on supv_bd's mean accuracy curve; `>`: never reached within the sizes run, "
                  "`≤`: reached at the first size). Autoencoder parameters: "
                  f"{', '.join(str(a) for a in ae) or '—'}.", ""]
        sizes = sorted({s for m in names for s in methods[m]})
        for metric, title in (("accuracy", "accuracy"), ("fnr", "false negative rate")):
            lines += [f"### {title} vs data set size (mean ± std over seeds; (k): seeds that reached it)", "",
                      row("data set size", *(label(m) for m in names)), "|---:|" + "---:|" * len(names)]
            for size in sizes:
                lines.append(row(size, *(cell_text(methods[m].get(size, {}).get(metric, []), n_seeds)
                                         for m in names)))
            lines.append("")
        base = [v for m in names for c in methods[m].values() for v in c["majority_accuracy"]]
        lines += [f"Majority-class accuracy of the test set: {np.mean(base):.4f}.", ""]
        spaces = defaultdict(set)
        for r in ds_runs:
            spaces[latent_space(r)].add(label(method(r)))
        if len(spaces) > 1:
            lines += ["These runs use " + str(len(spaces)) + " latent spaces (" + "; ".join(
                ", ".join(sorted(v)) for v in spaces.values()) + "), each with its own box U(Z) and test set: "
                "accuracies compare within a latent space, not across (the majority class above is their mean).",
                ""]
        lines += equal_size_markdown(ds_runs)
        lines += [handling_markdown(ds_runs)]
        lines += latent_markdown(ds_runs)
        lines += speed_markdown(ds, ds_runs, agg)
        lines += wall_time_markdown(ds_runs, names)
        lines += stability_markdown(ds, agg)
        lines += projection_markdown(ds_runs)
    if bench:
        lines += bench_markdown(bench)
    return "\n".join(lines)


def operating_rows(ds_rows: dict, names: list[str]) -> list[str]:
    """Accuracy and FNR at the operating point, where a method's runs have one (``n_operating`` seeds)."""
    if not any(ds_rows.get(m, {}).get("n_operating") for m in names):
        return []

    def cell(m: str, key: str) -> str:
        r = ds_rows.get(m)
        if not r or not r["n_operating"]:
            return "—"
        return pct_pm(r[f"operating_{key}_mean"], r[f"operating_{key}_std"], n=r["n_operating"]) + \
            f" ({r['n_operating']})"

    return [row(f"{title} at the operating point", *(cell(m, key) for m in names))
            for key, title in (("accuracy", "accuracy"), ("fnr", "false negative rate"))]


def paper_rows(ds: str, names: list[str]) -> list[str]:
    """The paper's Table 3 beside the measured rows, for a data set it reports."""
    if ds not in PAPER_TABLE3:
        return []
    t, figs = PAPER_TABLE3[ds], {m: paper_figures(ds, m) for m in names}
    return [row("paper: data set size", *(f"{t['final_size']:.0f}" if figs[m] else "—" for m in names)),
            row("paper: accuracy", *(f"{100 * figs[m][0]:.2f}%" if figs[m] else "—" for m in names)),
            row("paper: false negative rate", *(f"{100 * figs[m][1]:.2f}%" if figs[m] else "—" for m in names)),
            row("paper: equivalent supv_bd size",
                *(f"{t['equivalent_size']:.0f}" if m in ("active", "active_paper") else "—" for m in names))]


def bench_markdown(bench: dict) -> list[str]:
    """The detection time per sample, neural against exact (``bench/results.json``)."""
    return ["## Detection time per sample (bench/results.json)", "",
            f"Neural detector {bench['detector_us_per_sample_b4096']:.1f} µs at batch 4096 and "
            f"{bench['detector_us_per_sample_b1']:.0f} µs at batch 1; exact (decode + label, one core) "
            f"{bench['exact_ms_per_sample']:.1f} ms: {bench['neural_vs_exact_speedup']:.0f}× "
            f"(measured {bench.get('date', '?')})." + "".join(
                f" {name}: {bench[f'detector_{key}_us_per_sample_b4096']:.2f} µs, "
                f"{bench[f'neural_vs_exact_speedup_{key}']:.0f}×."
                for key, name in BENCH_VARIANTS if f"neural_vs_exact_speedup_{key}" in bench), ""]


def latent_markdown(runs: list[dict]) -> list[str]:
    """The latent space beside its PCA references: held-out error, the share of a probe of each box that
    collides and how often each round trip keeps a realistic mesh's label, mean over the runs that report them."""
    runs = [r for r in runs if (r.get("autoencoder") or {}).get("references")]
    if not runs:
        return []

    def mean(vals):
        vals = [v for v in vals if v is not None]
        return float(np.mean(vals)) if vals else None

    def cell(v, fmt):
        return "—" if v is None else format(v, fmt)

    lines = [f"### latent space against PCA at the same |Z_all| (mean over {len(runs)} runs; docs/autoencoder.md)", "",
             "| latent space | train error | held-out error | U(Z) probe collides | round trip keeps label |",
             "|---|---:|---:|---:|---:|"]
    for kind in sorted({r["autoencoder"].get("kind", "bilevel") for r in runs}):
        rs = [r for r in runs if r["autoencoder"].get("kind", "bilevel") == kind]
        lines.append(row(f"the runs' ({kind}, {len(rs)})",
                         cell(mean([r["autoencoder"]["train_mean_vertex_error"] for r in rs]), ".2%"),
                         cell(mean([r["autoencoder"]["val_mean_vertex_error"] for r in rs]), ".2%"),
                         cell(mean([_dig(r, ("latent", "box_probe", "space", "collision_share")) for r in rs]), ".1%"),
                         cell(mean([_dig(r, ("realistic", "round_trip", "agreement")) for r in rs]), ".1%")))
    names = sorted({name for r in runs for name in r["autoencoder"]["references"]})
    for name in names:
        refs = [r["autoencoder"]["references"].get(name) or {} for r in runs]
        lines.append(row(name, cell(mean([e.get("train_mean_vertex_error") for e in refs]), ".2%"),
                         cell(mean([e.get("val_mean_vertex_error") for e in refs]), ".2%"),
                         cell(mean([_dig(r, ("latent", "box_probe", "references", name, "collision_share"))
                                    for r in runs]), ".1%"),
                         cell(mean([_dig(r, ("realistic", "round_trip", "references", name, "agreement"))
                                    for r in runs]), ".1%")))
    return lines + [""]


def realistic_rows(runs: list[dict], names: list[str]) -> list[str]:
    """The "real meshes" block of the Table 3 layout: the realistic set's clear cases, mean ± std over
    the runs of each method; nothing when no run has a realistic evaluation."""
    if not any(r.get("realistic") for r in runs):
        return []
    out = []
    for title, path, pct in REALISTIC_ROWS:
        cells = []
        for m in names:
            vals = [v for r in runs if method(r) == m for v in [_dig(r, path)] if v is not None and np.isfinite(v)]
            if not vals:
                cells.append("—")
                continue
            mean, std = seed_mean_std(vals)
            cells.append(pct_pm(mean, std, ".2g" if pct == "small" else ".2f", n=len(vals)) if pct
                         else pm(mean, std, len(vals), lambda x: f"{x:.3g}"))
        if any(c != "—" for c in cells):
            out.append(row(title, *cells))
    n = [r["realistic"]["n_clear"] for r in runs if r.get("realistic")]
    count = str(min(n)) if min(n) == max(n) else f"{min(n)}-{max(n)}"
    return out + ["", f"Real meshes: the realistic set's clear cases ({count} meshes nobody trained on, "
                  "labeled exactly, about half colliding; docs/real_meshes.md)."] if out else []


def projection_markdown(runs: list[dict]) -> list[str]:
    """Per data set, the projection statistics per round (mean over the active runs)."""
    lines = []
    for ds, ds_runs in by_dataset(runs).items():
        proj = projection_runs(ds_runs)
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
                  "| colliding | moved level 1 / level 2 (half-ranges) | on a box face (level 1 / 2) |",
                  "|---:|---:|---:|---:|---:|---:|---:|"]
        for size in sorted(by_size):
            rs = by_size[size]

            def m(key, rs=rs):
                vals = [r[key] for r in rs if r.get(key) is not None]
                return float(np.mean(vals)) if vals else float("nan")

            def sub(group, rs=rs):
                vals = [r[group]["within_2eps"] for r in rs if r.get(group)]
                return float(np.mean(vals)) if vals else float("nan")

            lines.append(row(size, f"{m('within_eps'):.3f}", f"{m('within_2eps'):.3f}", f"{sub('uniform'):.3f}",
                             f"{m('colliding'):.3f}", f"{m('moved_level1'):.3f} / {m('moved_level2'):.3f}",
                             f"{m('on_face_level1'):.3f} / {m('on_face_level2'):.3f}"))
        lines.append("")
    return lines


def handling_markdown(runs: list[dict]) -> str:
    """Table of the handler's exact results per data set and method (final detectors), mean ± std over runs."""
    cells: dict = defaultdict(lambda: defaultdict(list))
    for run in runs:
        h = run.get("handling")
        if not h:
            continue
        ds, m = dataset(run), method(run)
        cells[(ds, m, "detector only")]["_n"].append(h["n"])
        for mode, res in (("detector only", h), ("verified", h.get("verified"))):
            if res:
                for key, _ in HANDLING_KEYS:
                    scale = 1e3 if key == "seconds_per_mesh" else 1.0
                    cells[(ds, m, mode)][key].append(scale * float(res[key]))
    if not cells:
        return ""
    lines = []
    for ds in sorted({k[0] for k in cells}):
        keys = sorted((k for k in cells if k[0] == ds), key=lambda k: (method_rank(k[1]), k[2]))
        n_in = cells[(ds, keys[0][1], "detector only")]["_n"]
        lines += [f"### collision handler, exact PD after handling ({n_in[0]} self-penetrating test inputs; "
                  "mean ± std over seeds)", "",
                  row("method", "handler", *(t for _, t in HANDLING_KEYS)), "|---|---|" + "---:|" * len(HANDLING_KEYS)]
        for k in keys:
            texts = []
            for key, _ in HANDLING_KEYS:
                pct = key in ("success_rate", "resolved_rate", "mean_pd_reduction")
                texts.append(pm(*seed_mean_std(cells[k][key]), len(cells[k][key]),
                                (lambda x: f"{100 * x:.1f}%") if pct else ".1f"))
            lines.append(row(label(k[1]), k[2], *texts))
        lines.append("")
    return "\n".join(lines)


def speed_markdown(ds: str, runs: list[dict], agg: dict) -> list[str]:
    """Cost table of one data set: final size, cumulative minutes and accuracy per method."""
    c, source = label_cost_per_sample(runs)
    lines = ["### cost (cumulative labeling + training + projection, mean over seeds)", ""]
    if c is not None:
        lines += [f"Labeling priced at {1e3 * c:.1f} ms per sample (from {source}), for every sample of D_c, "
                  "whether this run labeled it or took it from the shared cache.", ""]
    lines += ["| method | final size | cost (min) | accuracy |", "|---|---:|---:|---:|"]
    for m in ordered_methods(agg[ds]):
        last = max(agg[ds][m])
        cell = agg[ds][m][last]
        lines.append(row(label(m), last, f"{np.mean(cell['cost_seconds']) / 60:.1f}",
                         f"{np.mean(cell['accuracy']):.4f}"))
    return lines + [""]


STAGE_TITLES = {"data": "data (meshes, ACAP)", "latent": "autoencoder (latent space)",
                "open_pool": "U(Z) test set + labeling pool", "detector": "detector (labeling + training, all rounds)",
                "calibration": "operating point", "handler": "handler evaluation", "realistic": "real meshes",
                "cascade": "certified cascade", "speed": "speed against accuracy"}


def rounds_seconds(run: dict) -> float | None:
    """The detector stage's seconds as its rounds recorded them (``metrics.json`` -> ``rounds``: running totals of
    labeling, training and projection, kept across sittings with their batches and rounds), None without rounds."""
    rounds = run.get("rounds") or []
    if not rounds:
        return None
    last = rounds[-1]
    return sum(float(last.get(k) or 0.0) for k in ("label_seconds", "train_seconds", "project_seconds"))


def sitting_times(run: dict) -> tuple[dict, float, bool]:
    """A run's wall seconds per stage, its total minutes, and whether the detector's figure came from its rounds.
    In older runs a sitting killed inside the detector's rounds (the session's end, not ``max_minutes``) lost that
    stage's time from ``sittings.json``, though its finished rounds kept theirs: the detector stage is the larger of
    the two, and the total grows by the difference."""
    stages = dict(run["sittings"]["stage_seconds"])
    minutes = float(run["sittings"].get("minutes") or 0.0)
    by_rounds = rounds_seconds(run)
    if by_rounds is not None and by_rounds > stages.get("detector", 0.0) + 60:
        minutes += (by_rounds - stages.get("detector", 0.0)) / 60
        stages["detector"] = by_rounds
        return stages, minutes, True
    return stages, minutes, False


def wall_time_markdown(runs: list[dict], names: list[str]) -> list[str]:
    """Wall time per stage (``metrics.json`` -> ``sittings``: seconds summed over the sittings a run took; the
    detector's from its rounds where a killed sitting lost it, see ``sitting_times``), mean ± std over the seeds of
    each method, in minutes; nothing when no run recorded its sittings."""
    timed = [r for r in runs if (r.get("sittings") or {}).get("stage_seconds")]
    if not timed:
        return []
    times = [sitting_times(r) for r in timed]
    stages = list(dict.fromkeys(k for st, _, _ in times for k in st))
    lines = ["### wall time per stage (minutes, summed over sittings; mean ± std over seeds)", "",
             row("stage", *(label(m) for m in names)), "|---|" + "---:|" * len(names)]

    def cell(m: str, value, fmt: str = ".1f") -> str:
        vals = [v for r, t in zip(timed, times) if method(r) == m for v in [value(r, t)] if v is not None]
        return pm(*seed_mean_std(vals), len(vals), fmt) if vals else "—"

    for k in stages:
        if all(st.get(k, 0.0) < 30 for st, _, _ in times):
            continue  # under half a minute everywhere: in the total
        lines.append(row(STAGE_TITLES.get(k, k), *(cell(m, lambda r, t, k=k: t[0].get(k, 0.0) / 60) for m in names)))
    lines.append(row("**total**", *(cell(m, lambda r, t: t[1]) for m in names)))
    lines.append(row("sittings", *(cell(m, lambda r, t: r["sittings"].get("n"), ".2g") for m in names)))
    from_rounds = [Path(r["_path"]).name if "_path" in r else label(method(r)) for r, t in zip(timed, times) if t[2]]
    note = "" if not from_rounds else (
        f" The detector's time of {len(from_rounds)} run(s) ({', '.join(from_rounds)}) is its rounds' own record "
        "(labeling + training + projection, running totals kept with each round): a sitting of theirs was killed "
        "inside the rounds before `sittings.json` kept a running stage's time, so the sittings' figure "
        "lacks it; their totals grow by the difference.")
    return lines + ["", "Stages under half a minute in every run are left out of the rows (not of the total); a "
                    "stage near 0 took its result from the cache (`paths.cache_dir`), paid by an earlier run. A "
                    "run that shared its machine with another ran slower than it would alone." + note, ""]


def stability_markdown(ds: str, agg: dict) -> list[str]:
    """Stability table of one data set: spread across seeds, handling success monotone in size."""
    lines = ["### stability (spread across seeds; handling success vs size)", "",
             "| method | seeds | largest accuracy std over sizes | handling success monotone in size |",
             "|---|---:|---:|---|"]
    mono = monotone_handling(agg)
    for m in ordered_methods(agg[ds]):
        cells = agg[ds][m]
        stds = [np.std(c["accuracy"], ddof=1) for c in cells.values() if len(c["accuracy"]) > 1]
        n = max(len(c["seed"]) for c in cells.values())
        mo = mono.get((ds, m))
        mtxt = "— (no per-round handling; `handler.eval_every_round=true`)" if mo is None else \
            ("yes" if mo[0] else f"no ({mo[1]} drop{'s' if mo[1] > 1 else ''} > 1 point)")
        lines.append(row(label(m), n, f"{max(stds):.4f}" if stds else "— (one seed)", mtxt))
    return lines + [""]
