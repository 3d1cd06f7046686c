"""Learning curves of the detector next to non-neural references on the same rows (docs/diagnosis.md).

Is the detector data-limited (every model keeps improving with more rows), model-limited (a reference or a
wider detector does better on the same rows) or latent-limited (everything stays near the majority class:
the label is rough in the latent coordinates)? :func:`learning_curve` answers it on the first n rows of a
seed's pool of labeled uniform samples, for several n, scored on the shared test set.

The detector is trained by :func:`fit_detector`, a plain-torch loop equal to one ``supv``/``supv_bd`` round
of the pipeline (:class:`~neuralcol.lit.detector.DetectorLitModule` under the rounds callback): the same
losses, Adam, batch size and epochs, the 80/20 split by row id (``id % 5 == 4`` validates) and the weights of
the epoch with the best validation accuracy.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np
import torch

from neuralcol.metrics.detection import detection_metrics
from neuralcol.nn.detector import CollisionDetector, detector_losses
from neuralcol.samples.datamodule import detector_targets
from neuralcol.samples.store import VAL_EVERY, CollisionRows

LR_SCHEDULES = ("constant", "cosine")


def epoch_lr(base_lr: float, epoch: int, epochs: int, schedule: str = "constant") -> float:
    """Learning rate of epoch ``epoch`` (0-based) of a training run of ``epochs`` epochs.

    ``constant``: ``base_lr`` throughout (the paper's). ``cosine``: ``base_lr * (1 + cos(pi * epoch / epochs)) / 2``,
    from ``base_lr`` at epoch 0 down to nearly 0 at the last epoch (never exactly 0, so no epoch is wasted).
    """
    if schedule not in LR_SCHEDULES:
        raise ValueError(f"lr schedule {schedule!r}: expected one of {LR_SCHEDULES}")
    if schedule == "constant" or epochs <= 1:
        return float(base_lr)
    e = min(max(int(epoch), 0), int(epochs) - 1)
    return float(base_lr) * 0.5 * (1.0 + math.cos(math.pi * e / int(epochs)))


def take_rows(rows: CollisionRows, n: int) -> CollisionRows:
    """The first ``n`` rows."""
    return rows._replace(**{f: getattr(rows, f)[:n] for f in rows._fields})


def fit_detector(net: CollisionDetector, rows: CollisionRows, pd_unit: float, loss: dict, w_b: float,
                 use_boundary_set: bool, pd_clip: float, pd_floor: float | None, epochs: int, lr: float,
                 batch_size: int, seed: int, lr_schedule: str = "constant", patience: int | None = None,
                 ema_epochs: float | None = None) -> dict:
    """Train ``net`` on ``rows`` (80/20 by row position, as D_c) and keep the best-validation epoch.

    Args:
        net: a fresh detector (trained in place).
        rows: labeled rows (z, pd, pd_sub, subset, collides).
        pd_unit, pd_clip, pd_floor: PD target scaling (:func:`~neuralcol.samples.datamodule.detector_targets`).
        loss: ``w_pd, w_pdsum, w_r, w_ce, margin, temperature`` (``conf/detector/*.yaml`` -> ``loss``).
        w_b: weight of L_b (0 for ``supv``).
        use_boundary_set: keep D_b (``supv_bd``) or fold it into D_p (``supv``).
        epochs, lr, batch_size: Adam schedule.
        lr_schedule: ``constant`` or ``cosine`` over the epochs (:func:`epoch_lr`).
        patience: stop once this many epochs passed without a better validation accuracy (None: all epochs).
        ema_epochs: validate, select and keep an exponential moving average of the weights (``torch.optim.swa_utils``)
            whose horizon is this many epochs (per-step decay ``1 - 1 / (ema_epochs * steps per epoch)``);
            None: the raw weights.
        seed: initialisation is the caller's; this seeds the shuffling.

    Returns:
        ``train_accuracy``, ``val_accuracy``, ``epoch`` (selected), ``epochs_run``, ``seconds``; the net holds the
        selected weights (the averaged ones with ``ema_epochs``).
    """
    z, pd, pd_sub, subset = detector_targets(rows, pd_unit, pd_clip, use_boundary_set, pd_floor)
    epochs_run = 0
    val = torch.as_tensor(np.arange(len(z)) % VAL_EVERY == VAL_EVERY - 1)
    tr = torch.nonzero(~val).flatten()
    kw = {k: float(loss[k]) for k in ("w_pd", "w_pdsum", "w_r", "w_ce", "margin", "temperature")}
    kw["ce_on_boundary"] = bool(loss.get("ce_on_boundary", False))
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    gen = torch.Generator().manual_seed(int(seed))
    best = (-1.0, -1, None, float("nan"))
    ema = None
    if ema_epochs:
        steps = max(1, -(-len(tr) // int(batch_size)))
        decay = 1.0 - 1.0 / (float(ema_epochs) * steps)
        ema = torch.optim.swa_utils.AveragedModel(net, multi_avg_fn=torch.optim.swa_utils.get_ema_multi_avg_fn(decay))
    model = net if ema is None else ema.module
    t0 = time.perf_counter()
    for epoch in range(int(epochs)):
        for group in opt.param_groups:
            group["lr"] = epoch_lr(lr, epoch, int(epochs), lr_schedule)
        net.train()
        for b in tr[torch.randperm(len(tr), generator=gen)].split(int(batch_size)):
            out = net(z[b])
            total = detector_losses(out, pd[b], pd_sub[b], subset[b], w_b=w_b, **kw).total
            opt.zero_grad()
            total.backward()
            opt.step()
            if ema is not None:
                ema.update_parameters(net)
        model.eval()
        with torch.no_grad():
            acc = float(((model(z[val]).logit > 0) == (pd[val] > 0)).float().mean()) if val.any() else 0.0
            if acc > best[0]:
                tr_acc = float(((model(z[tr]).logit > 0) == (pd[tr] > 0)).float().mean())
                best = (acc, epoch, {k: v.clone() for k, v in model.state_dict().items()}, tr_acc)
        epochs_run = epoch + 1
        if patience is not None and epoch - best[1] >= int(patience):
            break
    net.load_state_dict(best[2])
    return {"val_accuracy": best[0], "epoch": best[1], "train_accuracy": best[3], "epochs_run": epochs_run,
            "seconds": time.perf_counter() - t0}


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
            ``pd_floor``; of ``det["loss"]``; ``lr_schedule``, ``epochs``, ``patience``, ``ema_epochs``; and ``w_b``,
            ``use_boundary_set``).
        build: ``net_config (dict) -> CollisionDetector`` (fresh, seeded by the caller's torch seed).
        pd_unit: the labeler's clearance cap.
        det: the detector config (``conf/detector/*.yaml``) with ``epochs``, ``lr``, ``batch_size`` (and optionally
            ``lr_schedule``, default constant, ``patience`` and ``ema_epochs``, default none).
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
            targets = {**det["targets"], **{k: over[k] for k in ("pd_clip", "pd_floor") if k in over}}
            loss = {**det["loss"], **over.get("loss", {})}
            for seed in seeds:
                torch.manual_seed(int(seed))
                net = build(net_cfg)
                fit = fit_detector(net, sub, pd_unit, loss, float(over.get("w_b", 0.0)),
                                   bool(over.get("use_boundary_set", False)), float(targets["pd_clip"]),
                                   targets.get("pd_floor"), int(over.get("epochs", det["epochs"])),
                                   float(det["lr"]), int(det["batch_size"]), int(seed),
                                   str(over.get("lr_schedule", det.get("lr_schedule", "constant"))),
                                   over.get("patience", det.get("patience")),
                                   over.get("ema_epochs", det.get("ema_epochs")))
                rec = {"size": int(n), "model": var["name"], "seed": int(seed), **fit, "test": test_metrics(net, test),
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
