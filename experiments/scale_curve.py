"""The detector's learning curve at the paper's scale: supv and supv_bd from 2k to 2*10^5 uniform samples.

    python -m experiments.scale_curve dataset=scape labeling.pool.workers=2
    python -m experiments.scale_curve dataset=scape scale.parts=[label] scale.max_label_minutes=30   # a piece

Three parts (``scale.parts``), each resumable:

* ``label``: grows the seed's pool of labeled uniform samples to ``max(scale.sizes)`` rows and the shared
  test set to ``scale.test_size`` rows, ``scale.label_piece`` rows at a time. Both are the caches that
  ``experiments.run`` and ``experiments.diagnose`` use (:mod:`neuralcol.samples.uniform`): a row is a
  pure function of (seed, index), rows are committed every 2048, so an interrupted or time-limited run loses
  at most one commit and a rerun goes on where it stopped. Each piece's wall time and labels per second are
  recorded in ``scale_curve.json``.
* ``train``: for each size n and method (``scale.methods``: the supv / supv_bd rounds of the pipeline, same
  losses and schedule as :func:`neuralcol.diagnose.curve.fit_rows`) trains a fresh detector on the first
  n rows and scores it on the whole test set. Each record is written to ``scale_curve.json`` as it finishes;
  a rerun skips the records it has.
* ``plot``: ``scale_curve.png`` (accuracy and FNR against n, log axis, majority class; labeling and training
  wall time) and a markdown table ``scale_curve.md``.
"""

from __future__ import annotations

import json
import logging
import shutil
import time
import warnings
from pathlib import Path

import hydra
import numpy as np
import torch
from omegaconf import DictConfig

from neuralcol.errors import UserInputError
from neuralcol.resources import conf_dir
from neuralcol.utils.cli import report_user_errors
from neuralcol.utils.config import as_dict

PARTS = ("label", "train", "plot")
STATE = "scale_curve.json"


def load_state(out: Path) -> dict:
    path = out / STATE
    if path.is_file():
        return json.loads(path.read_text())
    return {"pieces": [], "records": []}


def save_state(out: Path, state: dict) -> None:
    from neuralcol.utils.files import write_json_atomic

    write_json_atomic(out / STATE, state)


def _stores(cfg: DictConfig, oracle, key: str) -> tuple[Path, Path, int]:
    from neuralcol.samples.cache import samples_cache_dir

    shared = samples_cache_dir(cfg.paths.cache_dir, key, oracle.pool.labeler)
    seed = int(cfg.scale.pool_seed)
    return shared / f"uniform_s{seed}.h5", shared / f"test_s{int(cfg.detector.test_seed)}.h5", seed


def _rows_in(path: Path) -> int:
    import h5py

    if not path.is_file():
        return 0
    with h5py.File(path, "r") as h5:
        return int(len(h5["id"])) if "id" in h5 else 0


def label_part(cfg: DictConfig, oracle, key: str, state: dict, out: Path) -> None:
    """Grow the pool and the test set piece by piece (the larger deficit first), recording each piece."""
    from neuralcol.samples.uniform import uniform_rows

    pool_path, test_path, seed = _stores(cfg, oracle, key)
    want = {"pool": (pool_path, max(int(s) for s in cfg.scale.sizes), seed),
            "test": (test_path, int(cfg.scale.test_size), int(cfg.detector.test_seed))}
    piece = int(cfg.scale.label_piece)
    limit = cfg.scale.max_label_minutes
    t_start = time.perf_counter()
    pieces_now = 0
    while True:
        have = {name: _rows_in(p) for name, (p, _, _) in want.items()}
        todo = {name: n - have[name] for name, (_, n, _) in want.items() if have[name] < n}
        if not todo:
            print(f"labels: pool {have['pool']:,} rows, test {have['test']:,} rows: done")
            return
        if limit is not None and pieces_now and time.perf_counter() - t_start >= 60 * float(limit):
            print(f"labels: stopped after {limit} min (scale.max_label_minutes); pool {have['pool']:,}, test "
                  f"{have['test']:,} rows; rerun to go on")
            return
        name = max(todo, key=lambda k: todo[k] / want[k][1])  # the store furthest from its target
        path, n_want, s = want[name]
        target = min(n_want, have[name] + piece)
        res = uniform_rows(path, oracle, target, s, desc=f"labeling {name} to {target:,}")
        pieces_now += 1
        rate = res.labeled / res.seconds if res.seconds > 0 else float("nan")
        state["pieces"].append({"store": name, "rows": target, "labeled": res.labeled, "seconds": res.seconds,
                                "labels_per_s": rate, "failed": res.n_failed,
                                "workers": int(cfg.labeling.pool.workers), "backend": str(cfg.labeling.backend)})
        save_state(out, state)
        print(f"labels: {name} {target:,} rows (+{res.labeled:,} in {res.seconds:.0f} s, {rate:.1f} labels/s)")


def train_part(cfg: DictConfig, space, oracle, key: str, state: dict, out: Path) -> None:
    from neuralcol.diagnose.curve import fit_rows, take_rows
    from neuralcol.nn.detector import build_detector
    from neuralcol.samples.uniform import uniform_rows

    det = as_dict(cfg.detector)
    pool_path, test_path, seed = _stores(cfg, oracle, key)
    sizes = sorted(int(s) for s in cfg.scale.sizes)
    n_pool, n_test = _rows_in(pool_path), _rows_in(test_path)
    if n_test < int(cfg.scale.test_size) or n_pool < sizes[0]:
        raise UserInputError(f"scale.parts has train but the labels are not complete (pool {n_pool:,} of "
                             f"{sizes[-1]:,}, test {n_test:,} of {int(cfg.scale.test_size):,}); run the label "
                             "part first (scale.parts=[label])")
    test = uniform_rows(test_path, oracle, int(cfg.scale.test_size), int(det["test_seed"])).rows
    pool = uniform_rows(pool_path, oracle, min(n_pool, sizes[-1]), seed).rows
    state["test_size"] = len(test.z)
    base = float(np.mean(test.collides))
    state["base_rate"], state["majority_accuracy"] = base, max(base, 1 - base)
    done = {(r["size"], r["model"], r["seed"]) for r in state["records"]}
    pd_unit = float(oracle.pool.labeler.cap)
    for n in sizes:
        if n > len(pool.z):
            print(f"train: n={n:,} skipped: the pool has {len(pool.z):,} rows (label more first)")
            continue
        sub = take_rows(pool, n)
        for m in cfg.scale.methods:
            for s in cfg.scale.seeds:
                if (n, str(m.name), int(s)) in done:
                    continue
                torch.manual_seed(int(s))
                net = build_detector(space, det)
                fit = fit_rows(net, sub, test, pd_unit, det, float(m.w_b), bool(m.use_boundary_set), int(s))
                rec = {"size": n, "model": str(m.name), "seed": int(s), **fit}
                state["records"].append(rec)
                save_state(out, state)
                print(f"train: n={n:,} {m.name} seed {s}: test accuracy {rec['test']['accuracy']:.4f}, FNR "
                      f"{rec['test']['fnr']:.3f}, {fit['seconds']:.0f} s")


def _mean(records, model, n, key):
    vals = [r["test"][key] for r in records if r["model"] == model and r["size"] == n]
    return (float(np.mean(vals)), float(np.std(vals)), len(vals)) if vals else None


def plot_part(cfg: DictConfig, state: dict, out: Path, title: str) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    recs = state["records"]
    if not recs:
        print("plot: no records yet (run the train part)")
        return []
    models = list(dict.fromkeys(r["model"] for r in recs))
    sizes = sorted({r["size"] for r in recs})
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
    for i, m in enumerate(models):
        for a, key in ((ax[0], "accuracy"), (ax[1], "fnr")):
            pts = [(n, _mean(recs, m, n, key)) for n in sizes]
            pts = [(n, v) for n, v in pts if v is not None]
            a.errorbar([n for n, _ in pts], [v[0] for _, v in pts], yerr=[v[1] for _, v in pts], fmt="o-",
                       color=f"C{i}", label=m, capsize=3)
        secs = [(n, np.mean([r["seconds"] for r in recs if r["model"] == m and r["size"] == n])) for n in sizes
                if any(r["model"] == m and r["size"] == n for r in recs)]
        ax[2].plot([n for n, _ in secs], [s / 60 for _, s in secs], "o-", color=f"C{i}", label=f"training {m}")
    if "majority_accuracy" in state:
        ax[0].axhline(state["majority_accuracy"], color="k", ls=":", lw=0.8, label="majority class")
    pieces = [p for p in state["pieces"] if p["labeled"] > 0]
    if pieces:
        rate = sum(p["labeled"] for p in pieces) / sum(p["seconds"] for p in pieces)
        ax[2].plot(sizes, [n / rate / 60 for n in sizes], "k--",
                   label=f"labeling n rows ({rate:.0f} labels/s measured)")
    ax[0].set(ylabel="test accuracy", title=f"accuracy ({state.get('test_size', 0):,} test samples)")
    ax[1].set(ylabel="false negative rate", title="FNR")
    ax[2].set(ylabel="minutes", title="wall time", yscale="log")
    for a in ax:
        a.set(xscale="log", xlabel="|D_c| (uniform samples)")
        a.grid(alpha=0.3, which="both")
        a.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    png = out / "scale_curve.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    seeds = sorted({r["seed"] for r in recs})
    lines = [f"Test accuracy and FNR on {state.get('test_size', 0):,} U(Z) samples (majority class "
             f"{state.get('majority_accuracy', float('nan')):.4f}); mean ± std over training seeds {seeds} where "
             "there are several; min: training minutes per run.", "",
             "| n | " + " | ".join(f"{m} accuracy | {m} FNR | {m} min" for m in models) + " |",
             "| ---: |" + " ---: | ---: | ---: |" * len(models)]
    for n in sizes:
        cells = []
        for m in models:
            acc, fnr = _mean(recs, m, n, "accuracy"), _mean(recs, m, n, "fnr")
            sec = [r["seconds"] for r in recs if r["model"] == m and r["size"] == n]
            if acc is None:
                cells += ["-", "-", "-"]
            elif acc[2] > 1:  # mean ± std over the training seeds
                cells += [f"{acc[0]:.4f} ± {acc[1]:.4f}", f"{fnr[0]:.3f} ± {fnr[1]:.3f}", f"{np.mean(sec) / 60:.1f}"]
            else:
                cells += [f"{acc[0]:.4f}", f"{fnr[0]:.3f}", f"{np.mean(sec) / 60:.1f}"]
        lines.append(f"| {n:,} | " + " | ".join(cells) + " |")
    md = out / "scale_curve.md"
    md.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return [png, md]


def run(cfg: DictConfig) -> dict:
    parts = list(cfg.scale.parts)
    bad = [p for p in parts if p not in PARTS]
    if bad or not parts:
        raise UserInputError(f"scale.parts={parts}: use a non-empty list of {', '.join(PARTS)}")
    sizes = [int(s) for s in cfg.scale.sizes]
    if not sizes or min(sizes) < 10:
        raise UserInputError(f"scale.sizes={sizes}: use row counts >= 10")
    out = Path(str(cfg.scale.out))
    out.mkdir(parents=True, exist_ok=True)
    state = load_state(out)
    state["dataset"] = cfg.dataset.name
    if "label" in parts or "train" in parts:
        from experiments.diagnose import diagnose_context

        ctx = diagnose_context(cfg)
        space, report, _ = ctx.latent_space()
        key = report["cache_key"]
        state["latent_space"] = key
        with ctx.pool(ctx.sample_labeler()) as pool:
            oracle = ctx.oracle(pool)
            if "label" in parts:
                label_part(cfg, oracle, key, state, out)
            if "train" in parts:
                train_part(cfg, space, oracle, key, state, out)
    files = [out / STATE]
    save_state(out, state)
    if "plot" in parts:
        files += plot_part(cfg, state, out, f"{cfg.dataset.name}: detector learning curve (uniform samples)")
    if cfg.scale.docs:
        dest = Path(str(cfg.scale.docs))
        dest.mkdir(parents=True, exist_ok=True)
        for f in files:
            shutil.copy2(f, dest / f.name)
        print(f"copied {', '.join(f.name for f in files)} to {dest}")
    return state


@hydra.main(version_base="1.3", config_path=str(conf_dir()), config_name="scale_curve")
@report_user_errors
def main(cfg: DictConfig) -> None:
    logging.getLogger("lightning.pytorch.utilities.rank_zero").setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*")
    run(cfg)


if __name__ == "__main__":
    main()
