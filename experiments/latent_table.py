"""The latent space and what stands on it, run by run: ``python -m experiments.latent_table RUN [RUN ...]``.

Reads each run directory's ``metrics.json`` and prints one Markdown row per run: the latent space's
kind, its train / held-out vertex error beside the better PCA reference's held-out error, the share of U(Z) that
collides, the detector on U(Z) (accuracy, majority, skill, FNR), the realistic set (accuracy, FNR, skill, round-trip
agreement, codes outside the box), the handler on U(Z) (detector only) and ``resolve`` on realistic meshes
(detector-guided, verified). ``--group`` adds mean ± std rows over runs whose directory names differ only in a
trailing ``_s<seed>``.

    python -m experiments.latent_table outputs/latent/hand_* --group
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np

from neuralcol.errors import UserInputError
from neuralcol.utils.cli import report_user_errors

COLUMNS = ("latent", "train err", "held-out err", "best PCA held-out", "U(Z) collides", "U(Z) acc", "majority",
           "U(Z) skill", "U(Z) FNR", "real acc", "real FNR", "real skill", "round trip keeps", "outside box",
           "handler (detector)", "resolve (detector)", "resolve (verified)")


def _get(d: dict | None, *keys):
    for k in keys:
        if not isinstance(d, dict) or d.get(k) is None:
            return None
        d = d[k]
    return d


def row(metrics: dict) -> dict:
    """The table's values of one run's metrics (None where a stage did not run)."""
    ae, la, rounds = metrics["autoencoder"], metrics["latent"], metrics["rounds"]
    last = rounds[-1]
    base = la["uniform_collision_fraction"]
    majority = max(base, 1 - base)
    refs = [e.get("val_mean_vertex_error") for e in (ae.get("references") or {}).values()]
    refs = [r for r in refs if r is not None]
    r = metrics.get("realistic") or {}
    kind = ae.get("kind", "bilevel")
    return {
        "latent": f"pca ({ae.get('basis')})" if kind == "pca" else "bilevel",
        "train err": ae["train_mean_vertex_error"], "held-out err": ae["val_mean_vertex_error"],
        "best PCA held-out": min(refs) if refs else None, "U(Z) collides": base,
        "U(Z) acc": last["accuracy"], "majority": majority,
        "U(Z) skill": (last["accuracy"] - majority) / (1 - majority) if majority < 1 else None,
        "U(Z) FNR": last["fnr"],
        "real acc": _get(r, "detection", "accuracy"), "real FNR": _get(r, "detection", "fnr"),
        "real skill": _get(r, "detection", "skill"), "round trip keeps": _get(r, "round_trip", "agreement"),
        "outside box": _get(r, "round_trip", "out_of_box"),
        "handler (detector)": _get(metrics, "handling", "resolved_rate"),
        "resolve (detector)": _get(r, "handling", "detector_only", "resolved_rate"),
        "resolve (verified)": _get(r, "handling", "verified", "resolved_rate"),
    }


def _fmt(v, pct: bool) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, str):
        return v
    return f"{v:.2%}" if pct else f"{v:.3f}"


PERCENT = {"train err", "held-out err", "best PCA held-out"}


def table(named_rows: list[tuple[str, dict]]) -> list[str]:
    out = ["| run | " + " | ".join(COLUMNS) + " |", "|---|" + "---:|" * len(COLUMNS)]
    for name, r in named_rows:
        out.append(f"| {name} | " + " | ".join(_fmt(r[c], c in PERCENT) for c in COLUMNS) + " |")
    return out


def grouped(named_rows: list[tuple[str, dict]]) -> list[tuple[str, dict]]:
    """Mean ± std rows over runs named ``<group>_s<seed>``."""
    groups: dict[str, list[dict]] = {}
    for name, r in named_rows:
        groups.setdefault(re.sub(r"_s\d+$", "", name), []).append(r)
    out = []
    for g, rows in groups.items():
        agg = {}
        for c in COLUMNS:
            vals = [r[c] for r in rows]
            if all(isinstance(v, (int, float)) for v in vals):
                m, s = float(np.mean(vals)), float(np.std(vals, ddof=1)) if len(vals) > 1 else 0.0
                agg[c] = f"{m:.2%} ± {s:.2%}" if c in PERCENT else f"{m:.3f} ± {s:.3f}"
            else:
                agg[c] = vals[0] if len({str(v) for v in vals}) == 1 else "mixed"
        out.append((f"{g} (n={len(rows)})", agg))
    return out


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="run directories (each with metrics.json)")
    ap.add_argument("--group", action="store_true", help="add mean ± std rows over runs named <group>_s<seed>")
    args = ap.parse_args(argv)
    named = []
    for run in args.runs:
        path = run / "metrics.json"
        if not path.is_file():
            raise UserInputError(f"{path}: no such file; give finished run directories (metrics.json is written last)")
        named.append((run.name, row(json.loads(path.read_text()))))
    print("\n".join(table(named)))
    if args.group:
        print()
        print("\n".join(table(grouped(named))))


if __name__ == "__main__":
    main()
