"""What stands on the labels, from finished runs: U(Z)'s colliding share, the detector at its operating point and at
logit 0, the realistic set, the handler and ``resolve``, as mean ± std (ddof 1) over the runs given.

    PYTHONPATH=. .venv/bin/python research/exact_labels/summary.py outputs/exact_labels/make_run_s{0,1,2}
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def row(metrics: dict) -> dict[str, float]:
    """The figures of one run's metrics.json."""
    last = metrics["rounds"][-1]
    at0 = last.get("at_logit_0", last)
    real = metrics["realistic"]
    handling = real["handling"]
    return {
        "U(Z) colliding share": metrics["latent"]["uniform_collision_fraction"],
        "U(Z) accuracy, operating point": last["accuracy"],
        "U(Z) FNR, operating point": last["fnr"],
        "U(Z) accuracy, logit 0": at0["accuracy"],
        "U(Z) FNR, logit 0": at0["fnr"],
        "realistic (clear) colliding share": real["base_rate_clear"],
        "realistic accuracy": real["detection"]["accuracy"],
        "realistic FNR": real["detection"]["fnr"],
        "round trip keeps the exact label": real["round_trip"]["agreement"],
        "handler on U(Z), detector only: success": metrics["handling"]["success_rate"],
        "resolve, detector-guided: freed": handling["detector_only"]["resolved_rate"],
        "resolve, verified: freed": handling["verified"]["resolved_rate"],
        "detector stage, minutes": metrics["detector"]["stage_seconds"] / 60,
    }


def main(runs: list[str]) -> None:
    rows = [row(json.loads((Path(r) / "metrics.json").read_text())) for r in runs]
    print(f"| {len(rows)} runs: {', '.join(Path(r).name for r in runs)} | mean ± std |\n|---|---:|")
    for key in rows[0]:
        x = np.array([r[key] for r in rows])
        print(f"| {key} | {x.mean():.4f} ± {x.std(ddof=1) if len(x) > 1 else 0:.4f} |")


if __name__ == "__main__":
    main(sys.argv[1:])
