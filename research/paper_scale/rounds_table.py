"""The rounds of (possibly unfinished) runs as a markdown table, from each run's ``detector_rounds.json``:
``PYTHONPATH=. python research/paper_scale/rounds_table.py RUN_DIR...``.

One row per finished round: |D_c|, U(Z) test accuracy, FNR and FPR, the best validation accuracy of the round (the
20 % of D_c held out: train against test), and the round's own labeling and training seconds (the file keeps running
totals; the differences are shown). Sittings' pauses are not in these seconds (they are measured inside the fit).
A finished run's last round is recorded at its operating point (``detector.operating_fnr``): its columns then show the
figures at logit 0 like every other round, and the last column those at the operating point.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def rows(run: Path) -> list[dict]:
    rounds = json.loads((run / "detector_rounds.json").read_text())["rounds"]
    out, label0, train0 = [], 0.0, 0.0
    for r in rounds:
        at0 = r.get("at_logit_0", r)  # the last round of a finished run: its operating point in r, logit 0 here
        out.append({"run": run.name, "round": r["round"], "size": r["dataset_size"], "accuracy": at0["accuracy"],
                    "fnr": at0["fnr"], "fpr": at0["fpr"],
                    "operating": (r["accuracy"], r["fnr"]) if "at_logit_0" in r else None,
                    "val_accuracy": r.get("val_accuracy"),
                    "label_s": r["label_seconds"] - label0, "train_s": r["train_seconds"] - train0})
        label0, train0 = r["label_seconds"], r["train_seconds"]
    return out


def table(runs: list[Path]) -> str:
    lines = ["| run | round | \\|D_c\\| | U(Z) accuracy | FNR | FPR | validation accuracy | labeling s | training s "
             "| at the operating point |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for run in runs:
        for r in rows(run):
            val = "" if r["val_accuracy"] is None else f"{r['val_accuracy']:.4f}"
            op = "" if r["operating"] is None else "{:.4f} / FNR {:.4f}".format(*r["operating"])
            lines.append(f"| {r['run']} | {r['round']} | {r['size']:,} | {r['accuracy']:.4f} | {r['fnr']:.4f} | "
                         f"{r['fpr']:.4f} | {val} | {r['label_s']:.0f} | {r['train_s']:.0f} | {op} |".replace(",", " "))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path, nargs="+")
    a = ap.parse_args(argv)
    missing = [str(r) for r in a.runs if not (r / "detector_rounds.json").is_file()]
    if missing:
        raise SystemExit(f"no detector_rounds.json in {', '.join(missing)}: not a run directory, or no round finished")
    print(table(a.runs))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
