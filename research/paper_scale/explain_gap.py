"""Why a paper-scale run lands where it does, measured: ``PYTHONPATH=. python
research/paper_scale/explain_gap.py RUN_DIR... [--gbt FILE...] [--out FILE]``.

Three measurements per finished run, one per candidate limit (labels, network, inputs):

* **train against test**: the run's final detector (``detector.pt``; at logit 0 in the table, and at its operating
  point in the JSON) on its own D_c rows, split as
  training saw them (``id % 5 != 4`` trained on, ``id % 5 == 4`` held out for validation), each split into uniform and
  acquired (projected) rows, next to its U(Z) test accuracy. Training uniform rows far above the test set: the
  network fits what it saw and more labels would help (variance); training rows about equal to test: the network
  cannot fit even its own rows (bias: inputs, capacity or optimisation).
* **the curve's slope**: U(Z) accuracy and FNR against log2 |D_c| over the rounds, a least-squares line over all
  rounds and over the last three (points per doubling), and the size at which the line would reach the paper's
  Table 3 accuracy for the run's method (``None`` where it is reached or the slope is not positive). A slope still
  steep at 5.5e5: the label budget limits; flat: more labels do not.
* **a gradient-boosted reference on the same rows**: from ``research/gbt_reference.py``'s JSON (``--gbt``, matched by
  run directory): trees near the network -> the inputs limit; trees far below -> the network extracts more.

Prints one markdown table and writes the numbers as JSON (``--out``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import h5py
import numpy as np
import torch

from experiments.reporting.discover import paper_figures
from neuralcol.api.run import load_run
from neuralcol.operating import fnr_threshold
from neuralcol.samples.store import VAL_EVERY, Origin


def slope(sizes: np.ndarray, values: np.ndarray) -> float | None:
    """Least-squares change of ``values`` per doubling of ``sizes``; None with fewer than 2 distinct sizes."""
    x = np.log2(np.asarray(sizes, float))
    if len(np.unique(x)) < 2:
        return None
    return float(np.polyfit(x, np.asarray(values, float), 1)[0])


def size_to_reach(sizes: np.ndarray, values: np.ndarray, target: float) -> float | None:
    """Where the log-linear fit of ``values`` over all sizes reaches ``target`` (beyond the last size), or None."""
    x = np.log2(np.asarray(sizes, float))
    if len(np.unique(x)) < 2 or values[-1] >= target:
        return None
    b, a = np.polyfit(x, np.asarray(values, float), 1)
    return None if b <= 0 else float(2.0 ** ((target - a) / b))


def curve(run_dir: Path) -> dict:
    rounds = json.loads((run_dir / "detector_rounds.json").read_text())["rounds"]
    at0 = [r.get("at_logit_0", r) for r in rounds]
    sizes = np.array([r["dataset_size"] for r in rounds], float)
    acc = np.array([r["accuracy"] for r in at0])
    fnr = np.array([r["fnr"] for r in at0])
    return {"sizes": sizes.tolist(), "accuracy": acc.tolist(), "fnr": fnr.tolist(),
            "val_accuracy": [r.get("val_accuracy") for r in rounds],
            "acc_per_doubling": slope(sizes, acc), "acc_per_doubling_last3": slope(sizes[-3:], acc[-3:]),
            "fnr_per_doubling": slope(sizes, fnr), "fnr_per_doubling_last3": slope(sizes[-3:], fnr[-3:])}


def operating_threshold(metrics: dict) -> float:
    """The threshold folded into ``detector.pt``'s bias at the operating point (0.0 without one): the deployed
    logit is the trained one minus it, so ``logit + threshold > 0`` is the trained network at logit 0."""
    op = metrics["detector"].get("operating_point") or {}
    return float(op.get("threshold", 0.0))


def rates(logit: np.ndarray, y: np.ndarray, t: float = 0.0) -> dict:
    """Accuracy and FNR of the verdict ``logit > t`` (FNR None without a colliding row); round_gap.py's too."""
    pred = logit > t
    return {"accuracy": float(np.mean(pred == y)), "fnr": float(np.mean(~pred[y])) if y.any() else None}


def scored(logit: np.ndarray, y: np.ndarray, threshold: float) -> dict:
    """A deployed detector's logits (``threshold`` folded into its bias) at the trained logit 0 and as deployed."""
    return {"at logit 0": rates(logit, y, -threshold), "at the operating point": rates(logit, y)}


def fit_on_rows(run_dir: Path, threshold: float, paper_fnr: float | None = None, batch_size: int = 4096) -> dict:
    """The final detector on its own D_c rows, by split (train / validation) and origin, at logit 0 and at the
    operating point, and on the U(Z) test set (``test_predictions.npz``) the same two ways; with ``paper_fnr``, also
    on the test set at the threshold whose FNR on D_c's held-out uniform rows is the paper's (chosen without the test
    set: accuracy at the paper's FNR, where the two detectors lean differently between misses and false alarms)."""
    with h5py.File(run_dir / "dc.h5", "r") as f:
        n = int(f.attrs.get("committed", len(f["z"])))
        z = f["z"][:n]
        y = f["collides"][:n].astype(bool)
        rid = f["id"][:n]
        origin = f["origin"][:n]
    run = load_run(run_dir, workers=0)
    with torch.no_grad():
        logit = run.detect(torch.as_tensor(z), batch_size=batch_size).logit.numpy()
    val = rid % VAL_EVERY == VAL_EVERY - 1
    test = np.load(run_dir / "test_predictions.npz")
    out = {"test": {"n": len(test["logit"]), **scored(test["logit"], test["collides"].astype(bool), threshold)}}
    for split, s_mask in (("train", ~val), ("validation", val)):
        for name, o_mask in (("all", np.ones(n, bool)), ("uniform", origin == Origin.UNIFORM),
                             ("acquired", origin == Origin.PROJECTED)):
            m = s_mask & o_mask
            if m.any():
                out[f"{split} {name}"] = {"n": int(m.sum()), **scored(logit[m], y[m], threshold)}
    held_out = val & (origin == Origin.UNIFORM)
    if paper_fnr is not None and (held_out & y).any():
        t = fnr_threshold(logit[held_out], y[held_out], paper_fnr)  # in the deployed logit's units
        out["test"]["at the paper's FNR"] = {"threshold": t + threshold,
                                             **rates(test["logit"], test["collides"].astype(bool), t)}
    return out


def explain(run_dir: Path, gbt: dict | None, paper: tuple[float, float] | None = None) -> dict:
    """``paper``: the (accuracy, FNR) to compare with; None: the paper's Table 3 for the run's data set and method."""
    metrics = json.loads((run_dir / "metrics.json").read_text())
    method = metrics["detector"].get("method") if isinstance(metrics.get("detector"), dict) else None
    if method is None:
        from omegaconf import OmegaConf

        method = str(OmegaConf.load(run_dir / ".hydra" / "config.yaml").method.name)
    c = curve(run_dir)
    paper = paper or paper_figures(metrics["dataset"]["name"], method)  # Table 3 (experiments.reporting)
    target = None if paper is None else paper[0]
    out = {"run": run_dir.name, "method": method, "curve": c,
           "rows": fit_on_rows(run_dir, operating_threshold(metrics), None if paper is None else paper[1]),
           "test_accuracy": c["accuracy"][-1], "test_fnr": c["fnr"][-1], "paper": paper,
           "size_to_paper_accuracy": None if target is None else size_to_reach(np.array(c["sizes"]),
                                                                                 np.array(c["accuracy"]), target)}
    if gbt:
        out["gbt"] = {k: v for k, v in gbt.items() if k.startswith("gbt") or k == "detector"}
    return out


def f(v: float | None, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def at_paper_fnr(rows: dict) -> str:
    a = rows["test"].get("at the paper's FNR")
    return "-" if a is None else f"{a['accuracy']:.4f} / {a['fnr']:.4f}"


def table(results: list[dict]) -> str:
    head = ("| run | method | \\|D_c\\| | test acc / FNR | paper | train uniform | val uniform | train acquired "
            "| test at the paper's FNR | acc per doubling (all / last 3) | size to paper's acc "
            "| GBT codes / codes+pairs (AUC; net AUC) |")
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for r in results:
        rows, c = r["rows"], r["curve"]

        def acc(key, rows=rows):
            return f"{rows[key]['at logit 0']['accuracy']:.4f}" if key in rows else "-"

        paper = "-" if r["paper"] is None else "{:.4f} / {:.4f}".format(*r["paper"])
        g = r.get("gbt")
        gtxt = "-" if not g else " / ".join(
            f"{g[k]['accuracy']:.3f} ({g[k]['auc']:.3f})" for k in g if k.startswith("gbt")) + \
            f"; {g['detector']['auc']:.3f}"
        lines.append(f"| {r['run']} | {r['method']} | {int(c['sizes'][-1]):,} | {r['test_accuracy']:.4f} / "
                     f"{r['test_fnr']:.4f} | {paper} | {acc('train uniform')} | {acc('validation uniform')} | "
                     f"{acc('train acquired')} | {at_paper_fnr(rows)} | {f(c['acc_per_doubling'], '+.4f')} / "
                     f"{f(c['acc_per_doubling_last3'], '+.4f')} | {f(r['size_to_paper_accuracy'], '.3g')} | "
                     f"{gtxt} |".replace(",", " "))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path, nargs="+")
    ap.add_argument("--gbt", type=Path, nargs="*", default=[], help="research/gbt_reference.py outputs (JSON)")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    missing = [str(r) for r in a.runs if not (r / "metrics.json").is_file()]
    if missing:
        raise SystemExit(f"no metrics.json in {', '.join(missing)}: not a finished run (rerun its command to finish)")
    torch.set_num_threads(1)
    gbts = {Path(g["run"]).name: g for g in (json.loads(p.read_text()) for p in a.gbt)}
    results = [explain(r, gbts.get(r.name)) for r in a.runs]
    print(table(results))
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
