"""The collision handler's success against |D_c| (paper Fig. 5), measured afterwards from each round's saved
detector: ``PYTHONPATH=. python research/issue42/handling_curve.py RUN_DIR... [--inputs N] [--out FILE]
[--plot PNG]``.

For every ``round_detectors/round_<k>.pt`` of a run (written since stop 56; earlier rounds of a run started before
are missing and named), the handler guided by that detector alone, the paper's protocol and what
``handler.eval_every_round=true`` measures during a run, on the first N colliding codes of the run's U(Z) test set
(the inputs of the run's own handler stage, which takes its first ``handler.n_inputs``), every result labeled
exactly: success rate (PD reduced) and mean relative PD reduction over the successful inputs (paper: 94.81 % for
Active+bd, 88.76 % for Supv+bd on SCAPE). The runs' baselines (``supv``, ``supv_bd``) re-train at each size, so a
round's detector there is the baseline at that size. Prints a markdown table, writes JSON (``--out``) and a plot of
success rate against |D_c| per run (``--plot``).
"""

from __future__ import annotations

import argparse
import copy
import json
from pathlib import Path

import h5py
import numpy as np
import torch

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
                         "(started before stop 56) | | |")
    return "\n".join(lines)


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for res in results:
        if res["points"]:
            ax.plot([p["dataset_size"] for p in res["points"]], [p["success_rate"] for p in res["points"]], "o-",
                    label=f"{res['run']} ({res['method']})")
    ax.set_xlabel("|D_c|")
    ax.set_ylabel(f"handling success ({results[0]['n_inputs'] if results else 0} inputs)")
    ax.set_title("Collision handling success vs data set size (paper Fig. 5)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path, nargs="+")
    ap.add_argument("--inputs", type=int, default=1000, help="colliding test codes handled per round (default 1000)")
    ap.add_argument("--workers", type=int, default=2, help="labeling worker processes (default 2)")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--plot", type=Path, default=None)
    a = ap.parse_args(argv)
    bad = [str(r) for r in a.runs if not RunDir(r).detector_rounds.is_file()]
    if bad:
        raise SystemExit(f"no detector_rounds.json in {', '.join(bad)}: not a run directory, or no round finished")
    if a.inputs < 1:
        raise SystemExit(f"--inputs {a.inputs}: give at least 1")
    # one thread: beside the queue's runs two threads ran the handler 4.5x slower (128 inputs: 15.7 s against 3.3 s)
    torch.set_num_threads(1)
    results = [curve(r, a.inputs, a.workers) for r in a.runs]
    print(table(results))
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(results, indent=1))
    if a.plot:
        plot(results, a.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
