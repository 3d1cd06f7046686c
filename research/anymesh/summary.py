"""The tables of docs/studies/resolve_without_run.md from the study's outputs: per data set and draw
(seed 0, held-out), resolved by the repairs alone and by the data set's trained run, the share freed, the moves
(fractions of the rest mesh's bounding-box diagonal; the per-mesh largest move also over the freed meshes alone,
since a mesh the repairs give up on moves less) and the seconds (median / mean / max).

    .venv/bin/python -m research.anymesh.summary [--dir outputs/anymesh]

Reads ``realistic_resolve.json`` (seed 0, no run), ``heldout_retry.json`` (held-out, no run; the defaults),
``trained/seed0_<name>.json`` and ``trained/heldout_<name>.json`` (with the run), ``unseen/{seed0,heldout}_{a,b}.json``
(no run; the hands of ``bench.newuser_hand``), where present.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
DATASETS = ("scape", "proc_hand", "proc_cloth", "anny_body", "newuser hand a", "newuser hand b")


def rows_of(result: dict) -> dict:
    """Per-mesh arrays of one data set's result: freed, largest move, median move, seconds, input PD (fractions)."""
    pm = result["resolve"]["per_mesh"]
    return {k: np.array([m[src] for m in pm], dtype=float) for k, src in
            (("freed", "freed"), ("largest", "largest_move"), ("median", "median_move"), ("seconds", "seconds"),
             ("pd", "pd_input_frac"))}


def line(name: str, draw: str, how: str, r: dict) -> str:
    x = rows_of(r)
    n = len(x["freed"])
    ok = x["freed"] > 0
    freed_p95 = f"{100 * np.percentile(x['largest'][ok], 95):.2f} %" if ok.any() else "-"
    return (f"| {name} | {draw} | {how} | {int(x['freed'].sum())}/{n} ({100 * x['freed'].mean():.1f} %) | "
            f"{100 * np.median(x['median']):.3f} % | {100 * np.median(x['largest']):.2f} % | "
            f"{100 * np.percentile(x['largest'], 95):.2f} % | {freed_p95} | "
            f"{np.median(x['seconds']):.2f} / {np.mean(x['seconds']):.2f} / {np.max(x['seconds']):.1f} |")


def main(argv=None) -> str:
    ap = argparse.ArgumentParser(prog="python -m research.anymesh.summary")
    ap.add_argument("--dir", type=Path, default=ROOT / "outputs" / "anymesh")
    a = ap.parse_args(argv)
    sources = [("seed 0", "no run", a.dir / "realistic_resolve.json"),
               ("held-out", "no run", a.dir / "heldout_retry.json")]
    for v in ("a", "b"):  # research/anymesh/unseen.sh: topologies no preset was written for
        sources += [("seed 0", "no run", a.dir / "unseen" / f"seed0_{v}.json", f"newuser hand {v}"),
                    ("held-out", "no run", a.dir / "unseen" / f"heldout_{v}.json", f"newuser hand {v}")]
    for name in DATASETS[:4]:
        sources += [("seed 0", "run", a.dir / "trained" / f"seed0_{name}.json"),
                    ("held-out", "run", a.dir / "trained" / f"heldout_{name}.json")]
    found = {}
    for draw, how, path, *label in sources:
        if path.is_file():
            for name, r in json.loads(path.read_text())["results"].items():
                if "resolve" in r:
                    found[(label[0] if label else name, draw, how)] = r
    out = ["| data set | draw | resolved by | freed | median move | median largest | p95 largest | p95 largest, "
           "freed ones | s/mesh median / mean / max |", "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for name in DATASETS:
        for how in ("no run", "run"):
            for draw in ("seed 0", "held-out"):
                if (name, draw, how) in found:
                    out.append(line(name, draw, how, found[(name, draw, how)]))
    text = "\n".join(out)
    print(text)
    return text


if __name__ == "__main__":
    main()
