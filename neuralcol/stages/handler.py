"""Stage: resolve self-penetrating latent codes with the trained detector and measure the result exactly.

Paper sec. 5 ("Collision Handling"): self-penetrating codes ``Z_user`` from U(Z) (here: the colliding rows of
the shared test set, so every method and seed handles the same inputs, none of them seen in training) are
moved by the augmented-Lagrangian handler to the nearest code the detector calls collision-free; the exact
labeler then measures ``PD`` before and after. Metrics (all over the n inputs unless said otherwise):

* ``success_rate``: fraction with relative PD reduction ``(PD_before - max(PD_after, 0)) / PD_before > 0``;
* ``resolved_rate``: fraction with ``PD_after <= 0`` (no self-intersection left);
* ``mean_pd_reduction``: mean relative PD reduction over the successful inputs (paper: 94.81 % on SCAPE);
* ``mean_embedding_diff``: mean ``|Z - Z_user|`` over the successful inputs (paper: 56.17 on SCAPE);
* ``seconds_per_mesh``: handler wall time per input (batched; labeling excluded);
* failures, counted: ``n_nonfinite`` (NaN/inf in the detector or objective), ``n_detector_infeasible`` (the
  detector still says "collides" at the end), ``n_not_converged``.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from neuralcol.handler.alm import ALMSettings, Resolution
from neuralcol.handler.resolve import (
    CertifiedLabel,
    certified_outcome,
    detector_logits,
    handle_codes,
    verified_escalation,
)
from neuralcol.samples.oracle import LatentOracle


def pd_reduction_metrics(z_user: np.ndarray, z: np.ndarray, pd_before: np.ndarray,
                         pd_after: np.ndarray) -> tuple[dict, dict]:
    """The paper's handling measures from exact PD before/after (NaN after = the handler failed on that input).

    Returns (metrics: n, success_rate, resolved_rate, mean_pd_reduction and mean_embedding_diff over the
    successful inputs, and the same two over all finite inputs; arrays: reduction, embedding_diff, success,
    resolved)."""
    n = len(pd_before)
    finite = np.isfinite(pd_after)
    reduction = (pd_before - np.maximum(pd_after, 0.0)) / pd_before  # NaN where non-finite
    diff = np.linalg.norm(np.asarray(z, np.float64) - np.asarray(z_user, np.float64), axis=-1)
    success = np.nan_to_num(reduction, nan=-np.inf) > 0
    resolved = np.nan_to_num(pd_after, nan=np.inf) <= 0
    nan = float("nan")
    metrics = {
        "n": n,
        "success_rate": float(success.mean()) if n else nan,
        "resolved_rate": float(resolved.mean()) if n else nan,
        "mean_pd_reduction": float(reduction[success].mean()) if success.any() else nan,
        "mean_embedding_diff": float(diff[success].mean()) if success.any() else nan,
        "mean_pd_reduction_all": float(np.nanmean(reduction)) if finite.any() else nan,
        "mean_embedding_diff_all": float(diff[finite].mean()) if finite.any() else nan,
    }
    return metrics, {"reduction": reduction, "embedding_diff": diff, "success": success, "resolved": resolved}


def evaluate_handler(net: torch.nn.Module, oracle: LatentOracle, z_user: torch.Tensor, pd_before: np.ndarray,
                     settings: ALMSettings, batch_size: int = 256, verify_margins=(),
                     certify: dict | None = None) -> tuple[dict, dict]:
    """Handle ``z_user`` (all self-penetrating, PD ``pd_before`` > 0) and label the results exactly.

    The top-level metrics are the paper's protocol (the detector alone guides the handler). With
    ``verify_margins`` the inputs still self-penetrating are handled again with larger margins
    (:func:`verified_escalation`) and ``metrics["verified"]`` holds the same measures after that, with the
    wall time per input including the exact labeling.

    ``certify`` (``{target FNR: Band}``, with ``verify_margins``): the same verification through the certified
    cascade of each band (:class:`~neuralcol.handler.resolve.CertifiedLabel`): a handled result is labeled exactly
    only where the detector's logit on it lies in the band, the others trust the detector.
    ``metrics["certified"]`` holds one entry per target: the handling measures (on the exact PD of every final
    result, measured afterwards for the evaluation; the cascade did not see it outside the band), ``exact_share``
    (exact labels per verification decision; the first handling's results, whose exact PD is already known, are
    read instead of labeled again: the same answer), ``trusted_free_colliding`` (results the cascade called free
    that self-penetrate) and ``exact_calls_verified`` (the exact labels of the full verification, for comparison).

    Returns:
        (metrics dict, per-input arrays: z, pd_before, pd_after, reduction, embedding_diff, success, ...)
    """
    pd_before = np.asarray(pd_before, np.float64)
    if (pd_before <= 0).any():
        raise ValueError("evaluate_handler: every input must self-penetrate (PD > 0)")
    space = oracle.space
    z_user = z_user.cpu()
    n = len(z_user)

    def handle(rows: np.ndarray, margin: float) -> Resolution:
        return handle_codes(net, z_user[torch.as_tensor(rows)], space.box_lo, space.box_hi,
                            replace(settings, margin=margin), batch_size=batch_size,
                            desc=f"handling codes (margin {margin:g})")

    label_failures, labeled = [0], [0]

    def label(z: torch.Tensor, rows=None) -> np.ndarray:  # NaN PD where the labeler failed (reported, counted)
        lab = oracle(z, desc="labeling handled codes")
        label_failures[0] += int(getattr(lab, "n_failed", 0))
        labeled[0] += len(z)
        return lab.pd

    t0 = time.perf_counter()
    res = handle(np.arange(n), settings.margin)
    seconds = time.perf_counter() - t0
    finite = res.finite.numpy()
    pd_after = np.full(n, np.nan)
    t0 = time.perf_counter()
    pd_after[finite] = label(res.z[res.finite])
    label_seconds = time.perf_counter() - t0
    metrics, derived = pd_reduction_metrics(z_user.numpy(), res.z.numpy(), pd_before, pd_after)
    metrics.update({
        "seconds_per_mesh": seconds / max(n, 1),
        "label_seconds": label_seconds,
        "n_nonfinite": int((~finite).sum()),
        "n_label_failures": label_failures[0],  # results the exact labeler failed on (NaN PD, counted as failed)
        "n_detector_infeasible": int((finite & ~res.feasible.numpy()).sum()),
        "n_not_converged": int((finite & ~res.converged.numpy()).sum()),
        "mean_outer_iterations": float(res.outer.float().mean()) if n else float("nan"),
        "settings": settings.__dict__,
    })
    arrays = {"z_user": z_user.numpy(), "z": res.z.numpy(), "pd_before": pd_before, "pd_after": pd_after,
              "detector_feasible": res.feasible.numpy(), "finite": finite, **derived}
    margins = [float(m) for m in verify_margins]
    if margins:
        t_v = time.perf_counter()
        z_v, pd_v, stage, handled = verified_escalation(handle, label, z_user, res.z, pd_after, margins)
        seconds_v = seconds + label_seconds + time.perf_counter() - t_v
        exact_verified = labeled[0]  # exact labels of the full verification (first handling included)
        m_v, d_v = pd_reduction_metrics(z_user.numpy(), z_v.numpy(), pd_before, pd_v)
        metrics["verified"] = {**m_v, "margins": margins, "handled_per_stage": handled,
                               "kept_per_stage": np.bincount(stage, minlength=len(margins) + 1).tolist(),
                               "seconds_per_mesh": seconds_v / max(n, 1)}
        arrays.update({"z_verified": z_v.numpy(), "pd_after_verified": pd_v, "stage_verified": stage,
                       **{f"{k}_verified": v for k, v in d_v.items()}})
        if certify:
            metrics["certified"] = [
                certified_handling(net, handle, label, z_user, res, pd_before, pd_after, margins, float(t), band,
                                   exact_calls_verified=exact_verified)
                for t, band in certify.items()]
    return metrics, arrays


def certified_handling(net, handle, label, z_user: torch.Tensor, res: Resolution, pd_before: np.ndarray,
                       pd_after: np.ndarray, margins: list[float], target_fnr: float, band,
                       exact_calls_verified: int | None = None) -> dict:
    """One ``metrics["certified"]`` entry of :func:`evaluate_handler`: margin escalation decided by the certified
    cascade of ``band``, its results measured exactly afterwards."""
    finite = res.finite.numpy()
    decide = CertifiedLabel(band, lambda z: detector_logits(net, z), lambda z, rows: pd_after[rows])
    first = np.full(len(pd_after), np.nan)
    if finite.any():  # the first handling's exact PD is known: read, not labeled again
        first[finite] = decide(res.z[res.finite], np.flatnonzero(finite))
    decide.label = label
    z_c, pd_c, stage, handled = verified_escalation(handle, decide, z_user, res.z, first, margins)
    pd_meas, exact, free = certified_outcome(pd_c)
    trusted = np.flatnonzero(np.isinf(pd_c))
    kept_first = trusted[stage[trusted] == 0]
    pd_meas[kept_first] = pd_after[kept_first]
    later = trusted[stage[trusted] > 0]
    if len(later):  # measured for the evaluation only (not an exact call of the cascade)
        pd_meas[later] = label(z_c[torch.as_tensor(later)], later)
    m, _ = pd_reduction_metrics(z_user.numpy(), z_c.numpy(), pd_before, pd_meas)
    return {"target_fnr": target_fnr, "lo": float(band.lo), "hi": float(band.hi), **m,
            "exact_share": decide.exact_share, "exact_calls": decide.exact_calls, "decisions": decide.decisions,
            "exact_calls_verified": exact_calls_verified,
            "trusted_free_colliding": int((np.isneginf(pd_c) & (np.nan_to_num(pd_meas, nan=0.0) > 0)).sum()),
            "handled_per_stage": handled,
            "kept_per_stage": np.bincount(stage, minlength=len(margins) + 1).tolist()}


def plot_reduction_vs_difference(arrays: dict, path: Path, title: str = "") -> Path:
    """Paper Fig. 6: relative PD reduction vs embedding difference of the successfully handled inputs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.8))
    lows = [0.0]
    for suffix, name in (("", "detector only"), ("_verified", "verified")):
        if f"success{suffix}" not in arrays:
            continue
        ok = arrays[f"success{suffix}"]
        ax.scatter(arrays[f"embedding_diff{suffix}"][ok], arrays[f"reduction{suffix}"][ok], s=6, alpha=0.5,
                   label=f"{name}: {int(ok.sum())} of {len(ok)} successful")
        lows.append(float(np.nanmin(arrays[f"reduction{suffix}"][ok])) if ok.any() else 0.0)
    ax.set_xlabel("embedding difference |Z - Z_user|")
    ax.set_ylabel("relative PD reduction (successful inputs)")
    ax.set_ylim(min(lows), 1.05)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def per_input_results(arrays: dict, pd_sub_before: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The detector-only handler's result per input, as written to ``handling/per_input.npz``.

    Args:
        arrays: the per-input arrays of :func:`evaluate_handler` (N inputs).
        pd_sub_before: (N, K) exact PD of each input per sub-domain, or None (then left out).

    Returns:
        pd_before (N,) float64, pd_after (N,) float64 (NaN: the handler or the labeler failed), success (N,)
        bool (the criterion of ``success_rate``), and pd_sub_before (N, K) float64 when given.
    """
    out = {"pd_before": np.asarray(arrays["pd_before"], np.float64),
           "pd_after": np.asarray(arrays["pd_after"], np.float64), "success": np.asarray(arrays["success"], bool)}
    if pd_sub_before is not None:
        pd_sub = np.asarray(pd_sub_before, np.float64)
        if pd_sub.ndim != 2 or len(pd_sub) != len(out["pd_before"]):
            raise ValueError(f"per_input_results: pd_sub_before {pd_sub.shape} must be (N, K) with N = "
                             f"{len(out['pd_before'])} inputs")
        out["pd_sub_before"] = pd_sub
    return out


def export_handling(out_dir: Path, arrays: dict, space, labeler, n_examples: int, title: str = "",
                    pd_sub_before: np.ndarray | None = None) -> None:
    """Write the Fig. 6 scatter (``reduction_vs_difference.png``), the per-input arrays (``handling.npz``), the
    detector-only result per input with the inputs' PD per sub-domain (``per_input.npz``,
    :func:`per_input_results`; ``pd_sub_before``: (N, K) or None) and ``n_examples`` handled inputs as OBJ + PNG
    (input, result, and the verified result where escalation replaced it; penetrating vertices in red)."""
    from neuralcol.geometry.mesh_io import write_mesh
    from neuralcol.metrics.plots import depth_colors, render_mesh_png

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out_dir / "handling.npz", **arrays)
    np.savez_compressed(out_dir / "per_input.npz", **per_input_results(arrays, pd_sub_before))
    plot_reduction_vs_difference(arrays, out_dir / "reduction_vs_difference.png", title)
    faces = space.faces.cpu().numpy()
    order = np.flatnonzero(arrays["finite"])[:n_examples]
    for i in order:
        with torch.no_grad():
            pair = space.decode(torch.as_tensor(np.stack([arrays["z_user"][i], arrays["z"][i]]))).double().numpy()
        shown = [("input", pair[0], arrays["pd_before"][i]), ("result", pair[1], arrays["pd_after"][i])]
        if "stage_verified" in arrays and arrays["stage_verified"][i] > 0:
            with torch.no_grad():
                v = space.decode(torch.as_tensor(arrays["z_verified"][i:i + 1])).double().numpy()[0]
            shown.append(("verified", v, arrays["pd_after_verified"][i]))
        for name, verts, pd in shown:
            write_mesh(out_dir / f"example_{i}_{name}.obj", verts, faces)
            # per-vertex depths colour the penetration where the backend gives them (the cpu labeler does;
            # the fcl and gpu backends do not: the mesh is drawn grey, its PD in the title)
            depths = labeler.vertex_depths(verts) if hasattr(labeler, "vertex_depths") else np.zeros(len(verts))
            render_mesh_png(out_dir / f"example_{i}_{name}.png", verts, faces, depth_colors(depths),
                            title=f"{name}: PD = {pd:.3g}")
