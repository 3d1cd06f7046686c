"""TensorBoard as a researcher reads it: the scalars and pictures a run logs besides its trainings' own.

One TensorBoard run per stage under ``<run dir>/tensorboard/`` (:func:`~neuralcol.metrics.tensorboard.stage_logger`):
``data`` (the sub-domains mesh), ``detector_<method>`` (after the training's own curves: the realistic set's and the
cascade's scalars at the final |D_c|), ``handling`` (the handler's results) and ``latent`` (the latent space beside
its PCA references). :class:`experiments.reporting.run_report.RunReport` calls these at the end of a run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from neuralcol.metrics.plots import partition_colors
from neuralcol.metrics.tensorboard import stage_logger


def log_subdomains(run_dir: Path, rest: np.ndarray, faces: np.ndarray, partition: np.ndarray) -> None:
    """The rest mesh (V, 3) coloured by sub-domain (``partition`` (V,)) as the mesh ``subdomains`` of run ``data``."""
    colors = (partition_colors(partition)[:, :3] * 255).astype("uint8")
    logger = stage_logger(run_dir, "data")
    logger.experiment.add_mesh("subdomains", vertices=torch.as_tensor(rest[None]).float(),
                               colors=torch.as_tensor(colors[None]), faces=torch.as_tensor(faces[None]))
    logger.finalize("success")


def log_handling(run_dir: Path, h: dict, step: int) -> None:
    """The handler's rates and distances (``metrics["handling"]``) under ``handling/`` at ``step`` (the final
    |D_c|), run ``handling``."""
    logger = stage_logger(run_dir, "handling")
    for key in ("success_rate", "resolved_rate", "mean_pd_reduction", "mean_embedding_diff"):
        logger.experiment.add_scalar(f"handling/{key}", h[key], global_step=step)
    logger.finalize("success")


def log_latent(run_dir: Path, metrics: dict) -> None:
    """TensorBoard scalars of the latent space next to its PCA references (run ``latent``, step 0)."""
    ae, la = metrics["autoencoder"], metrics["latent"]
    scalars = {"latent/train_error": ae["train_mean_vertex_error"], "latent/val_error": ae["val_mean_vertex_error"],
               "latent/uz_collision_share": la["uniform_collision_fraction"]}
    for name, ref in (ae.get("references") or {}).items():
        scalars[f"latent/{name}_train_error"] = ref.get("train_mean_vertex_error")
        scalars[f"latent/{name}_val_error"] = ref.get("val_mean_vertex_error")
    for name, p in ((la.get("box_probe") or {}).get("references") or {}).items():
        scalars[f"latent/{name}_box_collision_share"] = p.get("collision_share")
    rt = ((metrics.get("realistic") or {}).get("round_trip") or {})
    scalars["latent/round_trip_agreement"] = rt.get("agreement")
    for name, agree in (rt.get("references") or {}).items():
        scalars[f"latent/{name}_round_trip_agreement"] = agree.get("agreement")
    logger = stage_logger(run_dir, "latent")
    for k, v in scalars.items():
        if v is not None and np.isfinite(v):
            logger.experiment.add_scalar(k, float(v), global_step=0)
    logger.finalize("success")


def log_realistic(logger, m: dict, step: int, render_dir=None) -> None:
    """TensorBoard scalars of the realistic set under ``realistic/`` (at the final |D_c|), and resolve's
    before/after pictures (``realistic/resolve_<kind>``) from ``render_dir``."""
    scalars = {f"realistic/{k}": m["detection"].get(k) for k in ("accuracy", "fnr", "fpr", "skill")}
    scalars["realistic/round_trip_agreement"] = m["round_trip"]["agreement"]
    scalars["realistic/out_of_box"] = m["round_trip"]["out_of_box"]
    h = m.get("handling")
    if h:
        scalars.update({"realistic/handler_resolved_detector_only": h["detector_only"]["resolved_rate"],
                        "realistic/handler_resolved_verified": h["verified"]["resolved_rate"],
                        "realistic/handler_resolved_repair_only": (h.get("repair_only") or {}).get("resolved_rate"),
                        "realistic/handler_displacement_median_frac": h["displacement_median_frac"]})
    for k, v in scalars.items():
        if v is not None and np.isfinite(v):
            logger.experiment.add_scalar(k, float(v), global_step=step)
    if h and render_dir is not None:
        import matplotlib.image as mpimg

        for kind, name in (h.get("renders") or {}).items():
            img = mpimg.imread(Path(render_dir) / name)[..., :3]
            logger.experiment.add_image(f"realistic/resolve_{kind.replace(' ', '_')}", img, global_step=step,
                                        dataformats="HWC")


def log_cascade(logger, m: dict, step: int) -> None:
    """TensorBoard scalars under ``cascade/`` (at the final |D_c|): per target FNR, the test and realistic FNR,
    accuracy and exact share, and the speed-up over the exact labeler alone."""
    for t in m["targets"]:
        tag = f"cascade/fnr_{t['target_fnr']:g}"
        scalars = {f"{tag}/{where}_{k}": (t[where] or {}).get(k) for where in ("test", "realistic")
                   for k in ("fnr", "accuracy", "exact_share")}
        scalars[f"{tag}/speedup_vs_exact"] = t["speedup_vs_exact"]
        scalars[f"{tag}/samples_per_s"] = t["samples_per_s"]
        for k, v in scalars.items():
            if v is not None and np.isfinite(v):
                logger.experiment.add_scalar(k, float(v), global_step=step)
