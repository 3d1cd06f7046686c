"""Stage: what the one detector over code and mesh reads besides the code (``detector.inputs:
code_and_mesh``).

* :func:`realistic_rows`: realistic training meshes (built like the realistic evaluation set, from the
  autoencoder's *training* meshes only; cached beside the U(Z) test set) labeled in full and encoded. They join
  D_c as rows of their own (code = encode(mesh), pair features of the mesh itself, exact label): a real mesh's detail
  lies outside the span of the decoded samples (docs/studies/one_detector.md).
* :func:`choose_run_geometry`: the contact pairs of each sub-domain, chosen on the decoded bootstrap samples (with
  their labels) and the realistic training meshes, saved in the run directory (``geometry.npz``) so a resumed run
  builds the same detector; :func:`load_run_geometry` reads them back.
* :func:`codes_featurizer`: the pair features of codes, decoding only the vertices they read, in blocks, without
  gradients (what D_c stores; whole meshes: :func:`~neuralcol.nn.part_geometry.mesh_pair_features`).

See :mod:`neuralcol.nn.part_geometry` for the features themselves.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from neuralcol.nn.part_geometry import PartGeometry, choose_geometry, geometry_of_codes
from neuralcol.utils.files import atomic_path
from neuralcol.utils.hashing import content_key
from neuralcol.utils.progress import progress_bar

INPUTS = ("latent", "code_and_mesh")  # detector.inputs


class RealisticRows(NamedTuple):
    """M labeled realistic training meshes as D_c rows: z (M, D) float32 = encode(mesh), pd (M,), pd_sub (M, K),
    collides (M,), subset (M,) int8, vertices (M, V, 3) float64."""

    z: np.ndarray
    pd: np.ndarray
    pd_sub: np.ndarray
    collides: np.ndarray
    subset: np.ndarray
    vertices: np.ndarray


def detector_inputs(det: dict) -> str:
    """``detector.inputs`` (default ``latent``), checked."""
    inputs = str(det.get("inputs", "latent"))
    if inputs not in INPUTS:
        raise ValueError(f"detector.inputs={inputs!r}; use one of {INPUTS}")
    return inputs


def encode_in_blocks(space, vertices: np.ndarray, block: int = 512) -> np.ndarray:
    """Meshes (M, V, 3) -> codes (M, D) float32, ``block`` meshes at a time."""
    out = [space.encode(torch.as_tensor(vertices[i:i + block], dtype=torch.float64)).detach().cpu().float()
           for i in range(0, len(vertices), block)]
    return torch.cat(out).numpy() if out else np.zeros((0, space.dim), np.float32)


def realistic_rows(space, vertices: np.ndarray, features: np.ndarray, acap, train_index, pool, train_set_cfg,
                   samples_dir: str | Path, eps: float) -> RealisticRows:
    """The realistic training meshes of the autoencoder's training meshes ``train_index``, labeled in full by
    ``pool`` (PD_i per sub-domain too) and encoded; meshes the labeler failed on or with PD exactly 0 are left out.

    Args:
        space: the latent space. vertices, features, acap: the data set's meshes, raw ACAP features, transform.
        train_index: the autoencoder's training meshes (the only sources). pool: label pool of the run's sample
            labeler. train_set_cfg: how many of each kind (``detector.geometry.train_set``). samples_dir: the latent
            space's samples cache. eps: the labeler's boundary width.
    """
    from neuralcol.stages.realistic import realistic_set

    idx = np.asarray(train_index, dtype=np.int64)
    real, _, _ = realistic_set(np.asarray(vertices)[idx], np.asarray(features)[idx], acap, [], pool, train_set_cfg,
                               samples_dir, eps, tag="realistic_train", sources=idx)
    v = np.asarray(real.vertices, np.float64)
    if len(v) == 0:
        k = space.n_parts
        return RealisticRows(np.zeros((0, space.dim), np.float32), np.zeros(0), np.zeros((0, k)),
                             np.zeros(0, bool), np.zeros(0, np.int8), v)
    ok, pd, pd_sub = full_labels(pool, v, samples_dir)
    keep = ok & (np.nan_to_num(pd) != 0)
    pd = pd[keep]
    return RealisticRows(encode_in_blocks(space, v[keep]), pd, pd_sub[keep], pd > 0,
                         pool.labeler.subsets(pd).astype(np.int8), v[keep])


def full_labels(pool, vertices: np.ndarray, samples_dir: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The full exact labels (``ok`` (M,), PD (M,), PD_i (M, K)) of the realistic training meshes ``vertices``,
    labeled by ``pool`` once and then read from ``samples_dir`` (keyed by the labeler's settings, as that folder
    is, and by the meshes' bytes): every later run of the same latent space and settings skips the labeling
    (on anny_body ~0.4 s per mesh)."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    key = content_key([v.tobytes(), str(v.shape).encode()])
    path = Path(samples_dir) / f"realistic_train_full_{key}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as f:
            return f["ok"].astype(bool), f["pd"].astype(np.float64), f["pd_sub"].astype(np.float64)
    pool.desc = "labeling realistic training meshes"
    report = pool.label_report(v)
    ok = np.asarray(report.ok, bool)
    pd = np.asarray(report.labels.pd, np.float64)
    pd_sub = np.asarray(report.labels.pd_sub, np.float64)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, ok=ok, pd=pd, pd_sub=pd_sub)
    return ok, pd, pd_sub


def choose_run_geometry(space, z: np.ndarray, collides: np.ndarray, real: RealisticRows | None, cfg: dict,
                        path: str | Path) -> PartGeometry:
    """Choose the pairs on the decoded codes ``z`` (labeled ``collides``; at most ``cfg["select_codes"]`` of them,
    an even stride) and the realistic training meshes, and save them to ``path`` (``geometry.npz``).

    Args:
        space: the latent space. z, collides: labeled codes (the bootstrap). real: realistic training rows or None.
        cfg: ``detector.geometry`` (radius, min_hops, fold_ratio, colliding_weight, per_part, clip, select_codes).
        path: where the choice is saved.
    """
    z = np.asarray(z, np.float32)
    stride = max(1, -(-len(z) // max(1, int(cfg["select_codes"]))))
    sel = np.arange(0, len(z), stride)
    with torch.no_grad():
        meshes = [space.decode(torch.as_tensor(z[sel[i:i + 512]])).double().cpu().numpy()
                  for i in range(0, len(sel), 512)]
    v = np.concatenate(meshes) if meshes else np.zeros((0, *space.rest_vertices.shape))
    y = np.asarray(collides, bool)[sel]
    if real is not None and len(real.vertices):
        v = np.concatenate([v, real.vertices])
        y = np.concatenate([y, real.collides])
    geo = choose_geometry(space, v, y, radius=float(cfg["radius"]), min_hops=int(cfg["min_hops"]),
                          fold_ratio=float(cfg["fold_ratio"]), colliding_weight=float(cfg["colliding_weight"]),
                          per_part=int(cfg["per_part"]), clip=float(cfg["clip"]))
    with atomic_path(Path(path)) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, pairs=geo.contact.pairs.numpy(), slots=geo.slots.numpy(), mask=geo.mask.numpy(),
                     radius=np.float64(geo.contact.radius), clip=np.float64(geo.contact.clip),
                     n_examples=np.int64(len(v)))
    return geo


def load_run_geometry(space, path: str | Path) -> PartGeometry:
    """The pairs :func:`choose_run_geometry` saved (a resumed run builds the same detector)."""
    with np.load(Path(path), allow_pickle=False) as f:
        return PartGeometry(f["pairs"], f["slots"], f["mask"], space.faces.detach().cpu().numpy(),
                            float(f["radius"]), float(f["clip"]))


def codes_featurizer(geometry: PartGeometry, space, block: int = 4096):
    """``codes (B, D) -> pair features (B, P, 3) float32`` of their decoded meshes, in blocks, no gradients; a
    progress line or bar when there are more than two blocks (round 0 of a paper-scale run: 2e5 codes through an
    ACAP decoder, minutes)."""

    def featurize(z: np.ndarray) -> np.ndarray:
        z = torch.as_tensor(np.asarray(z, np.float32))
        out = []
        with torch.no_grad(), progress_bar(total=len(z), desc="pair features of decoded codes", unit="code",
                                           disable=len(z) <= 2 * block) as bar:
            for i in range(0, len(z), block):
                out.append(geometry_of_codes(geometry, space, z[i:i + block]).float())
                bar.update(len(out[-1]))
        return torch.cat(out).numpy() if out else np.zeros((0, geometry.n_pairs, 3), np.float32)

    return featurize
