"""The collision handler's success against |D_c| (paper Fig. 5), measured afterwards from each round's saved
detector: ``PYTHONPATH=. python research/paper_scale/handling_curve.py RUN_DIR... [--inputs N] [--out FILE]
[--plot PNG]``.

For every ``round_detectors/round_<k>.pt`` of a run (rounds trained before round detectors were kept are
missing and named), the handler guided by that detector alone, the paper's protocol and what
``handler.eval_every_round=true`` measures during a run, on the first N colliding codes of the run's U(Z) test set
(the inputs of the run's own handler stage, which takes its first ``handler.n_inputs``), every result labeled
exactly: success rate (PD reduced) and mean relative PD reduction over the successful inputs (paper: 94.81 % for
Active+bd, 88.76 % for Supv+bd on SCAPE). The runs' baselines (``supv``, ``supv_bd``) re-train at each size, so a
round's detector there is the baseline at that size. Prints a markdown table, writes JSON (``--out``) and a plot
(``--plot``): success rate and PD reduction against |D_c|, one line per method, mean over its runs (seeds) with the
paper's final PD reductions. ``--from-json`` adds earlier ``--out`` files without measuring them again (one run a
call, then one plot of all: ``research/paper_scale/final_tables.sh``).
"""

from __future__ import annotations

import argparse
import copy
import json
from pathlib import Path

import h5py
import numpy as np
import torch

from experiments.reporting.discover import METHOD_ORDER, label, ordered_methods
from neuralcol.api.run import load_run
from neuralcol.handler.resolve import alm_settings
from neuralcol.nn.detector import load_detector
from neuralcol.nn.part_geometry import DetectorOnCodes
from neuralcol.rundir import RunDir
from neuralcol.samples.oracle import LatentOracle
from neuralcol.stages.handler import evaluate_handler
from research.speed_rerun import find_test_set


def handler_inputs(run, n: int) -> tuple[torch.Tensor, np.ndarray]:
    """The first ``n`` colliding codes of the run's U(Z) test set and their PD (as the run's handler stage)."""
    path = find_test_set(Path(run.cfg.paths.cache_dir).expanduser(), run.metrics["autoencoder"]["cache_key"],
                         int(run.cfg.detector.test_seed))
    with h5py.File(path, "r") as f:
        pd = f["pd"][:]
        pick = np.flatnonzero(pd > 0)[:n]
        z = f["z"][:][pick]
    return torch.as_tensor(z), pd[pick]


def curve(run_dir: Path, n_inputs: int, workers: int) -> dict:
    rd = RunDir(run_dir)
    rounds = json.loads(rd.detector_rounds.read_text())["rounds"]
    with load_run(run_dir, workers=workers) as run:
        z, pd = handler_inputs(run, n_inputs)
        oracle = LatentOracle(run.space, run.label_pool())
        settings = alm_settings(run.cfg.handler.alm)
        batch = int(run.cfg.handler.batch_size)
        points, missing = [], []
        for r in rounds:
            path = rd.round_detector(r["round"])
            if not path.is_file():
                missing.append(r["round"])
                continue
            net = copy.deepcopy(run.detector)
            net.load_state_dict(load_detector(path)[0].state_dict())
            m, _ = evaluate_handler(DetectorOnCodes(net.eval(), run.space), oracle, z, pd, settings, batch)
            points.append({"round": r["round"], "dataset_size": r["dataset_size"], "n": m["n"],
                           "success_rate": m["success_rate"], "mean_pd_reduction": m["mean_pd_reduction"],
                           "resolved_rate": m["resolved_rate"]})
            print(f"{run_dir.name} round {r['round']} (|D_c| {r['dataset_size']}): success {m['success_rate']:.4f}, "
                  f"PD reduction {m['mean_pd_reduction']:.4f}", flush=True)
    return {"run": run_dir.name, "method": run.metrics["detector"]["method"], "n_inputs": int(len(z)),
            "points": points, "missing_rounds": missing}


def table(results: list[dict]) -> str:
    lines = ["| run | method | round | \\|D_c\\| | success | mean PD reduction | resolved |",
             "|---|---|---|---|---|---|---|"]
    for res in results:
        for p in res["points"]:
            lines.append(f"| {res['run']} | {res['method']} | {p['round']} | {p['dataset_size']:,} | "
                         f"{p['success_rate']:.4f} | {p['mean_pd_reduction']:.4f} | {p['resolved_rate']:.4f} |"
                         .replace(",", " "))
        if res["missing_rounds"]:
            lines.append(f"| {res['run']} | {res['method']} | {res['missing_rounds']} | | no saved detector "
                         "(started before round detectors were kept) | | |")
    return "\n".join(lines)


# the paper's mean relative PD reduction of its final detectors on SCAPE (Fig. 6's caption; it gives no success rate
# as a number): Supv+bd and Active+bd (drawn once, in active_paper's colour), at its final size 5.5e5
PAPER_PD_REDUCTION = {"supv_bd": 0.8876, "active_paper": 0.9481}
PAPER_FINAL_SIZE = 5.5e5


def by_method(results: list[dict], key: str) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Per method (in the report's order): sizes, mean of ``key`` over the runs measured at that size, its error bar
    and the number of runs. The bar is the std over runs (ddof 1) where two or more runs have the size, else the
    binomial standard error of one run's rate over its ``n_inputs`` (``key`` is a rate over the inputs or over the
    successful ones; for the PD reduction, a mean over them, the same formula is a rough bar for a share near 1)."""
    out = {}
    for m in ordered_methods(r["method"] for r in results):
        at: dict[int, list[tuple[float, int]]] = {}
        for r in results:
            if r["method"] == m:
                for p in r["points"]:
                    at.setdefault(int(p["dataset_size"]), []).append((float(p[key]), int(p["n"])))
        if not at:
            continue
        sizes = np.array(sorted(at))
        mean = np.array([np.mean([v for v, _ in at[n]]) for n in sizes])
        err = np.array([np.std([v for v, _ in at[n]], ddof=1) if len(at[n]) > 1
                        else np.sqrt(max(at[n][0][0] * (1 - at[n][0][0]), 0.0) / max(at[n][0][1], 1))
                        for n in sizes])
        out[m] = (sizes, mean, err, np.array([len(at[n]) for n in sizes]))
    return out


def plot(results: list[dict], path: Path) -> None:
    """Paper Fig. 5 (handling success against |D_c|) and the mean PD reduction beside it, one line per method: mean
    over its runs at each size (error bars: :func:`by_method`); the paper's final PD reductions as stars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_inputs = sorted({r["n_inputs"] for r in results})
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, key, ylabel in ((axes[0], "success_rate", "handling success (share of inputs)"),
                            (axes[1], "mean_pd_reduction", "mean relative PD reduction (successful inputs)")):
        for m, (sizes, mean, err, runs) in by_method(results, key).items():
            colour = f"C{METHOD_ORDER.index(m)}" if m in METHOD_ORDER else None
            seeds = f"{runs.max()} seeds" if runs.max() > 1 else "1 seed"
            ax.errorbar(sizes, mean, yerr=err, marker="o", capsize=3, color=colour,
                        label=f"{label(m)} ({seeds})")
            if key == "mean_pd_reduction" and m in PAPER_PD_REDUCTION:
                ax.plot([PAPER_FINAL_SIZE], [PAPER_PD_REDUCTION[m]], "*", ms=14, color=colour,
                        markeredgecolor="black", label=f"paper: {label(m).split(' (')[0]}")
        ax.set_xlabel("data set size |D_c|")
        ax.ticklabel_format(axis="x", style="sci", scilimits=(5, 5))
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[0].set_title(f"success, detector alone ({'/'.join(map(str, n_inputs))} inputs a round)", fontsize=10)
    axes[1].set_title("PD reduction (stars: the paper's final detectors)", fontsize=10)
    handles, labels = axes[1].get_legend_handles_labels()
    order = sorted(range(len(labels)), key=lambda i: labels[i].startswith("paper"))  # the runs first, then the paper
    axes[1].legend([handles[i] for i in order], [labels[i] for i in order], fontsize=8, loc="center left",
                   bbox_to_anchor=(1.02, 0.5))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path, nargs="*", help="run directories to measure")
    ap.add_argument("--from-json", type=Path, nargs="*", default=[],
                    help="earlier --out files to table and plot with the runs measured now (not measured again)")
    ap.add_argument("--inputs", type=int, default=1000, help="colliding test codes handled per round (default 1000)")
    ap.add_argument("--workers", type=int, default=2, help="labeling worker processes (default 2)")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--plot", type=Path, default=None)
    a = ap.parse_args(argv)
    if not a.runs and not a.from_json:
        raise SystemExit("give run directories to measure, or --from-json FILE... of earlier results")
    missing = [str(p) for p in a.from_json if not p.is_file()]
    if missing:
        raise SystemExit(f"--from-json: no such file: {', '.join(missing)}")
    bad = [str(r) for r in a.runs if not RunDir(r).detector_rounds.is_file()]
    if bad:
        raise SystemExit(f"no detector_rounds.json in {', '.join(bad)}: not a run directory, or no round finished")
    if a.inputs < 1:
        raise SystemExit(f"--inputs {a.inputs}: give at least 1")
    # one thread: beside the queue's runs two threads ran the handler 4.5x slower (128 inputs: 15.7 s against 3.3 s)
    torch.set_num_threads(1)
    results = [res for p in a.from_json for res in json.loads(p.read_text())]
    results += [curve(r, a.inputs, a.workers) for r in a.runs]
    print(table(results))
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(results, indent=1))
    if a.plot:
        plot(results, a.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
