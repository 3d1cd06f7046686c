"""The model-size rule: choose the latent space and the detector size of a data set.

The rule, in two steps, each "the smallest that is nearly as good as the best":

1. **Latent space**: of the candidate sizes (``|Z_0|`` = ``n_components`` x ``level2_dim``), the smallest
   ``|Z_all| = n_components * (1 + level2_dim)`` whose autoencoder reconstructs the held-out meshes with a
   mean vertex error within ``recon_tol`` (relative) of the best candidate's. Ties: the smaller error.
2. **Detector**: at that latent space, of the candidate widths (``detector.net.width`` multiplies
   ``state_dim`` and ``hidden``), the one with the fewest parameters whose test accuracy at the labeling budget
   is within ``accuracy_tol`` (absolute) of the best width's. Ties: the higher accuracy.

:func:`choose_latent` and :func:`choose_detector` are the rule on plain records. ``python -m experiments.model_size
search OVERRIDES`` runs the search (autoencoders trained or taken from the cache; one ``supv`` sub-run per width)
and writes a preset of the chosen sizes; ``python -m experiments.model_size SWEEP_DIR`` applies the rule to the
runs of a size sweep (``experiment=size_<dataset>``). Both write ``model_size.json``:
``{"chosen": {"n_components", "level2_dim", "detector_width"}, "rule": {...}, "latent": [...],
"detector": [...]}``.
"""

from __future__ import annotations

import math

import numpy as np
from omegaconf import DictConfig

from neuralcol.active.stopping import kneedle
from neuralcol.errors import UserInputError


def latent_dim(n_components: int, level2_dim: int) -> int:
    """Entries of Z_all: ``n_components * (1 + level2_dim)``."""
    return int(n_components) * (1 + int(level2_dim))


LATENT_RULES = ("tolerance", "knee")


def error_envelope(records: list[dict]) -> list[tuple[int, float, dict]]:
    """The best held-out error reachable with at most ``d`` latent entries, for each candidate size ``d``:
    ``[(d, error, record), ...]`` by increasing ``d``; ``record`` is the smallest candidate reaching ``error``."""
    ok = sorted((r for r in records if r.get("val_error") is not None and math.isfinite(r["val_error"])),
                key=lambda r: (latent_dim(r["n_components"], r["level2_dim"]), r["val_error"]))
    out: list[tuple[int, float, dict]] = []
    for r in ok:
        d = latent_dim(r["n_components"], r["level2_dim"])
        best = out[-1] if out else None
        if best is not None and best[0] == d:
            continue  # sorted by error within one size: the first is that size's best
        if best is None or r["val_error"] < best[1]:
            out.append((d, float(r["val_error"]), r))
        else:
            out.append((d, best[1], best[2]))
    return out


def knee_latent(records: list[dict], sensitivity: float = 1.0) -> dict | None:
    """The knee of the held-out error against the latent size (Kneedle, Satopaa et al. 2011; the ``kneed``
    package), or None if the curve has none.

    The curve is :func:`error_envelope` (the best error reachable with at most d entries) against log2(d): the
    candidate sizes double, and each doubling of the latent space should buy about as much as the last one to be
    worth it. The knee is where the gains start to shrink: the latent space a scene needs. Returns the smallest
    candidate reaching the envelope's error at the knee.
    """
    env = error_envelope(records)
    x = np.log2([d for d, _, _ in env]) if env else np.empty(0)
    knee = kneedle(x, [e for _, e, _ in env], "convex", "decreasing", sensitivity)
    if knee is None:
        return None
    return next(rec for xi, (_, _, rec) in zip(x, env, strict=True) if abs(xi - knee) < 1e-9)


def choose_latent(records: list[dict], recon_tol: float, rule: str = "tolerance") -> dict:
    """The smallest latent space nearly as good as the best.

    Args:
        records: one per candidate, with ``n_components``, ``level2_dim`` and ``val_error`` (mean vertex error of
            the held-out meshes; lower is better).
        recon_tol: relative tolerance: eligible if ``val_error <= (1 + recon_tol) * best``.
        rule: ``tolerance`` (the smallest within ``recon_tol`` of the best) or ``knee`` (the
            knee of the error curve, :func:`knee_latent`; the tolerance rule where the curve has no knee).

    Returns:
        the chosen record.
    """
    if rule not in LATENT_RULES:
        raise ValueError(f"choose_latent: rule={rule!r}, use one of {LATENT_RULES}")
    ok = [r for r in records if r.get("val_error") is not None and math.isfinite(r["val_error"])]
    if not ok:
        raise ValueError("choose_latent: no candidate has a finite held-out reconstruction error")
    if rule == "knee":
        knee = knee_latent(ok)
        if knee is not None:
            return knee
    best = min(r["val_error"] for r in ok)
    eligible = [r for r in ok if r["val_error"] <= (1.0 + recon_tol) * best]
    return min(eligible, key=lambda r: (latent_dim(r["n_components"], r["level2_dim"]), r["val_error"]))


def choose_detector(records: list[dict], accuracy_tol: float) -> dict:
    """The smallest detector nearly as accurate as the best.

    Args:
        records: one per candidate, with ``n_parameters`` and ``accuracy`` (test accuracy at the budget).
        accuracy_tol: absolute tolerance: eligible if ``accuracy >= best - accuracy_tol``.

    Returns:
        the chosen record.
    """
    ok = [r for r in records if r.get("accuracy") is not None and math.isfinite(r["accuracy"])]
    if not ok:
        raise ValueError("choose_detector: no candidate has a finite test accuracy")
    best = max(r["accuracy"] for r in ok)
    eligible = [r for r in ok if r["accuracy"] >= best - accuracy_tol - 1e-12]
    return min(eligible, key=lambda r: (r["n_parameters"], -r["accuracy"]))


def _skill(accuracy: float, majority: float | None) -> float | None:
    """Share of the majority class's errors the detector avoids: ``(acc - maj) / (1 - maj)`` (None if unknown).
    Accuracy alone does not compare across latent spaces: each has its own U(Z) and collision rate."""
    if majority is None or majority >= 1.0:
        return None
    return (accuracy - float(majority)) / (1.0 - float(majority))


def size_record(metrics: dict, name: str) -> dict:
    """The sizes and scores of one finished run (its ``metrics.json``) as a record of the rule."""
    k = int(metrics["latent"]["n_parts"])
    det, last = metrics["detector"], metrics["rounds"][-1]
    h = metrics.get("handling") or {}
    return {"run": name, "n_components": k, "level2_dim": (int(metrics["latent"]["dim"]) - k) // k,
            "latent_dim": int(metrics["latent"]["dim"]),
            "detector_width": float(det.get("net", {}).get("width", 1.0)),
            "val_error": metrics["autoencoder"].get("val_mean_vertex_error"),
            "autoencoder_parameters": metrics["autoencoder"].get("n_parameters"),
            "n_parameters": int(det["n_parameters"]), "accuracy": float(last["accuracy"]),
            "fnr": float(last["fnr"]), "dataset_size": int(last["dataset_size"]),
            "majority_accuracy": last.get("majority_accuracy"),
            "skill": _skill(float(last["accuracy"]), last.get("majority_accuracy")),
            "inference_us": det.get("inference_us"), "handler_success": h.get("success_rate"),
            "handler_seconds_per_mesh": h.get("seconds_per_mesh"),
            "seconds": float(sum(r.get("label_seconds", 0) + r.get("train_seconds", 0) for r in metrics["rounds"]))}


def apply_size_rule(latents: list[dict], records: list[dict], recon_tol: float, accuracy_tol: float,
           latent_rule: str = "tolerance") -> dict:
    """The rule (module docstring) on latent records and detector records (:func:`size_record`; only those at the
    chosen latent space compete): ``model_size.json``'s content."""
    lat = choose_latent(latents, recon_tol, latent_rule)
    knee = knee_latent(latents) if latent_rule == "knee" else None
    same = [r for r in records if (r["n_components"], r["level2_dim"]) == (lat["n_components"], lat["level2_dim"])]
    if not same:
        raise ValueError(f"no detector was trained at the chosen latent space |Z_0| = {lat['n_components']}, "
                         f"level 2 = {lat['level2_dim']}")
    det = choose_detector(same, accuracy_tol)
    best = max(same, key=lambda r: r["accuracy"])  # accuracy compares only within one latent space
    return {"chosen": {"n_components": lat["n_components"], "level2_dim": lat["level2_dim"],
                       "detector_width": det["detector_width"]},
            "chosen_run": det["run"], "chosen_accuracy": det["accuracy"], "chosen_n_parameters": det["n_parameters"],
            "best_run": best["run"], "best_accuracy": best["accuracy"],
            "rule": {"latent_rule": latent_rule, "recon_tol": recon_tol, "accuracy_tol": accuracy_tol,
                     **({"knee_found": knee is not None} if latent_rule == "knee" else {})},
            "latent": sorted(latents, key=lambda r: (latent_dim(r["n_components"], r["level2_dim"]), r["val_error"])),
            "detector": sorted(records, key=lambda r: (r["latent_dim"], r["n_parameters"]))}


def choose_from_records(records: list[dict], recon_tol: float, accuracy_tol: float,
                        latent_rule: str = "tolerance") -> dict:
    """The rule on the runs of a full size sweep (records of :func:`size_record`; runs of one latent space share
    its autoencoder, hence its reconstruction error)."""
    latents = {}
    for r in records:
        latents.setdefault((r["n_components"], r["level2_dim"]), r)
    return apply_size_rule(list(latents.values()), records, recon_tol, accuracy_tol, latent_rule)


def validate_model_size(cfg: DictConfig) -> None:
    """Clear errors for the ``model_size`` settings (called before any work)."""
    ms = cfg.get("model_size")
    if ms is None:
        return
    if ms.mode not in ("fixed", "auto"):
        raise UserInputError(f"model_size.mode={ms.mode!r}: use fixed (the data set's sizes) or auto "
                             "(model_size=auto: search them first)")
    if ms.mode == "fixed":
        return
    for key, low in (("n_components", 1), ("level2_dim", 0)):
        vals = list(ms[key])
        if not vals or any(not isinstance(v, int) or v < low for v in vals):
            raise UserInputError(f"model_size.{key}={vals}: a non-empty list of integers >= {low}")
    widths = list(ms.width)
    if not widths or any(float(w) <= 0 for w in widths):
        raise UserInputError(f"model_size.width={widths}: a non-empty list of multipliers > 0")
    if ms.latent_rule not in LATENT_RULES:
        raise UserInputError(f"model_size.latent_rule={ms.latent_rule!r}: use tolerance (the smallest latent space "
                             "within recon_tol of the best held-out error) or knee (the knee of that error against "
                             "the latent size)")
    for key in ("recon_tol", "accuracy_tol"):
        if float(ms[key]) < 0:
            raise UserInputError(f"model_size.{key}={ms[key]}: must be >= 0")
    if ms.budget is not None and int(ms.budget) < 10:
        raise UserInputError(f"model_size.budget={ms.budget}: labeled samples per detector candidate, >= 10 "
                             "(null: the run's final |D_c|)")
