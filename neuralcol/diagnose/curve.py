"""Learning curves of the detector next to non-neural references on the same rows (docs/diagnosis.md).

Is the detector data-limited (every model keeps improving with more rows), model-limited (a reference or a
wider detector does better on the same rows) or latent-limited (everything stays near the majority class:
the label is rough in the latent coordinates)? :func:`learning_curve` answers it on the first n rows of a
seed's pool of labeled uniform samples, for several n, scored on the shared test set.

The detector is trained by :func:`fit_rows`: one ``supv``/``supv_bd`` bootstrap round of the pipeline's own
training (D_c datamodule, :class:`~neuralcol.lit.detector.DetectorLitModule`, the round callback and the Trainer,
built from the detector config): the same losses, optimizer, batch size and epochs, the 80/20 split by row id
(``id % 5 == 4`` validates) and the weights of the epoch with the best validation accuracy.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from neuralcol.active.rounds import Schedule
from neuralcol.lit.detector import detector_module
from neuralcol.metrics.detection import detection_metrics
from neuralcol.nn.detector import CollisionDetector
from neuralcol.samples.datamodule import CollisionDataModule, detector_targets
from neuralcol.samples.store import CollisionRows, Origin


def take_rows(rows: CollisionRows, n: int) -> CollisionRows:
    """The first ``n`` rows."""
    return rows.select(slice(0, n))


def fit_rows(net: CollisionDetector, rows: CollisionRows, test: CollisionRows, pd_unit: float, det: dict,
             w_b: float, use_boundary_set: bool, seed: int) -> dict:
    """Train ``net`` on ``rows`` as one bootstrap round of the pipeline's own training: its D_c datamodule (80/20
    by row position), LightningModule, round callback (best-validation epoch kept) and Trainer, all built from
    the detector config ``det`` (``conf/detector``), with ``det``'s ``epochs``, ``lr`` and ``batch_size``.

    Returns:
        ``train_accuracy``, ``val_accuracy``, ``epoch`` (selected, 0-based), ``epochs_run``, ``seconds``, and
        ``test`` (detection metrics on ``test``); the net holds the selected weights.
    """
    from hydra.utils import instantiate

    t0 = time.perf_counter()
    sched = Schedule(int(det["epochs"]), float(det["lr"]), int(det["batch_size"]))
    targets = det["targets"]
    with tempfile.TemporaryDirectory(prefix="neuralcol_curve_") as tmp:
        dm = CollisionDataModule(Path(tmp) / "rows.h5", rows.z.shape[1], rows.pd_sub.shape[1], sched.batch_size,
                                 pd_unit, float(targets["pd_clip"]), use_boundary_set=use_boundary_set, seed=seed,
                                 pd_floor=targets.get("pd_floor"))
        dm.append(rows.z, rows.pd, rows.pd_sub, rows.collides, rows.subset, 0, Origin.UNIFORM)
        module = detector_module(net, det, w_b, sched.lr)
        rounds = instantiate(det["rounds"], max_rounds=0, stop_at_elbow=False, select_best_val=True)(
            datamodule=dm, acquire=None, evaluate=lambda m: test_metrics(m.net, test), bootstrap=sched,
            update=sched, checkpoint_path=Path(tmp) / "rows.ckpt", seed=seed)
        trainer = instantiate(det["trainer"], enable_progress_bar=False)(max_epochs=rounds.max_epochs, logger=False,
                                                                         callbacks=[rounds])
        trainer.fit(module, datamodule=dm)
        rec = rounds.rounds[0]
        z, pd, _, _ = detector_targets(rows, pd_unit, float(targets["pd_clip"]), use_boundary_set,
                                       targets.get("pd_floor"))
        train = torch.as_tensor(~dm.store.split_mask())
        dm.close()
    net = module.net.cpu().eval()
    with torch.no_grad():
        train_acc = float(((net(z[train]).logit > 0) == (pd[train] > 0)).float().mean())
    return {"val_accuracy": rec["val_accuracy"], "epoch": rec["selected_epoch"], "train_accuracy": train_acc,
            "epochs_run": rec["epochs"], "seconds": time.perf_counter() - t0,
            "test": {k: rec[k] for k in detection_metrics(np.zeros(1, bool), np.zeros(1, bool))}}


def test_metrics(net: CollisionDetector, test: CollisionRows) -> dict:
    """Detection metrics of ``net`` on the test rows."""
    net.eval()
    with torch.no_grad():
        logit = torch.cat([net(c).logit for c in torch.as_tensor(test.z).split(65536)])
    return detection_metrics(logit.numpy() > 0, np.asarray(test.collides, bool))


def box_scaled(z: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray) -> np.ndarray:
    """(B, D) codes -> the box mapped to [-1, 1] (the references' inputs)."""
    return (np.asarray(z, np.float64) - box_lo) / (box_hi - box_lo) * 2 - 1


def reference_scores(rows: CollisionRows, test: CollisionRows, box_lo: np.ndarray, box_hi: np.ndarray,
                     knn_k: int = 15, seed: int = 0) -> dict:
    """Test accuracy of scikit-learn's HistGradientBoosting and k-nearest-neighbours on the same rows.

    Inputs are the box-normalised codes; both train on every row (HGB holds out 10 % for early stopping).
    """
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.neighbors import KNeighborsClassifier

    x, xt = box_scaled(rows.z, box_lo, box_hi), box_scaled(test.z, box_lo, box_hi)
    y, yt = np.asarray(rows.collides, bool), np.asarray(test.collides, bool)
    t0 = time.perf_counter()
    hgb = HistGradientBoostingClassifier(max_iter=500, early_stopping=True, random_state=seed).fit(x, y)
    t_hgb = time.perf_counter() - t0
    knn = KNeighborsClassifier(n_neighbors=min(knn_k, len(x))).fit(x, y)
    return {"hgb": detection_metrics(hgb.predict(xt), yt), "knn": detection_metrics(knn.predict(xt), yt),
            "hgb_seconds": t_hgb}


def learning_curve(rows: CollisionRows, test: CollisionRows, sizes: Sequence[int], variants: Sequence[dict],
                   build, pd_unit: float, det: dict, seeds: Sequence[int], box_lo: np.ndarray,
                   box_hi: np.ndarray, references: bool = True, log=print) -> list[dict]:
    """Train every detector variant and the references on the first n rows for each n in ``sizes``.

    Args:
        rows: a pool of labeled uniform rows (at least ``max(sizes)``).
        test: the test rows.
        sizes: row counts.
        variants: ``{"name": ..., **overrides}``; overrides of the detector config ``det`` (keys of
            ``det["net"]``: ``state_dim``, ``hidden``, ``decoder_features``, and ``width_factor`` scaling both
            widths; of ``det["targets"]``: ``pd_clip``,
            ``pd_floor``; of ``det["loss"]``; ``epochs``; and ``w_b``,
            ``use_boundary_set``).
        build: ``net_config (dict) -> CollisionDetector`` (fresh, seeded by the caller's torch seed).
        pd_unit: the labeler's clearance cap.
        det: the detector config (``conf/detector/*.yaml``): ``epochs``, ``lr``, ``batch_size``, ``loss``,
            ``targets`` and the components it builds (``optimizer``, ``rounds``, ``trainer``).
        seeds: training seeds.
        box_lo, box_hi: (D,) the latent box (inputs of the references).
        references: also score HistGradientBoosting and kNN.
        log: progress printer.

    Returns:
        One record per (size, variant, seed): ``size``, ``model``, ``seed``, ``train_accuracy``,
        ``val_accuracy``, ``test`` (detection metrics), ``seconds``, ``n_parameters``.
    """
    if len(rows.z) < max(sizes):
        raise ValueError(f"the pool has {len(rows.z)} rows; the curve asks for {max(sizes)}")
    out = []
    for n in sizes:
        sub = take_rows(rows, int(n))
        if references:
            ref = reference_scores(sub, test, box_lo, box_hi)
            for name in ("hgb", "knn"):
                out.append({"size": int(n), "model": name, "seed": 0, "test": ref[name]})
            log(f"  n={n}: HGB {ref['hgb']['accuracy']:.4f}, kNN {ref['knn']['accuracy']:.4f}")
        for var in variants:
            over = {k: v for k, v in var.items() if k != "name"}
            net_cfg = {**det["net"], **{k: over[k] for k in ("state_dim", "hidden", "decoder_features") if k in over}}
            if "width_factor" in over:
                f = float(over["width_factor"])
                net_cfg["state_dim"], net_cfg["hidden"] = (max(1, round(f * int(net_cfg[k])))
                                                           for k in ("state_dim", "hidden"))
            det_v = {**det, "targets": {**det["targets"], **{k: over[k] for k in ("pd_clip", "pd_floor") if k in over}},
                     "loss": {**det["loss"], **over.get("loss", {})}, "epochs": int(over.get("epochs", det["epochs"]))}
            for seed in seeds:
                torch.manual_seed(int(seed))
                net = build(net_cfg)
                fit = fit_rows(net, sub, test, pd_unit, det_v, float(over.get("w_b", 0.0)),
                               bool(over.get("use_boundary_set", False)), int(seed))
                rec = {"size": int(n), "model": var["name"], "seed": int(seed), **fit,
                       "n_parameters": int(sum(p.numel() for p in net.parameters()))}
                out.append(rec)
                log(f"  n={n}: {var['name']} seed {seed}: train {fit['train_accuracy']:.4f}, val "
                    f"{fit['val_accuracy']:.4f}, test {rec['test']['accuracy']:.4f} (FNR {rec['test']['fnr']:.3f}), "
                    f"epoch {fit['epoch']} of {fit['epochs_run']}, {fit['seconds']:.0f} s")
    return out


def needed_size(sizes: Sequence[float], accuracy: Sequence[float], target: float) -> float:
    """Rows needed to reach ``target`` by extrapolating ``accuracy = a + b log2(size)`` (least squares).

    Returns the smallest measured size that reaches it; ``nan`` with fewer than 3 sizes (too few to fit a
    trend); ``inf`` when the fitted slope is not positive or the answer lies beyond ``1000 x`` the largest
    measured size (no trend carries that far).
    """
    s, a = np.asarray(sizes, np.float64), np.asarray(accuracy, np.float64)
    reached = s[a >= target]
    if len(reached):
        return float(reached.min())
    if len(np.unique(s)) < 3:
        return float("nan")
    b, a0 = np.polyfit(np.log2(s), a, 1)
    if b <= 0:
        return float("inf")
    n = float(2 ** ((target - a0) / b))
    return n if n <= 1000 * s.max() else float("inf")
