"""The run's summary on the terminal: what ``python -m experiments.run`` prints at the end (:func:`print_summary`), and
the line it prints after every round of the detector (:func:`round_line`). Everything here reads ``metrics.json``'s
content only, so a finished run's summary can be printed again from its directory."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from neuralcol.operating import SET_NAMES


def _interval(ci) -> str:
    return "" if not ci else f" [{ci[0]:.3f}, {ci[1]:.3f}]"


def round_rows(rounds: list[dict]) -> list[dict]:
    """The detector's rounds on the U(Z) test set at logit 0: the last round's figures at logit 0 where the run
    set an operating point (its top-level figures are at that point; ``at_logit_0`` keeps the others)."""
    out = [dict(r) for r in rounds]
    if out and out[-1].get("at_logit_0"):
        out[-1].update(out[-1]["at_logit_0"])
        out[-1].setdefault("balanced_accuracy", float("nan"))
    return out


def operating_point_line(op: dict) -> str:
    """The summary's line on the detector's decision threshold, the point ``run.detect``, ``resolve``, the handler
    and the realistic figures decide at: where it was set, on how many rows, what it reached there (with the FNR's
    95 % interval)."""
    cal = op["calibration"]
    n_pos = cal.get("n_colliding")
    size = f"{cal['n']} {SET_NAMES.get(op['operating_set'], op['operating_set'])}" + (
        f" ({n_pos} colliding)" if n_pos is not None else "")
    return (f"  (the operating point, for meshes you bring: logit > {op['threshold']:.3f}, set to FNR <= "
            f"{op['operating_fnr']:g} on {size}: FNR {cal['fnr']:.3f}{_interval(cal.get('fnr_ci95'))} there)")


def operating_verdict(d: dict, target: float | None) -> str:
    """What the realistic FNR's 95 % interval says of the operating target: above it, below it, or consistent."""
    ci = d.get("fnr_ci95")
    if target is None or not ci:
        return ""
    if ci[0] > target:
        return f"; the operating target FNR <= {target:g} is missed"
    if ci[1] < target:
        return f"; under the operating target {target:g} (the threshold is more cautious than asked)"
    return f"; consistent with the operating target {target:g}"


def print_realistic(r: dict | None, target: float | None = None) -> None:
    if not r:
        return
    d, rt = r["detection"], r["round_trip"]
    print(f"realistic meshes (nobody trained on them; {r['n_clear']} of {r['n']} clear, |PD| >= "
          f"{r['clear_eps']:g} eps; {r['base_rate_clear']:.1%} collide):")
    if d.get("n"):
        print(f"  detector: accuracy {d['accuracy']:.4f}, FNR {d['fnr']:.4f}{_interval(d.get('fnr_ci95'))} "
              f"(of {d.get('n_colliding', '?')} colliding), FPR {d['fpr']:.4f}, skill {d['skill']:.3f} "
              f"(majority {d['majority_accuracy']:.4f}){operating_verdict(d, target)}")
    agree = "n/a" if rt["agreement"] is None else f"{rt['agreement']:.1%}"
    oob = "n/a" if rt["out_of_box"] is None else f"{rt['out_of_box']:.1%}"
    print(f"  round trip keeps the exact label of {agree}; codes outside the box {oob}")
    h = r.get("handling")
    if h:
        med = h["displacement_median_frac"]
        print(f"  resolve on {h['n']} colliding meshes: collision-free {h['detector_only']['resolved_rate']:.1%} "
              f"detector-guided, {h['verified']['resolved_rate']:.1%} verified; median vertex displacement "
              f"{'n/a' if med is None else f'{med:.2%}'} of the diagonal")
        kinds = h.get("verified_by_kind")
        if kinds:
            print("    by kind of collision: " + ", ".join(
                f"{k} {v['freed']}/{v['n']} freed" for k, v in kinds.items() if v["n"]))
        if h.get("repair"):
            print(f"    (verified with the handler's margins alone {h['verified_margins_only']['resolved_rate']:.1%}; "
                  f"{h['repair']['n_repaired']} of the returned meshes are the contact repair's)")
        ro = h.get("repair_only")
        if ro:
            med = ro["displacement_median_frac"]
            print(f"  contact repair alone on the inputs (reference): collision-free {ro['resolved_rate']:.1%}, "
                  f"median vertex displacement {'n/a' if med is None else f'{med:.2%}'}, max "
                  f"{ro['displacement_max_frac']:.2%} (median over meshes)")


def latent_reference_lines(metrics: dict) -> list[str]:
    """The latent space against its PCA references: held-out error, box share, round-trip label agreement."""
    ae, la = metrics["autoencoder"], metrics["latent"]
    refs = ae.get("references") or {}
    if not refs:
        return []
    probe = la.get("box_probe") or {}
    rt = (metrics.get("realistic") or {}).get("round_trip") or {}

    def pct(x):
        return "n/a" if x is None else f"{x:.2%}"

    def share(p):
        return "n/a" if not p or p.get("collision_share") is None else f"{p['collision_share']:.1%}"

    def agree(a):
        return "n/a" if not a or a.get("agreement") is None else f"{a['agreement']:.1%}"

    name = "pca" if ae.get("kind") == "pca" else "autoencoder"
    out = ["latent space against PCA at the same |Z_all| (fit on the same training meshes):",
           "                 train err  held-out err  U(Z) collides  round trip keeps label",
           f"  {name + ' (run)':<15} {pct(ae['train_mean_vertex_error']):>9}  {pct(ae['val_mean_vertex_error']):>12}"
           f"  {share(probe.get('space')):>13}  {agree(rt):>22}"]
    for ref, e in refs.items():
        if "reason" in e:
            out.append(f"  {ref:<15} n/a: {e['reason']}")
            continue
        out.append(f"  {ref:<15} {pct(e['train_mean_vertex_error']):>9}  {pct(e['val_mean_vertex_error']):>12}"
                   f"  {share((probe.get('references') or {}).get(ref)):>13}"
                   f"  {agree((rt.get('references') or {}).get(ref)):>22}")
    return out


def print_summary(metrics: dict, run_dir: Path) -> None:
    d, a = metrics["dataset"], metrics["acap"]
    print(f"\ndata set {d['name']}: {d['n_meshes']} meshes, {d['n_vertices']} vertices, {d['n_faces']} faces")
    print(f"ACAP round trip: mean error {a['mean_rel_error']:.2e}, max {a['max_rel_error']:.2e} "
          f"(fraction of bbox diagonal); features {a['features_seconds']:.2f} s"
          f"{' (cached)' if a['features_from_cache'] else ''}, decode {a['decode_ms_per_mesh']:.1f} ms/mesh")
    lb = metrics["dataset_labels"]
    print(f"exact labels: {lb['n_colliding']} of {d['n_meshes']} meshes self-collide {lb['colliding'][:8]}; "
          f"PD in [{lb['pd_min']:.3g}, {lb['pd_max']:.3g}] ({lb['seconds']:.1f} s)")
    ae, la = metrics["autoencoder"], metrics["latent"]
    val = ae["val_mean_vertex_error"]
    print(f"autoencoder{' (cached)' if ae['from_cache'] else ''}: |Z_all| = {la['dim']}, {la['n_parts']} sub-domains "
          f"(pieces {ae['pieces']}); mean vertex error train {ae['train_mean_vertex_error']:.2%}, "
          f"val {val:.2%} of the bbox diagonal" if val is not None else "")
    for line in latent_reference_lines(metrics):
        print(line)
    dt = metrics["detector"]
    print(f"U(Z): {la['uniform_collision_fraction']:.1%} of the {dt['test_set']['n']} test samples self-collide")
    op = dt.get("operating_point")
    print(f"detector ({dt['method']}), stopped by {dt['stopped_by']}; on the U(Z) test set, at logit 0 (the paper's "
          "protocol):")
    print("  |D_c|    accuracy  FNR     FPR     balanced")
    for r in round_rows(metrics["rounds"]):
        print(f"  {r['dataset_size']:<8d} {r['accuracy']:.4f}    {r['fnr']:.4f}  {r['fpr']:.4f}  "
              f"{r['balanced_accuracy']:.4f}")
    if op:
        r = metrics["rounds"][-1]
        print(f"  at the operating point: {r['accuracy']:.4f}    {r['fnr']:.4f}  {r['fpr']:.4f}  "
              f"{r['balanced_accuracy']:.4f}")
        print(operating_point_line(op))
    h = metrics["handling"]
    if h is not None:
        print(f"collision handler on {h['n']} self-penetrating inputs, exact PD after handling:")
        print("                    success  resolved  mean PD reduction  mean |Z - Z_user|  ms per mesh")
        rows = [("detector only", h)] + ([("verified", h["verified"])] if h.get("verified") else [])
        for name, m in rows:
            print(f"  {name:<17} {m['success_rate']:>7.1%}  {m['resolved_rate']:>8.1%}  {m['mean_pd_reduction']:>17.1%}"
                  f"  {m['mean_embedding_diff']:>17.1f}  {1e3 * m['seconds_per_mesh']:>11.1f}")
        print(f"  (detector only: {h['n_nonfinite']} non-finite, {h['n_detector_infeasible']} still predicted "
              f"colliding, {h['n_not_converged']} not converged; verified includes the exact labeling)")
        for c in h.get("certified") or []:
            print(f"  verified through the cascade, FNR <= {c['target_fnr']:g}: success {c['success_rate']:.1%}, "
                  f"resolved {c['resolved_rate']:.1%}; {c['exact_calls']} exact labels of {c['decisions']} decisions "
                  f"({c['exact_share']:.1%}; full verification {c['exact_calls_verified']}); "
                  f"{c['trusted_free_colliding']} trusted free but colliding")
    print_realistic(metrics.get("realistic"), (dt.get("operating_point") or {}).get("operating_fnr"))
    for line in cascade_table(metrics.get("cascade")):
        print(line)
    if metrics.get("speed_accuracy"):
        print("\n".join(speed_accuracy_table(metrics["speed_accuracy"])))
    print(f"results: {run_dir}   (tensorboard --logdir {run_dir / 'tensorboard'})")


def round_line(method: str, r: dict) -> str:
    """The line printed after each round of the detector: |D_c|, the U(Z) test set's accuracy, FNR, FPR and base
    rate, the round's labeling and training time."""
    return (f"[{method}] round {r['round']}: |D_c| = {r['dataset_size']}, test accuracy {r['accuracy']:.4f}, FNR "
            f"{r['fnr']:.4f}, FPR {r['fpr']:.4f} (base rate {r['base_rate']:.3f}); labeling {r['label_seconds']:.0f} "
            f"s, training {r['train_seconds']:.0f} s")


def cascade_table(m: dict | None) -> list[str]:
    """The summary's lines: one per target FNR (band, test and realistic FNR / accuracy / exact share, speed)."""
    if not m:
        return []
    a = m["detector_alone"]
    lines = [f"certified cascade (calibration: {m['calibration']['n']} U(Z) codes, {m['calibration']['base_rate']:.1%}"
             f" collide; exact {m['exact_ms_per_sample']:.2f} ms/sample, detector "
             f"{m['detector_us_per_sample']:.2f} µs/sample):",
             "  target FNR  band [lo, hi)      test FNR  accuracy  exact   realistic FNR  accuracy  exact   "
             "samples/s  vs exact"]

    def f(v, spec):
        return "n/a" if v is None or not np.isfinite(v) else format(v, spec)

    for t in m["targets"]:
        te, re = t["test"], t["realistic"] or {}
        band = f"[{f(t['lo'], '.2f')}, {f(t['hi'], '.2f') if np.isfinite(t['hi']) else 'inf'})"
        lines.append(f"  {t['target_fnr']:<10g}  {band:<17} {f(te['fnr'], '.4f'):>8}  {f(te['accuracy'], '.4f'):>8}"
                     f"  {f(te['exact_share'], '.1%'):>6}  {f(re.get('fnr'), '.4f'):>13}  "
                     f"{f(re.get('accuracy'), '.4f'):>8}  {f(re.get('exact_share'), '.1%'):>6}  "
                     f"{t['samples_per_s']:>9.0f}  {t['speedup_vs_exact']:>7.1f}x")
    lines.append(f"  detector alone             {a['test']['fnr']:>8.4f}  {a['test']['accuracy']:>8.4f}  "
                 f"{0:>6.1%}  {'':>13}  {'':>8}  {'':>6}  {a['samples_per_s']:>9.0f}")
    return lines


def speed_accuracy_table(sa: dict) -> list[str]:
    """The summary lines of ``metrics["speed_accuracy"]``: one row per point, fastest first."""
    def f(x, spec):
        return "—" if x is None else format(x, spec)

    lines = [f"speed against accuracy (torch threads: {sa['threads']}; {sa['n_timed']} test codes timed, "
             f"decode {sa['decode_ms_per_sample']:.2f} ms/sample):",
             "  method           variant                    samples/s   accuracy  FNR     scored on"]
    for p in sorted(sa["points"], key=lambda p: -(p["samples_per_s"] or 0)):
        lines.append(f"  {p['method']:<16} {p['variant']:<26} {f(p['samples_per_s'], '>9.4g')}   "
                     f"{f(p['accuracy'], '.4f'):<8}  {f(p['fnr'], '.4f'):<6}  {p['n_scored']}")
    lines += [f"  ({n})" for n in sa["notes"]]
    return lines
