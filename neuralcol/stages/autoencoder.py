"""Stage: train (or load from cache) the bilevel autoencoder of a data set -> :class:`LatentSpace`.

Training runs level 1 (attention components), derives the sub-domains, then level 2 on the residuals; the
result is cached under ``<cache_dir>/autoencoders/<key>/`` where the key hashes the meshes, the ACAP
settings, the autoencoder config and the seed, so a later run with the same inputs loads it.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import NamedTuple

import lightning as L
import numpy as np
import torch
from filelock import FileLock
from hydra.utils import instantiate
from omegaconf import DictConfig
from scipy.cluster.vq import kmeans2
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from neuralcol.data.datasets import MeshDataset
from neuralcol.data.feature_datamodule import FeatureDataModule
from neuralcol.data.features import DatasetFeatures
from neuralcol.geometry.topology import edge_topology
from neuralcol.lit.autoencoder import AutoencoderLitModule
from neuralcol.metrics.reconstruction import relative_vertex_error
from neuralcol.nn.autoencoder import BilevelAutoencoder, Level1Autoencoder, Level2Autoencoders
from neuralcol.nn.latent_space import LatentSpace
from neuralcol.nn.normalizer import FeatureNormalizer
from neuralcol.nn.pca_space import BASES, PCALatentSpace, centred_vertices, pca_space
from neuralcol.rundir import CacheDir
from neuralcol.utils.config import as_dict
from neuralcol.utils.hashing import settings_key
from neuralcol.utils.progress import trainer_progress
from neuralcol.utils.threads import threads_pinned


class PartitionReport(NamedTuple):
    """Sub-domain facts: sizes (K,), connected pieces per sub-domain before and after clean-up."""

    sizes: list[int]
    pieces_before: list[int]
    pieces_after: list[int]


def split_indices(n: int, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-seed train / validation split of n meshes: (train indices, val indices), both sorted."""
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction={val_fraction}: must be in [0, 1)")
    perm = np.random.default_rng(seed).permutation(n)
    n_val = int(round(val_fraction * n))
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


def spatial_attention_init(rest_vertices: np.ndarray, k: int, scale: float, seed: int) -> torch.Tensor:
    """(K, V) attention logits: ``scale`` on each vertex's k-means cluster of the rest mesh, 0 elsewhere."""
    _, labels = kmeans2(rest_vertices, k, seed=seed, minit="++")
    logits = np.zeros((k, len(rest_vertices)), dtype=np.float32)
    logits[labels, np.arange(len(rest_vertices))] = scale
    return torch.from_numpy(logits)


def count_pieces(partition: np.ndarray, edges: np.ndarray, k: int) -> list[int]:
    """Connected pieces of each sub-domain (edges with both ends in it)."""
    out = []
    for i in range(k):
        idx = np.nonzero(partition == i)[0]
        if len(idx) == 0:
            out.append(0)
            continue
        keep = (partition[edges[:, 0]] == i) & (partition[edges[:, 1]] == i)
        loc = -np.ones(len(partition), dtype=np.int64)
        loc[idx] = np.arange(len(idx))
        e = edges[keep]
        g = coo_matrix((np.ones(len(e)), (loc[e[:, 0]], loc[e[:, 1]])), shape=(len(idx), len(idx)))
        out.append(int(connected_components(g, directed=False)[0]))
    return out


def connect_partition(partition: np.ndarray, edges: np.ndarray, k: int, max_rounds: int = 20) -> np.ndarray:
    """Give every piece but the largest of each sub-domain to the neighbouring sub-domain it touches most.

    Args:
        partition: (V,) int sub-domain per vertex.
        edges: (E, 2) mesh edges.
        k: number of sub-domains.
        max_rounds: repetitions (pieces can merge in cascades).

    Returns:
        (V,) int partition where each sub-domain is one connected piece where possible.
    """
    part = partition.copy()
    n = len(part)
    for _ in range(max_rounds):
        changed = False
        for i in range(k):
            keep = (part[edges[:, 0]] == i) & (part[edges[:, 1]] == i)
            e = edges[keep]
            g = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
            _, comp = connected_components(g, directed=False)
            members = np.nonzero(part == i)[0]
            if len(members) == 0:
                continue
            labels, counts = np.unique(comp[members], return_counts=True)
            if len(labels) <= 1:
                continue
            main = labels[np.argmax(counts)]
            for lab in labels:
                if lab == main:
                    continue
                piece = members[comp[members] == lab]
                mask = np.zeros(n, dtype=bool)
                mask[piece] = True
                touching = np.concatenate([part[edges[mask[edges[:, 0]] & ~mask[edges[:, 1]], 1]],
                                           part[edges[mask[edges[:, 1]] & ~mask[edges[:, 0]], 0]]])
                touching = touching[touching != i]
                if len(touching):
                    part[piece] = np.bincount(touching, minlength=k).argmax()
                    changed = True
        if not changed:
            break
    return part


# settings added after caches existed: at these values they leave the key as it was (an unchanged model keeps
# its cached space when a config spells the default out)
KEY_NEUTRAL = {(None, "kind"): "bilevel",
               ("level1", "activation"): "tanh", ("level1", "code_noise"): 0.0, ("level2", "code_noise"): 0.0,
               ("level1", "interp_ratio"): 0.0, ("level2", "interp_ratio"): 0.0, (None, "interp_t"): [0.0, 1.0]}


def _key_config(ae_cfg: dict) -> dict:
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in ae_cfg.items()}
    for (group, name), neutral in KEY_NEUTRAL.items():
        where = out if group is None else out.get(group)
        if isinstance(where, dict) and name in where and _same(where[name], neutral):
            del where[name]
    return out


def _same(value, neutral) -> bool:
    if isinstance(neutral, list):
        return isinstance(value, (list, tuple)) and [float(v) for v in value] == neutral
    return value == neutral


def autoencoder_cache_key(ds: MeshDataset, reference_index: int, acap_kwargs: dict, ae_cfg: dict,
                          latent_cfg: dict, seed: int) -> str:
    """Hash of everything the trained latent space depends on (meshes, ACAP settings, config, seed)."""
    ae_cfg = _key_config(ae_cfg)
    return settings_key([reference_index, acap_kwargs, ae_cfg, latent_cfg, seed], 16, default=str,
                        data=[ds.vertices.detach().cpu().numpy().tobytes(), ds.faces.cpu().numpy().tobytes()])


def _scheduler(ae_cfg: dict, epochs: int):
    """The configured LR scheduler partial; a ``T_max: null`` entry is set to the stage's epochs."""
    cfg = ae_cfg.get("scheduler")
    if not cfg:
        return None
    if "T_max" in cfg and cfg["T_max"] is None:
        return instantiate(cfg, T_max=max(1, epochs))
    return instantiate(cfg)


def _stage_logger(logger, stage: str):
    """``logger`` may be one Lightning logger (both levels share it) or a factory ``stage name -> logger``
    (one TensorBoard run per level: ``autoencoder_level1``, ``autoencoder_level2``)."""
    if logger is None or hasattr(logger, "log_metrics"):
        return logger
    return logger(stage)


def _trainer(ae_cfg: dict, epochs: int, logger, callbacks=()) -> L.Trainer:
    return L.Trainer(max_epochs=epochs, accelerator=ae_cfg.get("accelerator", "auto"), devices=1,
                     logger=logger if logger is not None else False, enable_checkpointing=False,
                     enable_model_summary=False, log_every_n_steps=1,
                     check_val_every_n_epoch=int(ae_cfg.get("val_every", 50)), deterministic=False,
                     **trainer_progress(bool(ae_cfg.get("progress_bar", True)), "autoencoder", callbacks))


def train_latent_space(ds: MeshDataset, feats: DatasetFeatures, ae_cfg: DictConfig | dict,
                       latent_cfg: DictConfig | dict, seed: int, logger=None) -> tuple[LatentSpace, dict]:
    """Train the bilevel autoencoder of a data set.

    Args:
        ds: the meshes.
        feats: their ACAP features (``feats.acap`` is the transform; its settings go into the result).
        ae_cfg: autoencoder training config (``conf/autoencoder/*.yaml``).
        latent_cfg: latent sizes of this data set (``dataset.latent``).
        seed: seed of the split, initialisation and shuffling.
        logger: Lightning logger (TensorBoard), a factory ``stage name -> logger`` (one run per level), or None.

    Returns:
        The latent space and a report dict (errors, partition facts, seconds).
    """
    ae, lat = as_dict(ae_cfg), as_dict(latent_cfg)
    t_start = time.perf_counter()
    L.seed_everything(seed, workers=True, verbose=False)
    n = len(ds)
    train_idx, val_idx = split_indices(n, ae["val_fraction"], seed)
    normalizer = FeatureNormalizer(**ae.get("normalizer", {})).fit(feats.features[torch.as_tensor(train_idx)])
    x = normalizer.normalize(feats.features.float())
    rest = ds.vertices[feats.reference_index].detach().cpu().numpy().astype(np.float64)
    faces = ds.faces.cpu().numpy()
    edges = edge_topology(faces).edges
    k = int(lat["n_components"])
    l1cfg, l2cfg = ae["level1"], ae["level2"]
    interp_t = tuple(ae.get("interp_t", (0.0, 1.0)))
    init = spatial_attention_init(rest, k, float(l1cfg["attention_init_scale"]), seed)
    level1 = Level1Autoencoder(ds.n_vertices, k, hidden=int(l1cfg["hidden"]), attention_init=init,
                               activation=str(l1cfg.get("activation", "tanh")))
    net = BilevelAutoencoder(level1)
    dm = FeatureDataModule(x, train_idx, val_idx, batch_size=int(ae["batch_size"]), seed=seed)
    stage1 = AutoencoderLitModule(
        net, 1, optimizer=instantiate(ae["optimizer"], lr=l1cfg["lr"]), scheduler=_scheduler(ae, int(l1cfg["epochs"])),
        edges=torch.as_tensor(edges), w_sparsity=l1cfg["w_sparsity"], w_smoothness=l1cfg["w_smoothness"],
        w_balance=l1cfg["w_balance"], code_noise=float(l1cfg.get("code_noise", 0.0)),
        interp_ratio=float(l1cfg.get("interp_ratio", 0.0)), interp_t=interp_t)
    _trainer(ae, int(l1cfg["epochs"]), _stage_logger(logger, "autoencoder_level1")).fit(stage1, dm)
    with torch.no_grad():
        raw_part = net.level1.attention().argmax(0).cpu().numpy()
    part = connect_partition(raw_part, edges, k)
    report_part = PartitionReport(np.bincount(part, minlength=k).tolist(), count_pieces(raw_part, edges, k),
                                  count_pieces(part, edges, k))
    if int(lat["level2_dim"]) > 0:  # level2_dim 0: no level 2 at all (Z_all = Z_0), and no stage-2 training
        net.level2 = Level2Autoencoders(torch.as_tensor(part), k, latent_dim=int(lat["level2_dim"]),
                                        hidden=int(l2cfg["hidden"]))
        stage2 = AutoencoderLitModule(net, 2, optimizer=instantiate(ae["optimizer"], lr=l2cfg["lr"]),
                                      scheduler=_scheduler(ae, int(l2cfg["epochs"])),
                                      code_noise=float(l2cfg.get("code_noise", 0.0)),
                                      interp_ratio=float(l2cfg.get("interp_ratio", 0.0)), interp_t=interp_t)
        if int(l2cfg["epochs"]) > 0:
            _trainer(ae, int(l2cfg["epochs"]), _stage_logger(logger, "autoencoder_level2")).fit(stage2, dm)
    net.eval().cpu()
    with torch.no_grad():
        z = net.encode(x)
    box_from = str(ae.get("box_from", "all"))
    if box_from not in ("train", "all"):
        raise ValueError(f"autoencoder.box_from={box_from!r}; use 'train' (codes of the meshes the autoencoder "
                         "trained on) or 'all' (every mesh of the data set)")
    z_box = z[torch.as_tensor(train_idx)] if box_from == "train" else z
    lo, hi = z_box.amin(0), z_box.amax(0)
    margin = float(ae.get("box_margin", 0.0)) * (hi - lo)
    acap_kwargs = dict(feats.acap.settings)
    space = LatentSpace(net, normalizer, rest, faces, acap_kwargs, lo - margin, hi + margin,
                        torch.as_tensor(part), meta={})
    with torch.no_grad():
        recon = space.decode(z)
    err = relative_vertex_error(recon, ds.vertices.float())
    report = {
        "n_train": len(train_idx), "n_val": len(val_idx), "latent_dim": space.dim, "n_components": k,
        "train_mean_vertex_error": float(err.mean[torch.as_tensor(train_idx)].mean()),
        "val_mean_vertex_error": float(err.mean[torch.as_tensor(val_idx)].mean()) if len(val_idx) else None,
        "train_max_vertex_error": float(err.max[torch.as_tensor(train_idx)].max()),
        "partition_sizes": report_part.sizes, "pieces_before_cleanup": report_part.pieces_before,
        "pieces": report_part.pieces_after, "train_seconds": time.perf_counter() - t_start,
        "train_index": train_idx.tolist(), "val_index": val_idx.tolist(),
        "n_parameters": int(sum(p.numel() for p in net.parameters())),
        "box_from": box_from,
    }
    space.meta = report
    return space, report


def train_pca_space(ds: MeshDataset, feats: DatasetFeatures, ae_cfg: DictConfig | dict, latent_cfg: DictConfig | dict,
                    seed: int) -> tuple[PCALatentSpace, dict]:
    """``autoencoder=pca``: a PCA latent space of |Z_all| components fit on the training meshes.

    The split, the box rule (``box_from``, ``box_margin``) and the sub-domains' initial clustering are the bilevel
    autoencoder's, so the two spaces differ only in their maps. Returns the space and its report (the same keys as
    :func:`train_latent_space`'s).
    """
    ae, lat = as_dict(ae_cfg), as_dict(latent_cfg)
    t_start = time.perf_counter()
    basis = str(ae.get("basis", "vertex"))
    if basis not in (*BASES, "auto"):
        raise ValueError(f"autoencoder.basis={basis!r}; use one of {BASES} or auto")
    train_idx, val_idx = split_indices(len(ds), ae["val_fraction"], seed)
    rest = ds.vertices[feats.reference_index].detach().cpu().numpy().astype(np.float64)
    faces = ds.faces.cpu().numpy()
    edges = edge_topology(faces).edges
    k = int(lat["n_components"])
    cv = None
    if basis == "auto":  # the basis whose held-in cross-validation error is lower (the held-out meshes stay unseen)
        cv = {b: cross_validated_error(b, ds, feats, train_idx, k * (1 + int(lat["level2_dim"])),
                                       int(ae.get("cv_folds", 5)), seed) for b in BASES}
        basis = min(BASES, key=lambda b: cv[b])
    raw_part = spatial_attention_init(rest, k, 1.0, seed).argmax(0).numpy()
    part = connect_partition(raw_part, edges, k)
    box_from = str(ae.get("box_from", "train"))
    if box_from not in ("train", "all"):
        raise ValueError(f"autoencoder.box_from={box_from!r}; use 'train' or 'all'")
    dim = k * (1 + int(lat["level2_dim"]))  # |Z_all|, as the bilevel space's
    space = pca_space(basis, ds.vertices.numpy(), feats.features.numpy(), train_idx, dim, rest, faces,
                      dict(feats.acap.settings), k, part, float(ae.get("box_margin", 0.0)))
    if box_from == "all":
        z = space.encode(ds.vertices)
        margin = float(ae.get("box_margin", 0.0)) * (z.amax(0) - z.amin(0))
        space.box_lo.copy_(z.amin(0) - margin)
        space.box_hi.copy_(z.amax(0) + margin)
    err = reference_errors(space, ds, feats, train_idx, val_idx)
    report = {
        "kind": "pca", "basis": basis, "n_train": len(train_idx), "n_val": len(val_idx), "latent_dim": space.dim,
        "n_components": k, "train_mean_vertex_error": err["train_mean_vertex_error"],
        "val_mean_vertex_error": err["val_mean_vertex_error"], "train_max_vertex_error": err["train_max_vertex_error"],
        "partition_sizes": np.bincount(part, minlength=k).tolist(), "pieces_before_cleanup":
            count_pieces(raw_part, edges, k), "pieces": count_pieces(part, edges, k),
        "train_seconds": time.perf_counter() - t_start, "train_index": train_idx.tolist(),
        "val_index": val_idx.tolist(), "n_parameters": int(space.pca_components.numel() + space.pca_mean.numel()),
        "box_from": box_from, "basis_cv_error": cv,
    }
    space.meta = report
    return space, report


def cross_validated_error(basis: str, ds: MeshDataset, feats: DatasetFeatures, train_idx, dim: int, folds: int,
                          seed: int) -> float:
    """Mean vertex error of a ``basis`` PCA of ``dim`` components on the training meshes, each fold fit on the
    others (``folds``-fold, shuffled by ``seed``); folds whose complement cannot span ``dim`` are skipped (inf if
    all are)."""
    train_idx = np.asarray(train_idx)
    order = np.random.default_rng(seed).permutation(len(train_idx))
    rest = ds.vertices[feats.reference_index].detach().cpu().numpy().astype(np.float64)
    errs = []
    for fold in np.array_split(order, max(2, int(folds))):
        fit = np.setdiff1d(np.arange(len(train_idx)), fold)
        if len(fit) - 1 < dim or not len(fold):
            continue
        ref = pca_space(basis, ds.vertices.numpy(), feats.features.numpy(), train_idx[fit], dim, rest,
                        ds.faces.cpu().numpy(), dict(feats.acap.settings), dim, np.zeros(ds.n_vertices, np.int64))
        e = reference_errors(ref, ds, feats, train_idx[fit], train_idx[fold])
        errs.append(e["val_mean_vertex_error"])
    return float(np.mean(errs)) if errs else float("inf")


def reference_errors(space: PCALatentSpace, ds: MeshDataset, feats: DatasetFeatures, train_idx, val_idx) -> dict:
    """Train and held-out vertex errors of a PCA space's round trip on the data set's meshes (the autoencoder's
    metric, :func:`~neuralcol.metrics.reconstruction.relative_vertex_error`). The ACAP basis projects the data set's
    cached features instead of encoding the meshes again."""
    if space.basis == "vertex":
        rows = torch.from_numpy(centred_vertices(ds.vertices.numpy()))
    else:
        rows = feats.features.to(torch.float64).flatten(1)
    z = (rows - space.pca_mean) @ space.pca_components.T  # (N, D)
    with torch.no_grad():
        recon = torch.cat([space.decode(b) for b in z.split(256)])
    err = relative_vertex_error(recon.float(), ds.vertices.float())
    tr, va = torch.as_tensor(np.asarray(train_idx)), torch.as_tensor(np.asarray(val_idx))
    return {"train_mean_vertex_error": float(err.mean[tr].mean()),
            "val_mean_vertex_error": float(err.mean[va].mean()) if len(va) else None,
            "train_max_vertex_error": float(err.max[tr].max())}


def reference_spaces(ds: MeshDataset, feats: DatasetFeatures, space, report: dict) -> tuple[dict, dict]:
    """The PCA references of a latent space: PCA of the vertex positions and of the raw ACAP features at
    the same |Z_all|, fit on the same training meshes, with the space's sub-domains and box rule.

    Returns:
        (``{"vertex_pca": PCALatentSpace, "acap_pca": ...}``, ``{name: {train_mean_vertex_error,
        val_mean_vertex_error, train_max_vertex_error}}``); a reference the training meshes cannot span (|Z_all| >
        N_train - 1) is left out of the spaces and reported with its ``reason``.
    """
    train_idx, val_idx = np.asarray(report["train_index"]), np.asarray(report["val_index"])
    rest = ds.vertices[feats.reference_index].detach().cpu().numpy().astype(np.float64)
    spaces, errors = {}, {}
    for basis in BASES:
        name = f"{basis}_pca"
        try:
            ref = pca_space(basis, ds.vertices.numpy(), feats.features.numpy(), train_idx, space.dim, rest,
                            ds.faces.cpu().numpy(), dict(feats.acap.settings), space.n_parts,
                            space.partition.cpu().numpy())
        except ValueError as e:
            errors[name] = {"reason": str(e)}
            continue
        spaces[name] = ref
        errors[name] = reference_errors(ref, ds, feats, train_idx, val_idx)
    return spaces, errors


def train_or_load_latent_space(ds: MeshDataset, feats: DatasetFeatures, ae_cfg, latent_cfg, seed: int,
                               cache_dir: str | Path | None, logger=None,
                               threads: int | None = 1) -> tuple[LatentSpace, dict, bool]:
    """Load the cached latent space for these inputs, or train and cache it.

    ``threads``: torch/BLAS threads the training runs on (``neuralcol.utils.threads``; the trained weights depend
    on it, so it is part of the cache key); None: the machine's default, whatever it is.

    Returns:
        (latent space, report, loaded_from_cache); ``report["cache_key"]`` identifies the latent space (later
        caches, e.g. labeled test sets, are keyed by it).
    """
    ae, lat = as_dict(ae_cfg), as_dict(latent_cfg)
    train_keys = {k: v for k, v in ae.items() if k not in ("progress_bar", "accelerator", "val_every")}
    train_keys["threads"] = "machine" if threads is None else int(threads)
    if int(lat["level2_dim"]) == 0:
        # formerly a level2_dim-0 space still trained a level-2 stage (code-free decoders: a constant offset
        # per sub-domain, vertex effect ~4e-4 of the diagonal on SCAPE) for level2.epochs; such spaces are not
        # reused for the stage-free model
        train_keys["level2"] = "none"
    key = autoencoder_cache_key(ds, feats.reference_index, feats.acap.settings, train_keys, lat, seed)
    path = CacheDir(cache_dir).latent_space(key) if cache_dir else None
    train = train_latent_space if str(ae.get("kind", "bilevel")) != "pca" else (
        lambda ds, feats, ae, lat, seed, logger: train_pca_space(ds, feats, ae, lat, seed))
    if path is None:
        with threads_pinned(threads):
            space, report = train(ds, feats, ae, lat, seed, logger)
        return space, {**report, "cache_key": key}, False
    path.parent.mkdir(parents=True, exist_ok=True)
    # one trainer per cache entry: parallel sweep jobs (hydra/launcher=parallel) wait for the first one
    with FileLock(str(path.parent / ".lock")):
        if path.is_file():
            try:
                space = LatentSpace.load(path)
                return space, {**space.meta, "cache_key": key}, True
            except Exception:  # a broken cache entry is retrained, not fatal
                path.unlink()
        with threads_pinned(threads):
            space, report = train(ds, feats, ae, lat, seed, logger)
        space.save(path)
        (path.parent / "report.json").write_text(json.dumps({k: v for k, v in report.items()
                                                             if k not in ("train_index", "val_index")}, indent=2))
    return space, {**report, "cache_key": key}, False
