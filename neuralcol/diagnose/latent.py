"""Diagnostics of a latent space as a sampling domain for collision detection (docs/diagnosis.md).

Questions these functions answer, each on a trained :class:`~neuralcol.nn.latent_space.LatentSpace`:

* How well are the meshes that built the box Z embedded (:func:`reconstruction_report`)?
* How much of the box comes from codes the autoencoder did not train on (:func:`box_report`)?
* Does the decoder change smoothly along the box, or switch (:func:`decoder_report`: tanh saturation of the
  level-1 decoder's first layer, share of the decoded motion in the busiest 5 % of a line through the box)?
* Do samples of U(Z) look like the data set (:func:`plausibility_report`: edge stretch and ACAP feature range)?
* How rough is the label as a function of the normalised code (:func:`label_roughness`: flip rate under small
  shifts)?

Symbols: N meshes, B samples, V vertices, D = |Z_all|, K = |Z_0|.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

from neuralcol.geometry.topology import edge_topology
from neuralcol.metrics.reconstruction import relative_vertex_error
from neuralcol.nn.latent_space import LatentSpace


def _decode(space: LatentSpace, z: torch.Tensor, batch: int = 256) -> torch.Tensor:
    with torch.no_grad():
        return torch.cat([space.decode(c.float()) for c in z.split(batch)]) if len(z) else torch.zeros(0)


def reconstruction_report(space: LatentSpace, vertices: torch.Tensor, train_index: Sequence[int]) -> dict:
    """Per-mesh reconstruction error (encode then decode) relative to each mesh's bounding-box diagonal.

    Args:
        space: the latent space.
        vertices: (N, V, 3) the data set's meshes.
        train_index: indices of the meshes the autoencoder trained on (the rest are held out).

    Returns:
        ``errors`` (N,) mean vertex error per mesh, ``train`` (N,) bool, ``train_mean`` / ``heldout_mean`` /
        ``train_max`` / ``heldout_max``, ``heldout_over_train`` (ratio of the means).
    """
    v = torch.as_tensor(vertices).float()
    z = space.encode(v)
    err = relative_vertex_error(_decode(space, z), v).mean.numpy().astype(np.float64)
    train = np.zeros(len(v), bool)
    train[np.asarray(list(train_index), np.int64)] = True
    nan = float("nan")
    tr, ho = err[train], err[~train]
    out = {"errors": err.tolist(), "train": train.tolist(),
           "train_mean": float(tr.mean()) if len(tr) else nan, "train_max": float(tr.max()) if len(tr) else nan,
           "heldout_mean": float(ho.mean()) if len(ho) else nan, "heldout_max": float(ho.max()) if len(ho) else nan}
    out["heldout_over_train"] = out["heldout_mean"] / out["train_mean"] if len(ho) and len(tr) else nan
    return out


def _log10_volume(lo: np.ndarray, hi: np.ndarray, unit: np.ndarray) -> float:
    """log10 of the box volume in units of ``unit`` per axis (boxes of very different sizes stay finite)."""
    return float(np.sum(np.log10(np.maximum(hi - lo, 1e-30) / unit)))


def box_report(space: LatentSpace, vertices: torch.Tensor, train_index: Sequence[int]) -> dict:
    """The box Z against the boxes of the training codes and of all codes, per latent level.

    Returns:
        For ``level1``, ``level2`` and ``all``: log10 volume ratios ``box_over_train`` (the space's box vs the
        box of the training meshes' codes) and ``all_over_train`` (box of every mesh's code vs training codes);
        ``half_range`` (D,) of the space's box; ``box_from`` as recorded by the autoencoder stage.
    """
    z = space.encode(torch.as_tensor(vertices).float()).numpy().astype(np.float64)
    idx = np.asarray(list(train_index), np.int64)
    lo, hi = space.box_lo.numpy().astype(np.float64), space.box_hi.numpy().astype(np.float64)
    t_lo, t_hi = z[idx].min(0), z[idx].max(0)
    a_lo, a_hi = z.min(0), z.max(0)
    unit = np.maximum(t_hi - t_lo, 1e-30)
    k = space.n_parts
    out: dict = {"half_range": ((hi - lo) / 2).tolist(), "box_from": space.meta.get("box_from", "all")}
    for name, sl in (("level1", slice(0, k)), ("level2", slice(k, None)), ("all", slice(None))):
        if sl.start == k and space.dim == k:
            continue
        out[name] = {"box_over_train": _log10_volume(lo[sl], hi[sl], unit[sl]),
                     "all_over_train": _log10_volume(a_lo[sl], a_hi[sl], unit[sl])}
    return out


def decoder_report(space: LatentSpace, z: torch.Tensor, n_points: int = 201, top: float = 0.05) -> dict:
    """How step-like the decoder is along the level-1 axes.

    For each component k, a line through ``z[k % B]`` along axis k (from box_lo to box_hi, ``n_points``
    points) is decoded; the largest vertex displacement between consecutive points gives the motion per
    segment. ``busiest_share[k]`` is the share of the total motion in the busiest ``top`` fraction of the
    segments: ``top`` for a decoder that moves evenly, near 1 for a switch. ``saturation`` is the share of
    the level-1 decoder's tanh units with ``|z0 w + b| > 2`` over the samples ``z`` (0 for a linear decoder).

    Args:
        space: the latent space.
        z: (B, D) samples of U(Z) (B >= 1).
    """
    l1 = space.net.level1
    k = space.n_parts
    with torch.no_grad():
        pre = z[:, :k, None].float() * l1.comp_in_w + l1.comp_in_b  # (B, K, H)
    sat = float((pre.abs() > 2).float().mean()) if l1.activation == "tanh" else 0.0
    t = torch.linspace(0.0, 1.0, n_points)
    n_top = max(1, int(round(top * (n_points - 1))))
    busiest = []
    for j in range(k):
        line = z[j % len(z)].float().repeat(n_points, 1)  # (P, D)
        line[:, j] = space.box_lo[j] + t * (space.box_hi[j] - space.box_lo[j])
        v = _decode(space, line)
        step = (v[1:] - v[:-1]).norm(dim=-1).amax(-1).numpy().astype(np.float64)  # (P - 1,)
        total = step.sum()
        busiest.append(float(np.sort(step)[-n_top:].sum() / total) if total > 0 else float("nan"))
    return {"saturation": sat, "activation": l1.activation, "busiest_share": busiest,
            "busiest_share_mean": float(np.nanmean(busiest)), "even_share": n_top / (n_points - 1)}


def plausibility_report(space: LatentSpace, z: torch.Tensor, vertices: torch.Tensor, faces: np.ndarray,
                        tolerance: float = 0.1) -> dict:
    """Do decoded samples stay within the data set's range of deformation?

    * Edge stretch: each edge's length over its rest length. The data set's range is [min, max] over all its
      meshes and edges; a sample is within range if all its edges are within that range widened by
      ``tolerance`` (relative).
    * ACAP features: the decoded normalised features of a sample against [-bound, bound] (the data set's
      range after :class:`~neuralcol.nn.normalizer.FeatureNormalizer`), widened by ``tolerance`` x bound;
      ``feature_entries_within`` is the mean share of feature entries inside, ``feature_within`` the share of
      samples with 99 % of their entries inside.

    Args:
        space: the latent space.
        z: (B, D) samples.
        vertices: (N, V, 3) the data set's meshes.
        faces: (F, 3) triangles.
        tolerance: relative widening of the ranges.
    """
    edges = edge_topology(np.asarray(faces)).edges
    rest = space.rest_vertices.numpy()
    rest_len = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=-1)

    def stretch(v: np.ndarray) -> np.ndarray:  # (B, V, 3) -> (B, E)
        return np.linalg.norm(v[:, edges[:, 0]] - v[:, edges[:, 1]], axis=-1) / rest_len

    data = stretch(torch.as_tensor(vertices).double().numpy())
    lo, hi = data.min() * (1 - tolerance), data.max() * (1 + tolerance)
    dec = _decode(space, z).double().numpy()
    s = stretch(dec)
    within_edges = (s >= lo) & (s <= hi)
    with torch.no_grad():
        feats = torch.cat([space.net.decode(c.float()) for c in z.split(256)]).numpy()  # normalised (B, V, 9)
    bound = space.norm_bound * (1 + tolerance)
    inside = np.abs(feats) <= bound
    per_sample = inside.reshape(len(z), -1).mean(1)
    return {"edge_stretch_data_range": [float(data.min()), float(data.max())],
            "edge_stretch_sample_range": [float(s.min()), float(s.max())],
            "edge_within": float(within_edges.all(1).mean()),
            "feature_entries_within": float(per_sample.mean()),
            "feature_within": float((per_sample >= 0.99).mean()), "tolerance": tolerance}


def label_roughness(label: Callable[[torch.Tensor], np.ndarray], z: torch.Tensor, box_lo: torch.Tensor,
                    box_hi: torch.Tensor, scales: Sequence[float], seed: int = 0) -> dict:
    """Flip rate of the exact label under small shifts of the normalised code.

    Each sample's box-normalised coordinates (the box mapped to [-1, 1]) are shifted by ``+-s`` (random sign
    per coordinate), clamped into the box, and labeled again; the flip rate is the share of samples whose
    verdict changes. A smooth label has flip rates growing linearly with ``s`` from 0.

    Args:
        label: (B, D) codes -> (B,) bool verdicts (e.g. decode + exact labeler).
        z: (B, D) samples.
        box_lo, box_hi: (D,) the box.
        scales: shifts in normalised units (e.g. 1e-3, 1e-2, 3e-2, 1e-1).
        seed: seed of the signs.

    Returns:
        ``{"scales": [...], "flip_rate": [...], "base_rate": share colliding of the unshifted samples, "n": B}``
    """
    gen = torch.Generator().manual_seed(int(seed))
    half = (box_hi - box_lo) / 2
    y0 = np.asarray(label(z), bool)
    rates = []
    for s in scales:
        sign = torch.randint(0, 2, z.shape, generator=gen).to(z) * 2 - 1
        zs = torch.maximum(torch.minimum(z + float(s) * half * sign, box_hi), box_lo)
        rates.append(float(np.mean(np.asarray(label(zs), bool) != y0)))
    return {"scales": [float(s) for s in scales], "flip_rate": rates, "base_rate": float(y0.mean()), "n": len(z)}
