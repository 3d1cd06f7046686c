"""The rule registered in docs/studies/untangle_repair.md (untangle as the default repair), read from
the deciding runs' ``realistic_{contact,<candidate>}_<tag>.json`` (``research/resolve/runs.sh repair``):

    PYTHONPATH=. python research/resolve/decide_table.py RUN_DIR [RUN_DIR ...] [--tag rerun] [--candidate M]
        [--contact-tag T]

Prints per run: verified collision-free rate, the repair alone, the median over meshes of the per-mesh median
displacement, the 95th percentile and the median of the per-mesh largest (fractions of the diagonal), the handling
stage's seconds, each contact -> the candidate (default untangle); then criteria (a)-(d).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--tag", default="rerun")
    ap.add_argument("--contact-tag", help="the contact repair's runs under another tag (default: --tag)")
    ap.add_argument("--candidate", default="untangle", help="the method judged against contact (rule v2: "
                    "contact_untangle)")
    a = ap.parse_args()
    gains, ok_b, ok_c, ok_d, never_lower = 0, True, True, True, True
    print("| run | verified free | repair alone | median displacement (% diag) | p95 largest (%) | median largest (%) "
          "| handling s | by kind, candidate (freed/n) |")
    print("|---|---|---|---|---|---|---|---|")
    for run in a.runs:
        tags = {"contact": a.contact_tag or a.tag, a.candidate: a.tag}
        h = {m: json.loads((run / f"realistic_{m}_{t}.json").read_text())["handling"] for m, t in tags.items()}
        c, u = h["contact"], h[a.candidate]
        fc, fu = c["verified"]["resolved_rate"], u["verified"]["resolved_rate"]
        never_lower &= fu >= fc
        gains += fu - fc >= 0.05
        ok_b &= u["displacement_median_frac"] <= 0.002
        top = u["displacement_max_frac_p95"]
        ok_c &= top <= 0.03 or top <= c["displacement_max_frac_p95"]
        ok_d &= u["seconds"] <= 2 * c["seconds"]
        kinds = ", ".join(f"{k} {v['freed']}/{v['n']}" for k, v in u["verified_by_kind"].items() if v["n"])
        print(f"| {run.name} | {fc:.0%} -> {fu:.0%} | {c['repair_only']['resolved_rate']:.0%} -> "
              f"{u['repair_only']['resolved_rate']:.0%} | {100 * c['displacement_median_frac']:.4f} -> "
              f"{100 * u['displacement_median_frac']:.4f} | {100 * c['displacement_max_frac_p95']:.1f} -> "
              f"{100 * u['displacement_max_frac_p95']:.1f} | {100 * c['displacement_max_frac']:.2f} -> "
              f"{100 * u['displacement_max_frac']:.2f} | {c['seconds']:.0f} -> {u['seconds']:.0f} | {kinds} |")
    print(f"\n(a) never lower: {never_lower}; >= 5 points higher on {gains} runs (need 2): "
          f"{never_lower and gains >= 2}\n(b) median displacement <= 0.2 %: {ok_b}\n"
          f"(c) p95 of the largest <= 3 % or <= contact's: {ok_c}\n(d) handling <= 2x contact's time: {ok_d}")


if __name__ == "__main__":
    main()
