"""The rules registered in docs/studies/shrink_correction.md and docs/studies/displacement_cap.md, read
from the deciding runs' ``realistic_<name>{0,N}_<tag>.json`` and the user path's
``user_scape_<name>{0,N}_<tag>.json`` (``research/resolve/runs.sh shrink``, ``... cap``):

    PYTHONPATH=. python research/resolve/shrink_table.py RUN_DIR [RUN_DIR ...] [--tag rerun] [--user-dir D]
        [--name shrink --steps 5 | --name cap --steps 6]

Prints per run, <name>_steps 0 -> N: verified free, median displacement, p95 and median of the per-mesh largest
(fractions of the diagonal), meshes changed, the handling stage's seconds, the p95 edge strain where recorded; then
criteria (a)-(e) ((e): the shrink rule's <= 1 s per mesh; the cap rule's <= 1.05x the seconds of N = 0).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--tag", default="rerun")
    ap.add_argument("--name", choices=("shrink", "cap"), default="shrink")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--user-dir", type=Path, default=Path("outputs/resolve"))
    a = ap.parse_args()
    def strain(h: dict) -> str:
        return "" if h.get("edge_strain_p95") is None else f"{h['edge_strain_p95']:.3f}"

    never_lower, p95_never_higher, p95_lower, ok_c, ok_d = True, True, 0, True, True
    print("| run | verified free | median displacement (% diag) | p95 largest (%) | median largest (%) | changed "
          "| handling s | p95 edge strain |")
    print("|---|---|---|---|---|---|---|---|")
    for run in a.runs:
        b, c = (json.loads((run / f"realistic_{a.name}{s}_{a.tag}.json").read_text())["handling"]
                for s in (0, a.steps))
        fb, fc = b["verified"]["resolved_rate"], c["verified"]["resolved_rate"]
        pb, pc = b["displacement_max_frac_p95"], c["displacement_max_frac_p95"]
        never_lower &= fc >= fb
        p95_never_higher &= pc <= pb
        p95_lower += pc < pb
        ok_c &= c["displacement_median_frac"] <= 0.002
        ok_d &= c["seconds"] <= 1.25 * b["seconds"]
        print(f"| {run.name} | {fb:.0%} -> {fc:.0%} | {100 * b['displacement_median_frac']:.4f} -> "
              f"{100 * c['displacement_median_frac']:.4f} | {100 * pb:.1f} -> {100 * pc:.1f} | "
              f"{100 * b['displacement_max_frac']:.2f} -> {100 * c['displacement_max_frac']:.2f} | "
              f"{c['repair'].get('n_shrunk' if a.name == 'shrink' else 'n_capped', 0)} of {c['n']} | "
              f"{b['seconds']:.0f} -> {c['seconds']:.0f} | {strain(b)} -> {strain(c)} |")
    user = {s: a.user_dir / f"user_scape_{a.name}{s}_{a.tag}.json" for s in (0, a.steps)}
    if all(p.exists() for p in user.values()):
        u = {s: json.loads(p.read_text())["contact_untangle"] for s, p in user.items()}
        print(f"\nuser path, SCAPE: free {u[0]['free']:.3f} -> {u[a.steps]['free']:.3f}, p95 of the largest "
              f"{100 * u[0]['p95_largest_frac']:.2f} -> {100 * u[a.steps]['p95_largest_frac']:.2f} %, "
              f"{u[0]['seconds_per_mesh']:.2f} -> {u[a.steps]['seconds_per_mesh']:.2f} s per mesh")
        secs = u[a.steps]["seconds_per_mesh"]
        ok_e = secs <= 1.0 if a.name == "shrink" else secs <= 1.05 * u[0]["seconds_per_mesh"]
    else:
        ok_e = None
    print(f"\n(a) verified free never lower: {never_lower}\n(b) p95 of the largest never higher: {p95_never_higher}, "
          f"lower on {p95_lower} runs (need 1): {p95_never_higher and p95_lower >= 1}\n"
          f"(c) median displacement <= 0.2 %: {ok_c}\n(d) handling <= 1.25x: {ok_d}\n"
          f"(e) user path SCAPE {'<= 1 s' if a.name == 'shrink' else '<= 1.05x'} per mesh: {ok_e}")


if __name__ == "__main__":
    main()
