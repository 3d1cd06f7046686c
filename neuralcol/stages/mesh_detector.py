"""Stage: train the detector that reads the mesh (issue 27) after the latent detector.

Training rows: the run's D_c codes, decoded (the meshes the exact labeler judged), and realistic training
meshes built like the realistic evaluation set but from the autoencoder's *training* meshes only
(``mesh_detector.train_set``; cached as ``realistic_train_<hash>.npz`` beside the U(Z) test set). The contact
pairs are chosen on a stride of the decoded D_c meshes plus the realistic training meshes; the features of
every row are computed once, then an MLP is fit with cross-entropy (a thin LightningModule). Writes
``mesh_detector.pt`` (tensors and plain values only: it loads with ``weights_only=True``).
"""

from __future__ import annotations

import time
from pathlib import Path

import lightning as L
import numpy as np
import torch
from hydra.utils import instantiate
from torch.utils.data import DataLoader, TensorDataset

from neuralcol.geometry.contact_pairs import ContactFeatures, select_contact_pairs
from neuralcol.lit.mesh_detector import MeshDetectorLitModule
from neuralcol.metrics.detection import detection_metrics
from neuralcol.nn.mesh_detector import (
    MeshDetector,
    code_logits,
    decoded_batches,
    mesh_features,
    mesh_logits_from_features,
    save_mesh_detector,
)
from neuralcol.utils.config import as_dict
from neuralcol.utils.progress import trainer_progress


def train_mesh_detector(space, dc_z: np.ndarray, dc_collides: np.ndarray, real_vertices: np.ndarray,
                        real_collides: np.ndarray, cfg, seed: int, run_dir: str | Path, logger=None,
                        progress: bool = False) -> tuple[MeshDetector, dict]:
    """Choose the contact pairs, compute every row's features, fit the MLP, save ``mesh_detector.pt``.

    Args:
        space: the latent space (decoder, faces, rest mesh).
        dc_z, dc_collides: D_c's codes (N, D) and exact labels (N,).
        real_vertices, real_collides: realistic training meshes (M, V, 3) and their exact labels (M,).
        cfg: the ``mesh_detector`` config.
        seed: seeds the split and the training.
        run_dir: where ``mesh_detector.pt`` goes.
        logger: a Lightning logger (TensorBoard) or None.

    Returns:
        (the trained detector (eval mode), report).
    """
    c = as_dict(cfg)
    pc, tc = c["pairs"], c["train"]
    t0 = time.perf_counter()
    rest = space.rest_vertices.cpu().numpy()
    faces = space.faces.cpu().numpy()
    diag = float(np.linalg.norm(np.ptp(rest, axis=0)))
    radius = float(pc["radius"]) * diag
    stride = max(1, int(pc["select_stride"]))
    dc_z = np.asarray(dc_z, np.float32)
    dc_collides = np.asarray(dc_collides, bool)
    # decoded once (float32), kept for the features (SCAPE's 38 000 rows: ~1 GB)
    dc_v = torch.cat(list(decoded_batches(space, dc_z))).numpy() if len(dc_z) else np.zeros((0, len(rest), 3),
                                                                                             np.float32)
    t_decode = time.perf_counter() - t0
    sel_v = np.concatenate([dc_v[::stride], np.asarray(real_vertices, np.float32)])
    sel_y = np.concatenate([dc_collides[::stride], np.asarray(real_collides, bool)])
    pairs = select_contact_pairs(sel_v, sel_y, faces, radius, int(pc["min_hops"]), int(pc["n_pairs"]),
                                 float(pc["colliding_weight"]), pc.get("max_per_vertex"))
    del sel_v
    if len(pairs) == 0:
        raise ValueError(f"no vertex pair at least {pc['min_hops']} edges apart comes within "
                         f"mesh_detector.pairs.radius={pc['radius']} of the diagonal in the examples; raise it")
    t_pairs = time.perf_counter() - t0 - t_decode
    feats = ContactFeatures(pairs, faces, radius, float(pc["clip"]))
    x = np.concatenate([mesh_features(feats, dc_v), mesh_features(feats, real_vertices)])
    del dc_v
    y = np.concatenate([dc_collides, np.asarray(real_collides, bool)])
    t_feats = time.perf_counter() - t0 - t_pairs - t_decode
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(y))
    n_val = int(round(float(tc["val_fraction"]) * len(y)))
    val, train = order[:n_val], order[n_val:]
    L.seed_everything(seed, workers=False, verbose=False)
    net = MeshDetector(feats, hidden=int(c["net"]["hidden"]))
    module = MeshDetectorLitModule(net, optimizer=instantiate(tc["optimizer"]))
    xt, yt = torch.as_tensor(x), torch.as_tensor(y)
    g = torch.Generator().manual_seed(seed)
    train_dl = DataLoader(TensorDataset(xt[train], yt[train]), batch_size=int(tc["batch_size"]), shuffle=True,
                          generator=g)
    val_dl = DataLoader(TensorDataset(xt[val], yt[val]), batch_size=4096) if n_val else None
    steps_per_epoch = max(1, -(-len(train) // int(tc["batch_size"])))
    epochs = max(1, min(int(tc["epochs"]), -(-int(tc["max_steps"]) // steps_per_epoch)))
    trainer = L.Trainer(max_epochs=epochs, logger=logger if logger is not None else False,
                        enable_checkpointing=False, enable_model_summary=False,
                        num_sanity_val_steps=0, accelerator="cpu", devices=1,
                        log_every_n_steps=min(10, steps_per_epoch), **trainer_progress(progress, "mesh detector"))
    t1 = time.perf_counter()
    trainer.fit(module, train_dataloaders=train_dl, val_dataloaders=val_dl)
    net = module.net.cpu().eval()
    t_train = time.perf_counter() - t1
    val_metrics = detection_metrics(mesh_logits_from_features(net, x[val]) > 0, y[val]) if n_val else None
    save_mesh_detector(Path(run_dir) / "mesh_detector.pt", net)
    report = {"n_rows": int(len(y)), "n_dc": int(len(dc_z)), "n_realistic": int(len(real_collides)),
              "n_pairs": int(len(pairs)), "radius": radius,
              "n_parameters": int(sum(p.numel() for p in net.mlp.parameters())),
              "epochs": epochs, "val": val_metrics, "decode_seconds": t_decode,
              "pairs_seconds": t_pairs, "features_seconds": t_feats, "train_seconds": t_train,
              "seconds": time.perf_counter() - t0}
    return net, report


def mesh_detector_stage(space, vertices: np.ndarray, features: np.ndarray, acap, train_index, pool, cfg,
                        samples_dir: str | Path, eps: float, dc_path: str | Path, seed: int, run_dir: str | Path,
                        test=None, logger=None) -> tuple[MeshDetector, dict]:
    """Build the realistic training meshes (cached), train the mesh detector on them and the decoded D_c, and
    measure it on the U(Z) test rows ``test`` (their decoded meshes) if given.

    Args:
        space: the latent space. vertices, features, acap: the data set's meshes, raw ACAP features, transform.
        train_index: the autoencoder's training meshes (the only sources of realistic training meshes).
        pool: label pool. cfg: the ``mesh_detector`` config. samples_dir: the latent space's samples cache.
        eps: the labeler's boundary width. dc_path: the run's ``dc.h5``. seed: the run's seed.
        run_dir: where ``mesh_detector.pt`` goes. test: U(Z) test rows (``z``, ``collides``) or None.
        logger: Lightning logger or None.
    """
    from neuralcol.samples.store import CollisionStore
    from neuralcol.stages.realistic import realistic_set

    t0 = time.perf_counter()
    c = as_dict(cfg)
    idx = np.asarray(train_index, dtype=np.int64)
    real, pd, _ = realistic_set(np.asarray(vertices)[idx], np.asarray(features)[idx], acap, [], pool,
                                c["train_set"], samples_dir, eps, tag="realistic_train", sources=idx)
    ok = np.isfinite(pd) & (pd != 0)
    rows = CollisionStore(dc_path, space.dim, space.n_parts).read()
    net, report = train_mesh_detector(space, rows.z, rows.collides, real.vertices[ok], pd[ok] > 0, c, seed,
                                      run_dir, logger=logger)
    if test is not None:
        logits = code_logits(net, space, np.asarray(test.z))
        report["test"] = detection_metrics(logits > 0, np.asarray(test.collides, bool))
    report["stage_seconds"] = time.perf_counter() - t0
    return net, report
