"""Table of the detector-transfer study's runs (docs/studies/detector_transfer.md): per variant and data set, the
realistic test set at the operating point (accuracy, FNR, skill next to the majority class), U(Z) at logit 0, the
threshold, the realistic training rows and the wall time, per seed and as mean ± std (ddof 1) over seeds; then the
handler: success on U(Z) driven by the detector alone and verified, the share of colliding realistic meshes the
detector-guided resolve frees (alone and verified), and the handler stage's seconds.

    python -m research.detector_transfer.summary [--dir outputs/detector_transfer] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np

SETS = ("make_run", "scape", "proc_cloth", "anny_body")


def run_row(metrics: dict) -> dict:
    """The study's figures of one finished run's ``metrics.json``."""
    real = metrics["realistic"]["detection"]
    last = metrics["rounds"][-1]
    at0 = last.get("at_logit_0") or last
    op = metrics["detector"].get("operating_point") or {}
    per_kind = metrics["realistic"].get("per_kind") or {}
    handling = metrics.get("handling") or {}
    resolve = metrics["realistic"].get("handling") or {}
    stages = (metrics.get("sittings") or {}).get("stage_seconds") or {}
    return {"real_acc": real["accuracy"], "real_fnr": real["fnr"], "real_fpr": real["fpr"],
            "real_skill": real.get("skill"), "real_majority": real["majority_accuracy"],
            "real_colliding": real.get("n_colliding"),
            "uz_acc": at0["accuracy"], "uz_fnr": at0["fnr"], "uz_majority": at0.get("majority_accuracy"),
            "threshold": op.get("threshold"), "n_realistic_rows": metrics["detector"].get("n_realistic_rows"),
            "dc_size": last.get("dataset_size"), "minutes": (metrics.get("sittings") or {}).get("minutes"),
            "per_kind_acc": {k: v.get("accuracy") for k, v in per_kind.items() if isinstance(v, dict)},
            "handler_success": handling.get("success_rate"),
            "handler_verified": (handling.get("verified") or {}).get("success_rate"),
            "resolve_freed": (resolve.get("detector_only") or {}).get("resolved_rate"),
            "resolve_freed_verified": (resolve.get("verified") or {}).get("resolved_rate"),
            "handler_seconds": stages.get("handler")}


def collect(root: Path) -> dict:
    """``{variant: {set: {seed: row}}}`` of every finished run under ``root``."""
    out: dict = {}
    for m in sorted(root.glob("*/*/metrics.json")):
        hit = re.fullmatch(r"(.+)_s(\d+)", m.parent.name)
        if not hit:
            continue
        out.setdefault(m.parent.parent.name, {}).setdefault(hit[1], {})[int(hit[2])] = run_row(
            json.loads(m.read_text()))
    return out


def _ms(values: list[float], digits: int = 3) -> str:
    v = np.asarray([x for x in values if x is not None], float)
    if len(v) == 0:
        return "-"
    return f"{v.mean():.{digits}f}" if len(v) == 1 else f"{v.mean():.{digits}f} ± {v.std(ddof=1):.{digits}f}"


def groups(runs: dict):
    """``(variant, data set, "0,1,2", rows)`` of every variant and data set, the study's sets first."""
    for variant, sets in runs.items():
        for name in [s for s in SETS if s in sets] + [s for s in sets if s not in SETS]:
            seeds = sorted(sets[name])
            yield variant, name, ",".join(map(str, seeds)), [sets[name][k] for k in seeds]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", default="outputs/detector_transfer")
    ap.add_argument("--json", default=None, help="also write the rows here")
    a = ap.parse_args(argv)
    runs = collect(Path(a.dir))
    print("| variant | data set | seeds | realistic acc | realistic FNR | skill (majority) | U(Z) acc at 0 | "
          "U(Z) FNR at 0 | threshold | realistic rows | minutes |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for variant, name, seeds, rows in groups(runs):
        def col(key, rows=rows):
            return [r.get(key) for r in rows]

        print(f"| {variant} | {name} | {seeds} | {_ms(col('real_acc'))} | "
              f"{_ms(col('real_fnr'))} | {_ms(col('real_skill'))} ({_ms(col('real_majority'))}) | "
              f"{_ms(col('uz_acc'))} | {_ms(col('uz_fnr'))} | {_ms(col('threshold'))} | "
              f"{_ms(col('n_realistic_rows'), 0)} | {_ms(col('minutes'), 1)} |")
    print()
    print("| variant | data set | seeds | handler success on U(Z): detector only | verified | realistic resolve frees: "
          "detector only | verified | handler stage s |")
    print("|---|---|---|---:|---:|---:|---:|---:|")
    for variant, name, seeds, rows in groups(runs):
        print(f"| {variant} | {name} | {seeds} | "
              + " | ".join(_ms([r.get(key) for r in rows]) for key in
                           ("handler_success", "handler_verified", "resolve_freed", "resolve_freed_verified"))
              + f" | {_ms([r.get('handler_seconds') for r in rows], 0)} |")
    if a.json:
        Path(a.json).write_text(json.dumps(runs, indent=1))


if __name__ == "__main__":
    main()
