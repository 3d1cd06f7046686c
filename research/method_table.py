"""Methods side by side over seeds, from finished runs: ``python -m research.method_table NAME=RUN[,RUN...] ...``.

For each named group of run directories (one method, several seeds) prints mean ± std over its runs of: the labels
used (|D_c|), U(Z) accuracy and FNR at the run's decision threshold (the operating point where the run set one) and
at logit 0, the U(Z) AUC (threshold-free, from ``test_predictions.npz``), the realistic set's (clear cases)
accuracy, FNR and AUC (``realistic_predictions.npz``), and the detector-only handler's success; then, for each pair
of groups, the gap of the means against the larger std (the criterion "each gap beyond the seeds' std"). Used to
compare active against supv_bd and supv at equal labels.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from sklearn.metrics import roc_auc_score

KEYS = ("labels", "acc", "fnr", "acc@0", "fnr@0", "auc", "real_acc", "real_fnr", "real_auc", "handler")


def run_row(run_dir: Path) -> dict:
    """The numbers of one finished run (see the module docstring)."""
    m = json.loads((run_dir / "metrics.json").read_text())
    last = m["rounds"][-1]
    at0 = last.get("at_logit_0") or last
    test = np.load(run_dir / "test_predictions.npz")
    real = m.get("realistic") or {}
    det = real.get("detection") or {}
    row = {"labels": last["dataset_size"], "acc": last["accuracy"], "fnr": last["fnr"], "acc@0": at0["accuracy"],
           "fnr@0": at0["fnr"], "auc": roc_auc_score(test["collides"], test["logit"]),
           "real_acc": det.get("accuracy"), "real_fnr": det.get("fnr"), "real_auc": None,
           "handler": (m.get("handling") or {}).get("success_rate")}
    rp = run_dir / "realistic_predictions.npz"
    if rp.is_file():
        r = np.load(rp)
        clear = r["clear"].astype(bool)
        y = r["pd"][clear] > 0
        if 0 < y.sum() < len(y):
            row["real_auc"] = roc_auc_score(y, r["logit"][clear])
    return row


def summarize(rows: list[dict]) -> dict:
    out = {}
    for k in KEYS:
        vals = np.array([r[k] for r in rows if r.get(k) is not None], float)
        out[k] = (float(vals.mean()), float(vals.std(ddof=1)) if len(vals) > 1 else 0.0, len(vals)) if len(vals) \
            else None
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.method_table", description=__doc__.splitlines()[0])
    ap.add_argument("groups", nargs="+", metavar="NAME=RUN[,RUN...]")
    ap.add_argument("--out", type=Path, default=None, help="write the per-run rows and summaries as JSON")
    a = ap.parse_args(argv)
    groups = {}
    for g in a.groups:
        name, _, runs = g.partition("=")
        if not runs:
            ap.error(f"{g!r}: give NAME=RUN[,RUN...]")
        groups[name] = [run_row(Path(r)) for r in runs.split(",")]
    summ = {name: summarize(rows) for name, rows in groups.items()}
    print("| method | " + " | ".join(KEYS) + " |")
    print("|---" * (len(KEYS) + 1) + "|")
    for name, s in summ.items():
        cells = ["—" if s[k] is None else (f"{s[k][0]:.0f}" if k == "labels" else f"{s[k][0]:.3f} ± {s[k][1]:.3f}")
                 for k in KEYS]
        print(f"| {name} (n={len(groups[name])}) | " + " | ".join(cells) + " |")
    names = list(summ)
    print("\ngaps (mean difference / larger std):")
    for i, x in enumerate(names):
        for y in names[i + 1:]:
            parts = []
            for k in ("acc", "acc@0", "auc", "real_acc", "real_auc", "fnr"):
                if summ[x][k] and summ[y][k]:
                    d = summ[x][k][0] - summ[y][k][0]
                    sd = max(summ[x][k][1], summ[y][k][1])
                    parts.append(f"{k} {d:+.3f} ({abs(d) / sd:.1f} std)" if sd > 0 else f"{k} {d:+.3f}")
            print(f"  {x} - {y}: " + ", ".join(parts))
    if a.out:
        a.out.write_text(json.dumps({"runs": groups, "summary": summ}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
