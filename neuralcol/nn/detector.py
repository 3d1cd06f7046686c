"""Neural collision detector over latent codes (paper sec. 3.2) and its training losses (sec. 4.3).

``S_0 = CSE(Z_all)``, ``S_i = CP(S_0, z0_i, Z_i)`` for each sub-domain i with weights shared across i (so
the parameter count grows with |Z_0| only through the input width of CSE and MLP_c), and
``p = MLP_c(S_1, ..., S_K)`` the probability that the decoded mesh self-collides. Smooth activations
(tanh, CELU) keep gradients useful for the Newton projector and the handler.

Symbols: B batch, D = |Z_all|, K = |Z_0| sub-domains, d = level-2 code size.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from neuralcol.collision.labeler import SUBSET_BOUNDARY
from neuralcol.utils.files import atomic_path
from neuralcol.utils.safe_files import plain_values, read_torch_file


class DetectorOutput(NamedTuple):
    """prob (B,) collision probability, logit (B,), s (B, K) per-sub-domain indicators S_i."""

    prob: torch.Tensor
    logit: torch.Tensor
    s: torch.Tensor


def _mlp(sizes: list[int], act: type[nn.Module]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(act())
    return nn.Sequential(*layers)


class CollisionDetector(nn.Module):
    """CSE -> CP_i (shared) -> MLP_c.

    ``inference_block`` (class attribute, rows; 0 or None: off) sets the block size of CPU inference without
    gradients (see ``forward``).

    Args:
        n_components: K = |Z_0|.
        level2_dim: d (0 if the latent space has no level 2).
        state_dim: width of S_0.
        hidden: hidden width of CSE, CP and MLP_c.
        box_lo, box_hi: (D,) the latent box Z. Codes are mapped affinely from the box to [-1, 1] before CSE
            and CP (the raw level-1 codes span hundreds of units, the level-2 ones tens; unscaled inputs
            train measurably worse, see docs/studies/detector_training_choices.md). The map is part of the network
            (saved buffers), so gradients w.r.t. the raw codes, used by the projector and the handler, include it.
        code_features: optional ``(w (K, H), b (K, H), activation)``: the first layer of the latent space's
            level-1 decoder (``Level1Autoencoder.comp_in_w``, ``comp_in_b``, ``activation``). Each sub-domain's
            input then also holds ``act(z0_i w_i + b_i)`` (H values), the decoder's own reading of its code
            (frozen buffers, differentiable in z). Where the decoder's tanh units switch sharply inside the box
            the label changes sharply in z0 but smoothly in these features (measured in
            docs/studies/diagnosis_scape.md).
            None: the paper's inputs, Z_all only.
        geometry: optional :class:`~neuralcol.nn.part_geometry.PartGeometry`: each sub-domain's input
            then also holds an embedding of the contact-pair features of its own slots (``geometry_pool``:
            ``"linear"``, one affine map per sub-domain of its slots' features then CELU; ``"deepsets"``, a
            shared per-pair MLP, max and mean over the filled slots), and CSE reads all of them. ``forward`` then
            takes the pair features ``(B, P, 3)`` of the meshes (:meth:`geometry_of_meshes`, or
            :func:`~neuralcol.nn.part_geometry.geometry_of_codes` for decoded codes; what D_c stores). None: codes
            only.
        geometry_hidden: width of the geometry embedding.
    """

    inference_block: int | None = 512

    def __init__(self, n_components: int, level2_dim: int, state_dim: int = 64, hidden: int = 128,
                 box_lo: torch.Tensor | None = None, box_hi: torch.Tensor | None = None,
                 code_features: tuple[torch.Tensor, torch.Tensor, str] | None = None,
                 geometry: nn.Module | None = None, geometry_hidden: int = 32, geometry_pool: str = "linear"):
        super().__init__()
        self.n_components = n_components
        self.level2_dim = level2_dim
        latent_dim = n_components * (1 + level2_dim)
        n_feat = 0
        self.feature_activation = None
        if code_features is not None:
            fw, fb, act = code_features
            fw, fb = torch.as_tensor(fw, dtype=torch.float32), torch.as_tensor(fb, dtype=torch.float32)
            if fw.ndim != 2 or fw.shape[0] != n_components or fb.shape != fw.shape:
                raise ValueError(f"code_features: w and b must both be ({n_components}, H), got {tuple(fw.shape)} "
                                 f"and {tuple(fb.shape)}")
            if act not in ("tanh", "linear"):
                raise ValueError(f"code_features activation {act!r}; use 'tanh' or 'linear'")
            self.register_buffer("feature_w", fw.clone())
            self.register_buffer("feature_b", fb.clone())
            self.feature_activation = act
            n_feat = fw.shape[1]
        self.n_code_features = n_feat
        self.geometry = geometry
        self.geometry_pool = None
        n_geo = 0
        if geometry is not None:
            k_geo, m = geometry.mask.shape
            if k_geo != n_components:
                raise ValueError(f"geometry has slots for {k_geo} sub-domains, the detector {n_components}")
            if geometry_pool == "linear":
                self.slot_w = nn.Parameter(torch.randn(n_components, 3 * m, geometry_hidden) / (3 * m) ** 0.5)
                self.slot_b = nn.Parameter(torch.zeros(n_components, geometry_hidden))
                n_geo = geometry_hidden
            elif geometry_pool == "deepsets":
                self.phi = _mlp([4, geometry_hidden, geometry_hidden], nn.CELU)
                n_geo = 2 * geometry_hidden
            else:
                raise ValueError(f"geometry_pool={geometry_pool!r}; use 'linear' or 'deepsets'")
            self.geometry_pool = geometry_pool
        self.geometry_hidden = int(geometry_hidden)
        self.n_geometry_features = n_geo
        part_dim = 1 + level2_dim + n_feat + n_geo
        center, half = torch.zeros(latent_dim), torch.ones(latent_dim)
        if (box_lo is None) != (box_hi is None):
            raise ValueError("give both box_lo and box_hi, or neither")
        if box_lo is not None:
            lo, hi = torch.as_tensor(box_lo, dtype=torch.float32), torch.as_tensor(box_hi, dtype=torch.float32)
            if lo.shape != (latent_dim,) or hi.shape != (latent_dim,) or not bool((hi > lo).all()):
                raise ValueError(f"box_lo/box_hi must be ({latent_dim},) with box_hi > box_lo")
            center, half = (lo + hi) / 2, (hi - lo) / 2
        self.register_buffer("center", center)
        self.register_buffer("half_range", half)
        # CSE reads [x, code features, geometry embeddings]: D + K H + K G = K part_dim entries
        self.cse = nn.Sequential(_mlp([n_components * part_dim, hidden, state_dim], nn.CELU), nn.Tanh())
        self.cp = _mlp([state_dim + part_dim, hidden, hidden, 1], nn.CELU)
        self.mlp_c = _mlp([n_components, hidden, 1], nn.CELU)

    @property
    def latent_dim(self) -> int:
        return self.n_components * (1 + self.level2_dim)

    @property
    def output_bias(self) -> torch.nn.Parameter:
        """MLP_c's output bias, where the operating threshold is folded (:mod:`neuralcol.operating`)."""
        return self.mlp_c[-1].bias

    @torch.no_grad()
    def shift_decision(self, threshold: float) -> None:
        """Move the decision threshold to ``logit = threshold``: MLP_c's output bias minus ``threshold``, so that
        ``logit > 0`` (and p > 0.5, the handler's constraint, the cascade's bands) afterwards means what
        ``logit > threshold`` meant before (the operating point, :func:`neuralcol.operating.fold_into`)."""
        self.output_bias.sub_(float(threshold))

    def split(self, z_all: torch.Tensor) -> torch.Tensor:
        """(B, D) -> per-sub-domain inputs (B, K, 1 + d): [z0_i, Z_i]."""
        k, d = self.n_components, self.level2_dim
        z0 = z_all[:, :k, None]  # (B, K, 1)
        if d == 0:
            return z0
        return torch.cat([z0, z_all[:, k:].reshape(-1, k, d)], dim=-1)  # (B, K, 1 + d)

    def forward(self, z_all: torch.Tensor, geometry: torch.Tensor | None = None, *,
                embedding: torch.Tensor | None = None) -> DetectorOutput:
        """Z_all (B, D) [and, for a detector with geometry, the pair features of the meshes (B, P, 3), or their
        embedding (B, K, G) already computed (``embedding=``, :meth:`embed_batch_last`)] -> DetectorOutput.

        Without gradients on the CPU, a batch larger than ``inference_block`` rows runs block by block: the
        (block, K, hidden) intermediates then stay in cache (with the split CP layer of ``_cp``: 1.9x faster at
        batch 4096 on a 2-core machine; ``python -m research.detector_forward RUN_DIR``). The result is the same.
        """
        if z_all.ndim != 2 or z_all.shape[1] != self.latent_dim:
            raise ValueError(f"z_all has shape {tuple(z_all.shape)}, expected (B, {self.latent_dim})")
        if geometry is not None and embedding is not None:
            raise ValueError("pass the pair features (geometry) or their embedding, not both")
        given = geometry if embedding is None else embedding
        if (self.geometry is None) != (given is None):
            raise ValueError("this detector reads the codes only: pass no geometry" if self.geometry is None else
                             "this detector reads the mesh too: pass its pair features (B, P, 3) "
                             "(geometry_of_codes or detector.geometry_of_meshes)")
        if geometry is not None and tuple(geometry.shape) != (len(z_all), self.geometry.n_pairs, 3):
            raise ValueError(f"geometry has shape {tuple(geometry.shape)}, expected ({len(z_all)}, "
                             f"{self.geometry.n_pairs}, 3)")
        if embedding is not None and tuple(embedding.shape) != (len(z_all), self.n_components,
                                                                self.n_geometry_features):
            raise ValueError(f"embedding has shape {tuple(embedding.shape)}, expected ({len(z_all)}, "
                             f"{self.n_components}, {self.n_geometry_features})")
        block = self.inference_block
        if (block and len(z_all) > block and z_all.device.type == "cpu" and not torch.is_grad_enabled()
                and not torch.jit.is_tracing() and not torch.onnx.is_in_onnx_export()):
            outs = [self._forward(z_all[i:i + block], *self._rows(geometry, embedding, i, block))
                    for i in range(0, len(z_all), block)]
            return DetectorOutput(*(torch.cat(t) for t in zip(*outs)))
        return self._forward(z_all, *self._rows(geometry, embedding, 0, len(z_all)))

    @staticmethod
    def _rows(geometry, embedding, start: int, block: int) -> tuple:
        """The rows ``start:start + block`` of the geometry inputs given, as ``_forward``'s extra arguments."""
        if embedding is not None:
            return None, embedding[start:start + block]
        return () if geometry is None else (geometry[start:start + block],)

    def inputs(self, z_all: torch.Tensor, geometry: torch.Tensor | None = None,
               embedding: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Z_all (B, D) [, pair features (B, P, 3) or their embedding (B, K, G)] -> (per-sub-domain inputs of CP
        (B, K, P), input of CSE (B, K P))."""
        x = (z_all - self.center) / self.half_range  # the box -> [-1, 1]
        parts = self.split(x)  # (B, K, 1 + d)
        cse_in = x
        if self.feature_activation is not None:
            h = z_all[:, : self.n_components, None] * self.feature_w + self.feature_b  # (B, K, H), raw codes
            if self.feature_activation == "tanh":
                h = torch.tanh(h)
            parts = torch.cat([parts, h], dim=-1)  # (B, K, 1 + d + H)
            cse_in = torch.cat([cse_in, h.flatten(1)], dim=-1)  # (B, D + K H)
        if geometry is not None:
            embedding = self.geometry_embedding(self.geometry.per_part(geometry.to(x.dtype)))  # (B, K, G)
        if embedding is not None:
            g = embedding.to(x.dtype)
            parts = torch.cat([parts, g], dim=-1)
            cse_in = torch.cat([cse_in, g.flatten(1)], dim=-1)
        return parts, cse_in

    def geometry_embedding(self, geometry: torch.Tensor) -> torch.Tensor:
        """(B, K, M, 3) per-sub-domain pair features -> (B, K, G) (see ``geometry_pool``)."""
        mask = self.geometry.mask[None, :, :, None]  # (1, K, M, 1)
        if self.geometry_pool == "linear":
            x = (geometry * mask).flatten(2)  # (B, K, 3 M)
            return F.celu(torch.einsum("bkm,kmh->bkh", x, self.slot_w) + self.slot_b)
        x = torch.cat([geometry, mask.expand(*geometry.shape[:3], 1).to(geometry)], -1)  # the fill flag
        h = self.phi(x)  # (B, K, M, G)
        hmax = h.masked_fill(~mask, -1e4).amax(2)
        hmax = torch.where(self.geometry.mask.any(1)[None, :, None], hmax, torch.zeros_like(hmax))
        hmean = (h * mask).sum(2) / mask.sum(2).clamp_min(1)
        return torch.cat([hmax, hmean], -1)

    def embed_batch_last(self, feats: torch.Tensor) -> torch.Tensor:
        """Batch-last pair features (3 P, B) (:meth:`~neuralcol.nn.part_geometry.PartGeometry.features_batch_last`)
        -> the geometry embedding (B, K, G): what :meth:`geometry_embedding` gives for the same features, the
        linear pool as one batched product over sub-domains with the batch last."""
        if self.geometry_pool != "linear":
            pair_feats = feats.T.reshape(feats.shape[1], 3, -1).transpose(1, 2)  # (B, P, 3)
            return self.geometry_embedding(self.geometry.per_part(pair_feats))
        x = self.geometry.per_part_batch_last(feats)  # (K, 3 M, B)
        return F.celu(torch.bmm(self.slot_w.transpose(1, 2), x).permute(2, 0, 1) + self.slot_b)

    def embed_vertices_batch_last(self, x: torch.Tensor) -> torch.Tensor:
        """The vertices its pair features read, batch last (V', 3, B) -> the geometry embedding (B, K, G): the
        features in ``x``'s dtype, the embedding in the detector's."""
        return self.embed_batch_last(self.geometry.features_batch_last(x).to(self.center.dtype))

    def geometry_of_meshes(self, vertices: torch.Tensor) -> torch.Tensor:
        """Whole meshes (B, V, 3) -> the pair features (B, P, 3) this detector reads."""
        return self.geometry.pair_features(vertices)

    def _forward(self, z_all: torch.Tensor, geometry: torch.Tensor | None = None,
                 embedding: torch.Tensor | None = None) -> DetectorOutput:
        parts, cse_in = self.inputs(z_all, geometry, embedding)
        s0 = self.cse(cse_in)  # (B, S)
        s = self._cp(s0, parts)  # (B, K)
        logit = self.mlp_c(s)[:, 0]
        return DetectorOutput(torch.sigmoid(logit), logit, s)

    def _cp(self, s0: torch.Tensor, parts: torch.Tensor) -> torch.Tensor:
        """``S_i = CP([S_0, part_i])`` for every sub-domain: (B, S), (B, K, P) -> (B, K).

        The first layer of CP is split by input: ``W [S_0; part_i] + b = (W_s S_0 + b) + W_p part_i``. The S_0
        half is the same for every i, so it is computed once per sample instead of K times (the same function as
        applying ``self.cp`` to the concatenation; tests/test_detector.py compares them).
        """
        layers = iter(self.cp)  # (slicing an nn.Sequential builds a new one per call: slow at batch 1)
        first = next(layers)
        state_dim = s0.shape[-1]
        w = first.weight
        h = F.linear(s0, w[:, :state_dim], first.bias)[:, None, :] + F.linear(parts, w[:, state_dim:])  # (B, K, H)
        for layer in layers:
            h = layer(h)
        return h[..., 0]


def smooth_max(s: torch.Tensor, temperature: float) -> torch.Tensor:
    """Soft maximum over the last axis: ``t * logsumexp(s / t)`` (-> max as t -> 0). (B, K) -> (B,)."""
    return temperature * torch.logsumexp(s / temperature, dim=-1)


BOUNDARY_REDUCTIONS = ("boundary", "batch")  # detector.loss.boundary_reduction (see detector_losses)


class DetectorLosses(NamedTuple):
    """Terms of the detector loss (scalars): total, pd, rank, ce, boundary."""

    total: torch.Tensor
    pd: torch.Tensor
    rank: torch.Tensor
    ce: torch.Tensor
    boundary: torch.Tensor


def detector_losses(out: DetectorOutput, pd: torch.Tensor, pd_sub: torch.Tensor, subset: torch.Tensor,
                    w_pd: float, w_pdsum: float, w_r: float, w_ce: float, w_b: float, margin: float,
                    temperature: float, ce_on_boundary: bool = False,
                    boundary_reduction: str = "boundary") -> DetectorLosses:
    """``L = w_PD L_PD + w_r L_r + w_ce L_ce + w_b L_b`` (paper sec. 4.3) on one batch.

    - ``L_PD = mean_B [ sum_i (S_i - PD_i)^2 + w_PDsum (smax(S) - PD)^2 ]``: PD_i are the labeler's
      per-part depths and PD = max_i PD_i (docs/labels.md), so the aggregate is a smooth max
      (``temperature``) instead of the paper's sum.
    - ``L_r = mean over ordered pairs (a, b) of the batch with PD_a < PD_b of max(0, margin - (smax(S_b) -
      smax(S_a)))``: the predicted depths keep the order of the true ones by at least ``margin``.
    - ``L_ce``: binary cross-entropy of the collision probability on D_p and D_n (subset 0 and 1); with
      ``ce_on_boundary`` on every row, D_b included (their label, ``PD > 0``, is known: without it the shallow
      collisions of D_b are only pulled to p = 0.5 by L_b, and the detector under-calls collisions).
    - ``L_b = mean over D_b (subset 2) of |p - 0.5|`` (paper eq. 3; ``boundary_reduction="boundary"``). With
      ``boundary_reduction="batch"`` the D_b terms are summed and divided by the batch size instead, so a D_b row
      weighs ``w_b / B`` like a cross-entropy row's ``w_ce / B`` rather than ``w_b / |D_b in batch|`` (with the
      paper's eps, D_b is a few rows per thousand: ~100x the weight of a CE row). Not in the paper; a
      diagnostic of supv_bd (docs/studies/boundary_loss_weight.md).

    Args:
        out: detector output for the batch.
        pd: (B,) PD targets (already scaled).
        pd_sub: (B, K) PD_i targets (same scale).
        subset: (B,) int codes 0 = D_p, 1 = D_n, 2 = D_b.
        w_pd, w_pdsum, w_r, w_ce, w_b: weights (paper: 5, 0.2, 2, 2, 0.5).
        margin: ranking margin alpha.
        temperature: smooth-max temperature.
        ce_on_boundary: cross-entropy on D_b rows too (not in the paper; docs/studies/diagnosis_scape.md, cause 4).
        boundary_reduction: "boundary" (paper: mean over the batch's D_b rows) or "batch" (sum / batch size).

    Returns:
        DetectorLosses; terms without samples (e.g. no D_b in the batch) are 0.
    """
    agg = smooth_max(out.s, temperature)  # (B,)
    l_pd = (((out.s - pd_sub) ** 2).sum(-1) + w_pdsum * (agg - pd) ** 2).mean()
    less = pd[:, None] < pd[None, :]  # (B, B): PD_a < PD_b
    n_less = int(less.sum())
    if n_less:
        # the mean over the pairs in ``less`` as a masked sum: boolean indexing of the (B, B) matrix and its
        # backward (nonzero, index, index_put) cost about a third of a training step at batch 1024
        gap = agg[None, :] - agg[:, None]  # smax_b - smax_a
        l_r = (F.relu(margin - gap) * less).sum() / n_less
    else:
        l_r = agg.new_zeros(())
    label_mask = torch.ones_like(subset, dtype=torch.bool) if ce_on_boundary else subset != 2
    if label_mask.any():
        target = (pd[label_mask] > 0).to(out.logit.dtype) if ce_on_boundary else \
            (subset[label_mask] == 0).to(out.logit.dtype)
        l_ce = F.binary_cross_entropy_with_logits(out.logit[label_mask], target)
    else:
        l_ce = agg.new_zeros(())
    bmask = subset == SUBSET_BOUNDARY  # D_b
    if boundary_reduction not in BOUNDARY_REDUCTIONS:
        raise ValueError(f"boundary_reduction={boundary_reduction!r}; use 'boundary' (the paper's) or 'batch'")
    if not bmask.any():
        l_b = agg.new_zeros(())
    elif boundary_reduction == "boundary":
        l_b = (out.prob[bmask] - 0.5).abs().mean()
    else:
        l_b = (out.prob[bmask] - 0.5).abs().sum() / len(subset)
    total = w_pd * l_pd + w_r * l_r + w_ce * l_ce + w_b * l_b
    return DetectorLosses(total, l_pd, l_r, l_ce, l_b)


def decoder_code_features(space) -> tuple[torch.Tensor, torch.Tensor, str] | None:
    """The first layer of the latent space's level-1 decoder, ``(w (K, H), b (K, H), activation)``; None for a
    space without one (a PCA space, ``autoencoder=pca``: its decoder is linear, the codes say it all)."""
    if getattr(space, "net", None) is None:
        return None
    l1 = space.net.level1
    return l1.comp_in_w.detach().cpu().float(), l1.comp_in_b.detach().cpu().float(), l1.activation


def net_widths(net_cfg: dict) -> dict:
    """The detector's widths ``{"state_dim", "hidden"}``: the configured ones times ``width`` (default 1; the
    size sweep's multiplier), rounded, at least 1."""
    w = float(net_cfg.get("width", 1.0))
    return {k: max(1, round(w * int(net_cfg[k]))) for k in ("state_dim", "hidden")}


def detector_for_space(space, state_dim: int, hidden: int, width: float = 1.0, normalize_inputs: bool = True,
                       decoder_features: bool = False, geometry: nn.Module | None = None, geometry_hidden: int = 32,
                       geometry_pool: str = "linear") -> CollisionDetector:
    """A detector for the codes of ``space`` (the ``_target_`` of ``detector.net``; docs/detector.md).

    Args:
        space: the latent space (its sub-domains, box and level-1 decoder).
        state_dim, hidden: widths of S_0 and of the hidden layers, times ``width`` (rounded, at least 1).
        normalize_inputs: map the box Z to [-1, 1] inside the network.
        decoder_features: also feed the level-1 decoder's first layer ``act(z0 w + b)``.
        geometry, geometry_hidden, geometry_pool: the pair features each CP_i also reads (None: codes
            only), see :class:`CollisionDetector`.
    """
    l2 = (space.dim - space.n_parts) // space.n_parts
    box = (space.box_lo.detach().cpu(), space.box_hi.detach().cpu()) if normalize_inputs else (None, None)
    feats = decoder_code_features(space) if decoder_features else None
    widths = net_widths({"state_dim": state_dim, "hidden": hidden, "width": width})
    return CollisionDetector(space.n_parts, l2, **widths, box_lo=box[0], box_hi=box[1], code_features=feats,
                             geometry=geometry, geometry_hidden=int(geometry_hidden), geometry_pool=str(geometry_pool))


def build_detector(space, det: dict, geometry: nn.Module | None = None) -> CollisionDetector:
    """The detector ``det["net"]`` configures (a ``_partial_`` ``_target_`` taking the space) for ``space``; with
    ``geometry`` (a :class:`~neuralcol.nn.part_geometry.PartGeometry`) one that reads the mesh too, its embedding
    as ``det["geometry"]`` sets (``hidden``, ``pool``)."""
    from hydra.utils import instantiate

    if geometry is None:
        return instantiate(det["net"])(space)
    g = det["geometry"]
    return instantiate(det["net"])(space, geometry=geometry, geometry_hidden=int(g["hidden"]),
                                   geometry_pool=str(g["pool"]))


def save_detector(path: Path, net: CollisionDetector, det: dict, method: dict, pd_unit: float) -> None:
    """Write ``detector.pt``: the weights and plain facts only, so it loads with ``weights_only=True``."""
    facts = {"n_components": net.n_components, "level2_dim": net.level2_dim,
             "net": {**{k: v for k, v in det["net"].items() if not k.startswith("_")}, **net_widths(det["net"]),
                     "width": 1.0},  # widths as built
             "method": method["name"], "pd_unit": pd_unit,
             "code_features": None if net.feature_activation is None else
             {"hidden": net.n_code_features, "activation": net.feature_activation},
             "geometry": None if net.geometry is None else
             {"pool": net.geometry_pool, "hidden": int(net.geometry_hidden), "radius": net.geometry.contact.radius,
              "clip": net.geometry.contact.clip, "fixed_slots": int(net.geometry.n_fixed_slots),
              "summaries": None if net.geometry.summary is None else
              {"min_hops": net.geometry.summary.min_hops, "fold_ratio": net.geometry.summary.fold_ratio,
               "max_vertices": net.geometry.summary.max_vertices, "smooth": net.geometry.summary.smooth}}}
    blob = {"state": net.state_dict(), **plain_values(facts, Path(path).name)}
    with atomic_path(path) as tmp:
        torch.save(blob, tmp)


def load_detector(path: str | Path, map_location="cpu") -> tuple[CollisionDetector, dict]:
    """The final detector of a run (``detector.pt``) and its metadata, read without unpickling code.

    Raises:
        UnsafeFileError: the file holds pickled Python objects (not run) or is damaged; the message names it.
    """
    blob = read_torch_file(path, map_location, fix="re-create it with this version of neuralcol (run the run's "
                                                   "command again in a new directory)")
    cf = blob.get("code_features")
    feats = None
    if cf is not None:  # shapes only; the values come with the state dict
        zeros = torch.zeros(blob["n_components"], int(cf["hidden"]))
        feats = (zeros, zeros, cf["activation"])
    geo, gf = None, blob.get("geometry")
    if gf is not None:  # the pairs, faces and slots come with the state dict
        from neuralcol.nn.part_geometry import PartGeometry

        st = blob["state"]
        m = int(gf.get("fixed_slots", st["geometry.slots"].shape[1]))  # the chosen pairs' slots (no summary rows)
        summ = gf.get("summaries")
        if summ is not None:
            summ = {"rest": st["geometry.summary_rest"].numpy(), "faces": st["geometry.summary_faces"].numpy(),
                    "partition": st["geometry.summary_partition"].numpy(), **summ}
        geo = PartGeometry(st["geometry.contact.pairs"].numpy(), st["geometry.slots"][:, :m].numpy(),
                           st["geometry.mask"][:, :m].numpy(), st["geometry.contact.faces"].numpy(),
                           float(gf["radius"]), float(gf["clip"]), summ)
    net = CollisionDetector(blob["n_components"], blob["level2_dim"], state_dim=int(blob["net"]["state_dim"]),
                            hidden=int(blob["net"]["hidden"]), code_features=feats, geometry=geo,
                            geometry_hidden=int(gf["hidden"]) if gf else 32,
                            geometry_pool=gf["pool"] if gf else "linear")
    net.load_state_dict(blob["state"])
    return net, {k: v for k, v in blob.items() if k != "state"}
