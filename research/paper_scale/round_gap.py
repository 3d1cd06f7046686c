"""Train against test for one round of a run still in progress, from the round's saved detector (the finished run's
full analysis is explain_gap.py): ``HDF5_USE_FILE_LOCKING=FALSE PYTHONPATH=. python research/paper_scale/round_gap.py
RUN_DIR ROUND [--paper-fnr 0.0515] [--gbt] [--cache-dir DIR]``.

``round_detectors/round_<ROUND>.pt`` scored at logit 0 on the run's U(Z) test set (checked against the round's
record), on the first |D_c| rows of that round split as training saw them (uniform rows trained on / held out,
acquired rows trained on); the test accuracy at the paper's FNR, its threshold chosen on the held-out uniform rows;
the test AUC; with ``--gbt`` sklearn's HistGradientBoostingClassifier (defaults, ``random_state=0``) on the same rows'
codes. For a detector that reads the code only (the paper's); one over code and mesh needs the finished run
(explain_gap.py). ``HDF5_USE_FILE_LOCKING=FALSE`` reads ``dc.h5`` while the run holds it open (rows of finished
rounds are committed and never rewritten).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import h5py
import numpy as np
import torch
from omegaconf import OmegaConf
from sklearn.metrics import roc_auc_score

from neuralcol.nn.detector import load_detector
from neuralcol.operating import fnr_threshold
from neuralcol.rundir import RunDir
from neuralcol.samples.store import VAL_EVERY, Origin
from research.paper_scale.explain_gap import rates
from research.speed_rerun import find_test_set


def logits(net, z: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return torch.cat([net(c).logit for c in torch.as_tensor(z).split(8192)]).numpy()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("round", type=int)
    ap.add_argument("--paper-fnr", type=float, default=0.0515, help="the paper's FNR (SCAPE, Active+bd: 0.0515)")
    ap.add_argument("--gbt", action="store_true")
    ap.add_argument("--cache-dir", type=Path, default=Path("~/neuralcol-cache").expanduser())
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    rd = RunDir(a.run_dir)
    path = rd.round_detector(a.round)
    if not path.is_file():
        raise SystemExit(f"{path}: no saved detector of round {a.round} "
                         "(round not finished, or a run from before round detectors were kept?)")
    record = json.loads(rd.detector_rounds.read_text())["rounds"][a.round]
    cfg = OmegaConf.load(rd.config)
    if str(cfg.detector.get("inputs", "latent")) != "latent":
        raise SystemExit(f"{a.run_dir}: its detector reads code and mesh; use explain_gap.py on the finished run")
    net = load_detector(path)[0].eval()
    key = json.loads(rd.metrics.read_text())["autoencoder"]["cache_key"] if rd.metrics.is_file() else None
    test_path = find_latent_test(a.cache_dir, key, int(cfg.detector.test_seed), record)
    with h5py.File(test_path, "r") as f:
        zt, yt = f["z"][:], f["collides"][:].astype(bool)
    size = int(record["dataset_size"])
    with h5py.File(rd.dc, "r") as f:
        z, y = f["z"][:size], f["collides"][:size].astype(bool)
        rid, origin = f["id"][:size], f["origin"][:size]
    lt, lc = logits(net, zt), logits(net, z)
    test = {"n": int(len(yt)), **rates(lt, yt)}
    if abs(test["accuracy"] - record.get("at_logit_0", record)["accuracy"]) > 1e-9:
        raise SystemExit(f"{test_path}: round {a.round}'s detector scores {test['accuracy']} there, its record "
                         f"{record['accuracy']}: not this run's test set")
    val = rid % VAL_EVERY == VAL_EVERY - 1
    out = {"run": a.run_dir.name, "round": a.round, "dataset_size": size, "test": test,
           "test_auc": float(roc_auc_score(yt, lt))}
    for name, m in (("train uniform", ~val & (origin == Origin.UNIFORM)),
                    ("held-out uniform", val & (origin == Origin.UNIFORM)),
                    ("train acquired", ~val & (origin == Origin.PROJECTED))):
        if m.any():
            out[name] = {"n": int(m.sum()), **rates(lc[m], y[m])}
    held = val & (origin == Origin.UNIFORM)
    t = fnr_threshold(lc[held], y[held], a.paper_fnr)
    out["test at the paper's FNR"] = {"threshold": t, **rates(lt, yt, t)}
    if a.gbt:
        from sklearn.ensemble import HistGradientBoostingClassifier

        p = HistGradientBoostingClassifier(random_state=0).fit(z, y).predict_proba(zt)[:, 1]
        out["gbt on codes"] = {**rates(p, yt, 0.5), "auc": float(roc_auc_score(yt, p))}
    print(json.dumps(out, indent=1))
    return 0


def find_latent_test(cache_dir: Path, key: str | None, test_seed: int, record: dict) -> Path:
    """The run's test set: by its latent space's key when known, else the cached test set of that seed whose size
    and base rate match the round's record."""
    if key is not None:
        return find_test_set(cache_dir, key, test_seed)
    for p in sorted((cache_dir / "collision").glob(f"*/test_s{test_seed}.h5")):
        with h5py.File(p, "r") as f:
            y = f["collides"][:]
        if len(y) == record["n"] and abs(float(np.mean(y)) - record["base_rate"]) < 1e-12:
            return p
    raise SystemExit(f"{cache_dir}: no cached test set of {record['n']} codes with base rate {record['base_rate']}")


if __name__ == "__main__":
    raise SystemExit(main())
