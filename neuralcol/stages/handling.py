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
from pathlib import Path

import numpy as np
import torch

from neuralcol.active.oracle import LatentOracle
from neuralcol.handling.alm import ALMSettings, Resolution, alm_resolve
from neuralcol.handling.objectives import LatentObjective
from neuralcol.utils.config import as_dict


def alm_settings(cfg) -> ALMSettings:
    return ALMSettings(**as_dict(cfg))


def handle_codes(net: torch.nn.Module, z_user: torch.Tensor, box_lo: torch.Tensor, box_hi: torch.Tensor,
                 settings: ALMSettings, objective=None, batch_size: int = 256) -> Resolution:
    """Run the handler over many codes in batches (on the detector's device); results on the CPU.

    Args:
        net: the detector (its ``logit`` is the constraint).
        z_user: (N, D) codes to resolve.
        box_lo, box_hi: (D,) the latent box.
        settings: ALM settings.
        objective: ``(z, idx) -> (len(idx),)`` over the N problems; default ``|Z - Z_user|^2 / 2``.
        batch_size: problems solved together.
    """
    dev = next(net.parameters()).device
    net = net.eval()
    objective = objective or LatentObjective(z_user.to(dev))
    parts = []
    for start in range(0, len(z_user), batch_size):
        rows = torch.arange(start, min(start + batch_size, len(z_user)), device=dev)
        res = alm_resolve(lambda z, idx, rows=rows: objective(z, rows[idx]), lambda z: net(z).logit,
                          z_user[rows.cpu()].to(dev), box_lo.to(dev), box_hi.to(dev), settings)
        parts.append(Resolution(*(t.detach().cpu() for t in res)))
    if not parts:
        empty = torch.zeros(0)
        return Resolution(torch.zeros(0, z_user.shape[1]), *(empty.bool(),) * 3, empty.long(), empty, empty)
    return Resolution(*(torch.cat([getattr(p, f) for p in parts]) for f in Resolution._fields))


def evaluate_handler(net: torch.nn.Module, oracle: LatentOracle, z_user: torch.Tensor, pd_before: np.ndarray,
                     settings: ALMSettings, batch_size: int = 256) -> tuple[dict, dict]:
    """Handle ``z_user`` (all self-penetrating, PD ``pd_before`` > 0) and label the results exactly.

    Returns:
        (metrics dict, per-input arrays: z, pd_before, pd_after, reduction, embedding_diff, success, ...)
    """
    pd_before = np.asarray(pd_before, np.float64)
    if (pd_before <= 0).any():
        raise ValueError("evaluate_handler: every input must self-penetrate (PD > 0)")
    space = oracle.space
    t0 = time.perf_counter()
    res = handle_codes(net, z_user, space.box_lo, space.box_hi, settings, batch_size=batch_size)
    seconds = time.perf_counter() - t0
    finite = res.finite.numpy()
    pd_after = np.full(len(z_user), np.nan)
    lab = oracle(res.z[res.finite], desc="labeling handled codes")
    pd_after[finite] = lab.pd
    reduction = (pd_before - np.maximum(pd_after, 0.0)) / pd_before  # NaN where non-finite
    diff = (res.z - z_user.cpu()).norm(dim=-1).numpy().astype(np.float64)
    success = np.nan_to_num(reduction, nan=-np.inf) > 0
    resolved = np.nan_to_num(pd_after, nan=np.inf) <= 0
    n = len(z_user)
    metrics = {
        "n": n,
        "success_rate": float(success.mean()) if n else float("nan"),
        "resolved_rate": float(resolved.mean()) if n else float("nan"),
        "mean_pd_reduction": float(reduction[success].mean()) if success.any() else float("nan"),
        "mean_embedding_diff": float(diff[success].mean()) if success.any() else float("nan"),
        "mean_pd_reduction_all": float(np.nanmean(reduction)) if finite.any() else float("nan"),
        "mean_embedding_diff_all": float(diff[finite].mean()) if finite.any() else float("nan"),
        "seconds_per_mesh": seconds / max(n, 1),
        "label_seconds": lab.seconds,
        "n_nonfinite": int((~finite).sum()),
        "n_detector_infeasible": int((finite & ~res.feasible.numpy()).sum()),
        "n_not_converged": int((finite & ~res.converged.numpy()).sum()),
        "mean_outer_iterations": float(res.outer.float().mean()) if n else float("nan"),
        "settings": settings.__dict__,
    }
    arrays = {"z_user": z_user.cpu().numpy(), "z": res.z.numpy(), "pd_before": pd_before, "pd_after": pd_after,
              "reduction": reduction, "embedding_diff": diff, "success": success, "resolved": resolved,
              "detector_feasible": res.feasible.numpy(), "finite": finite}
    return metrics, arrays


def plot_reduction_vs_difference(arrays: dict, path: Path, title: str = "") -> Path:
    """Paper Fig. 6: relative PD reduction vs embedding difference of the successfully handled inputs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = arrays["success"]
    fig, ax = plt.subplots(figsize=(5, 3.8))
    ax.scatter(arrays["embedding_diff"][ok], arrays["reduction"][ok], s=6, alpha=0.5,
               label=f"successful ({int(ok.sum())} of {len(ok)})")
    ax.set_xlabel("embedding difference |Z - Z_user|")
    ax.set_ylabel("relative PD reduction")
    ax.set_ylim(min(0.0, float(np.nanmin(arrays["reduction"][ok])) if ok.any() else 0.0), 1.05)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def export_handling(out_dir: Path, arrays: dict, space, labeler, n_examples: int, title: str = "") -> None:
    """Write the Fig. 6 scatter (``reduction_vs_difference.png``), the per-input arrays (``handling.npz``) and
    ``n_examples`` handled inputs as OBJ + PNG (input and result, penetrating vertices in red)."""
    from neuralcol.geometry.mesh_io import write_mesh
    from neuralcol.metrics.plots import depth_colors, render_mesh_png

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out_dir / "handling.npz", **arrays)
    plot_reduction_vs_difference(arrays, out_dir / "reduction_vs_difference.png", title)
    faces = space.faces.cpu().numpy()
    order = np.flatnonzero(arrays["finite"])[:n_examples]
    for i in order:
        with torch.no_grad():
            pair = space.decode(torch.as_tensor(np.stack([arrays["z_user"][i], arrays["z"][i]]))).double().numpy()
        for name, verts, pd in (("input", pair[0], arrays["pd_before"][i]), ("result", pair[1], arrays["pd_after"][i])):
            write_mesh(out_dir / f"example_{i}_{name}.obj", verts, faces)
            render_mesh_png(out_dir / f"example_{i}_{name}.png", verts, faces,
                            depth_colors(labeler.vertex_depths(verts)), title=f"{name}: PD = {pd:.3g}")
