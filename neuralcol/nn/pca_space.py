"""A linear latent space: PCA of the meshes' vertex positions or of their ACAP features.

Two roles:

* the **reference** every run reports next to the autoencoder (as the majority class stands next to accuracy):
  PCA at the same |Z_all|, fit on the same training meshes, its train and held-out vertex errors and how often its
  round trip keeps a realistic mesh's exact label;
* a **latent space** of its own (``autoencoder=pca``): :class:`PCALatentSpace` has the interface of
  :class:`~neuralcol.nn.latent_space.LatentSpace` (encode, decode, decode_vertices, box, U(Z), sub-domains, save and
  load), so the detector, the active learning, the handler and ``resolve`` run on it unchanged.

Codes are the (unwhitened) principal-component coordinates ``z = (x - mean) W^T`` with ``x`` the centred vertex
positions (``basis="vertex"``) or the raw ACAP features (``basis="acap"``) flattened; ``decode`` is
``mean + z W`` (then the ACAP inverse for ``basis="acap"``). Sub-domains (for PD_i and the detector's CP_i) are a
spatial clustering of the rest mesh, as the attention of the bilevel autoencoder starts from.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from neuralcol.errors import UserInputError
from neuralcol.geometry.acap import FEATURE_DIM
from neuralcol.nn.latent_box import LatentBox
from neuralcol.utils.files import atomic_path
from neuralcol.utils.safe_files import plain_values

BASES = ("vertex", "acap")


class PCABasis(NamedTuple):
    """A principal-component basis of rows ``x (N, P)``.

    Attributes:
        mean: (P,) float64 mean of the fitted rows.
        components: (D, P) float64 orthonormal principal directions, largest variance first.
        singular_values: (D,) float64.
    """

    mean: np.ndarray
    components: np.ndarray
    singular_values: np.ndarray


def fit_pca(x: np.ndarray, dim: int) -> PCABasis:
    """The first ``dim`` principal components of the rows ``x (N, P)`` (centred on their mean).

    Raises:
        UserInputError (a ValueError): ``dim`` exceeds what ``N`` rows can span (``N - 1``).
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"x has shape {x.shape}, expected (N, P)")
    if not 1 <= dim <= len(x) - 1:
        raise UserInputError(f"a PCA of {len(x)} training meshes spans at most {len(x) - 1} dimensions, asked for "
                             f"{dim}; lower dataset.latent.n_components (or level2_dim), or train on more meshes")
    mean = x.mean(0)
    _, s, vt = np.linalg.svd(x - mean, full_matrices=False)
    return PCABasis(mean, vt[:dim].copy(), s[:dim].copy())


def centred_vertices(vertices) -> np.ndarray:
    """(N, V, 3) -> (N, V*3) float64 rows with each mesh's centroid removed."""
    v = np.asarray(vertices, dtype=np.float64)
    return (v - v.mean(1, keepdims=True)).reshape(len(v), -1)


class PCALatentSpace(LatentBox):
    """A PCA latent space with the interface of :class:`~neuralcol.nn.latent_space.LatentSpace`.

    Args:
        basis: ``"vertex"`` or ``"acap"``: what the components span.
        pca: the fitted basis (``components (D, P)``, P = V*3 or V*9).
        rest_vertices: (V, 3) ACAP rest mesh (its centroid places decoded meshes; the ACAP inverse for "acap").
        faces: (F, 3) triangles.
        acap_kwargs: keyword arguments of :class:`ACAP`.
        n_components: K, the number of sub-domains; ``D = K * (1 + d)`` splits into [Z_0, Z_1..Z_K] as the
            bilevel space's codes do (the detector's CP_i read one block each).
        box_lo, box_hi: (D,) the sampling box Z.
        partition: (V,) long sub-domain of each vertex.
        meta: JSON-able facts.
    """

    def __init__(self, basis: str, pca: PCABasis, rest_vertices, faces, acap_kwargs: dict, n_components: int,
                 box_lo: torch.Tensor, box_hi: torch.Tensor, partition: torch.Tensor, meta: dict | None = None):
        super().__init__()
        if basis not in BASES:
            raise ValueError(f"basis={basis!r}; use one of {BASES}")
        d = len(pca.components)
        if d % n_components:
            raise ValueError(f"{d} components do not split into {n_components} sub-domain blocks")
        self.basis = basis
        self.net = None  # no network: decoder_code_features() and the export know this
        self.n_components = int(n_components)
        self._register_mesh_and_box(rest_vertices, faces, acap_kwargs, box_lo, box_hi, partition, meta)
        self.register_buffer("pca_mean", torch.as_tensor(pca.mean, dtype=torch.float64).clone())
        self.register_buffer("pca_components", torch.as_tensor(pca.components, dtype=torch.float64).clone())
        self.register_buffer("pca_singular_values", torch.as_tensor(pca.singular_values, dtype=torch.float64).clone())

    # ------------------------------------------------------------------ facts
    @property
    def n_parts(self) -> int:
        return self.n_components

    @property
    def channels(self) -> int:
        """3 (vertex positions) or 9 (ACAP features) per vertex."""
        return 3 if self.basis == "vertex" else FEATURE_DIM

    def blocks(self) -> list[slice]:
        k, d = self.n_components, (self.dim - self.n_components) // self.n_components
        return [slice(0, k)] + ([slice(k + i * d, k + (i + 1) * d) for i in range(k)] if d else [])

    # ------------------------------------------------------------------ maps
    def rows(self, vertices: torch.Tensor) -> torch.Tensor:
        """Meshes (B, V, 3) -> the rows the basis spans (B, V*C) float64 (centred vertices or ACAP features)."""
        v = vertices.detach().to(torch.float64).cpu()
        if self.basis == "vertex":
            return (v - v.mean(1, keepdim=True)).flatten(1)
        return self.acap.encode(v).flatten(1)

    def encode(self, vertices: torch.Tensor) -> torch.Tensor:
        """Meshes (B, V, 3) -> Z_all (B, D) float32 (the projection onto the components).

        For ``basis="vertex"``, ``(v - centroid(v) - mean) W^T`` as one product ``v_flat A - c`` with
        ``A = W^T - 1_V S / V`` (``S`` (3, D) the components summed over the vertices: the centroid's share folded
        into the map) and ``c = mean W^T``, both computed once: one pass over the meshes, no mesh-sized
        subtraction (~3x faster on SCAPE meshes; the same to round-off in float64)."""
        comp = self.pca_components.cpu()
        if self.basis != "vertex":
            return ((self.rows(vertices) - self.pca_mean.cpu()) @ comp.T).to(self.box_lo)
        a, c = self._vertex_projection()
        return (vertices.detach().to(torch.float64).cpu().flatten(1) @ a - c).to(self.box_lo)

    def _vertex_projection(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(A (3 V, D), c (D,))`` of :meth:`encode` for ``basis="vertex"``, float64 on the CPU (cached)."""
        key = tuple((t.data_ptr(), t._version) for t in (self.pca_components, self.pca_mean))  # (a reloaded basis)
        cached = getattr(self, "_projection", None)
        if cached is None or cached[0] != key:
            comp = self.pca_components.detach().cpu()
            n_vertices = comp.shape[1] // 3
            per_coordinate = comp.view(len(comp), -1, 3).sum(1).T  # (3, D)
            a = comp.T - per_coordinate.repeat(n_vertices, 1) / n_vertices
            cached = self._projection = (key, a.contiguous(), self.pca_mean.detach().cpu() @ comp.T)
        return cached[1], cached[2]

    def _linear(self, z_all: torch.Tensor, cols=None) -> torch.Tensor:
        """``mean + z W`` in ``z_all``'s dtype and device, over the columns ``cols`` (all: None)."""
        mean, comp = self.pca_mean, self.pca_components
        if cols is not None:
            mean, comp = mean[cols], comp[:, cols]
        return mean.to(z_all) + z_all @ comp.to(z_all)

    def decode_features(self, z_all: torch.Tensor) -> torch.Tensor:
        """Z_all (B, D) -> raw ACAP features (B, V, 9): differentiable for ``basis="acap"``; for ``"vertex"`` the
        features of the decoded meshes (no gradient)."""
        if self.basis == "acap":
            return self._linear(z_all).view(z_all.shape[0], -1, FEATURE_DIM)
        with torch.no_grad():
            return self.acap.encode(self.decode(z_all).detach().to(torch.float64).cpu()).to(z_all)

    def decode(self, z_all: torch.Tensor) -> torch.Tensor:
        """Z_all (B, D) -> vertices (B, V, 3), differentiable, same dtype and device as ``z_all``."""
        if z_all.ndim != 2 or z_all.shape[1] != self.dim:
            raise ValueError(f"z_all has shape {tuple(z_all.shape)}, expected (B, {self.dim})")
        if self.basis == "acap":
            return self.acap.decode(self.decode_features(z_all)).to(z_all.dtype)
        centroid = self.rest_vertices.mean(0).to(z_all)
        return self._linear(z_all).view(z_all.shape[0], -1, 3) + centroid

    def decode_vertices(self, z_all: torch.Tensor, idx) -> torch.Tensor:
        """Z_all (B, D) -> positions of the vertices ``idx`` (B, K, 3), ``decode(z_all)[:, idx]`` to round-off."""
        if z_all.ndim != 2 or z_all.shape[1] != self.dim:
            raise ValueError(f"z_all has shape {tuple(z_all.shape)}, expected (B, {self.dim})")
        if self.basis == "acap":
            feats = self.decode_features(z_all)
            return self.acap.decode_vertices(feats, idx).to(z_all.dtype)
        idx = torch.as_tensor(np.asarray(idx), dtype=torch.long).reshape(-1)
        cols = (idx[:, None] * 3 + torch.arange(3)).reshape(-1).to(self.pca_mean.device)
        centroid = self.rest_vertices.mean(0).to(z_all)
        return self._linear(z_all, cols).view(z_all.shape[0], -1, 3) + centroid

    def vertex_decoder(self, idx):
        """A function ``z (B, D) -> (V', 3, B)``: :meth:`decode_vertices` of the vertices ``idx`` with the batch
        last (:func:`~neuralcol.nn.part_geometry.vertex_decoder`). For ``basis="vertex"`` one product
        ``W_idx^T z^T + (mean + centroid)`` with the basis columns taken once here; for ``"acap"`` the decode and
        a transpose."""
        idx = torch.as_tensor(np.asarray(idx), dtype=torch.long).reshape(-1)
        if self.basis != "vertex":
            return lambda z: self.decode_vertices(z, idx).permute(1, 2, 0)
        return LinearVertexDecoder(self, idx)

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | Path) -> Path:
        """Save the basis, box, partition and facts to one file of tensors and plain values."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        facts = plain_values({"kind": "pca", "basis": self.basis, "n_components": self.n_components,
                              "acap_kwargs": self.acap_kwargs, "meta": self.meta}, path.name)
        with atomic_path(path) as tmp:
            torch.save({**facts, "state": self.state_dict()}, tmp)
        return path

    @classmethod
    def from_blob(cls, blob: dict) -> PCALatentSpace:
        """The space of a file written by :meth:`save` (read by :meth:`LatentSpace.load`)."""
        s = blob["state"]
        pca = PCABasis(s["pca_mean"].numpy(), s["pca_components"].numpy(), s["pca_singular_values"].numpy())
        return cls(blob["basis"], pca, s["rest_vertices"].numpy(), s["faces"].numpy(), blob["acap_kwargs"],
                   int(blob["n_components"]), s["box_lo"], s["box_hi"], s["partition"], blob["meta"])


def pca_space(basis: str, vertices: np.ndarray, features: np.ndarray | None, train_idx: np.ndarray, dim: int,
              rest_vertices, faces, acap_kwargs: dict, n_components: int, partition, box_margin: float = 0.0,
              meta: dict | None = None) -> PCALatentSpace:
    """Fit a PCA latent space on the training meshes; its box spans their codes (widened by ``box_margin``).

    Args:
        basis: ``"vertex"`` or ``"acap"``.
        vertices: (N, V, 3) the data set's meshes. features: (N, V, 9) their raw ACAP features (for "acap").
        train_idx: (N_train,) the meshes the basis and the box are fit on.
        dim: D = |Z_all|.
        rest_vertices, faces, acap_kwargs: the ACAP transform's rest mesh, triangles and settings.
        n_components: K sub-domains; partition: (V,) their vertices.
        box_margin: fraction of each side the box is widened by on both ends.
    """
    if basis not in BASES:
        raise ValueError(f"basis={basis!r}; use one of {BASES}")
    train_idx = np.asarray(train_idx)
    if basis == "vertex":
        rows = centred_vertices(np.asarray(vertices)[train_idx])
    else:
        if features is None:
            raise ValueError("basis='acap' needs the ACAP features")
        f = np.asarray(features, dtype=np.float64)[train_idx]
        rows = f.reshape(len(f), -1)
    pca = fit_pca(rows, dim)
    z = torch.as_tensor((rows - pca.mean) @ pca.components.T, dtype=torch.float32)
    lo, hi = z.amin(0), z.amax(0)
    margin = float(box_margin) * (hi - lo)
    return PCALatentSpace(basis, pca, rest_vertices, faces, acap_kwargs, n_components, lo - margin, hi + margin,
                          torch.as_tensor(np.asarray(partition)), meta)


class LinearVertexDecoder:
    """``z (B, D) -> (V', 3, B)``, the vertices ``idx`` of a vertex-basis PCA space, batch last: ``W^T z^T + c``
    with ``W`` its components' columns of those vertices and ``c`` the mean's plus the rest centroid, both taken
    once (float64 and float32 copies, on the space's device; moved to ``z``'s device on first use there)."""

    def __init__(self, space: PCALatentSpace, idx: torch.Tensor):
        cols = (idx[:, None] * 3 + torch.arange(3)).reshape(-1).to(space.pca_mean.device)
        centroid = space.rest_vertices.mean(0).to(torch.float64).repeat(len(idx)).to(space.pca_mean.device)
        w = space.pca_components[:, cols].T.contiguous()  # (3 V', D)
        c = (space.pca_mean[cols] + centroid)[:, None].contiguous()  # (3 V', 1)
        self._weights = {torch.float64: (w, c), torch.float32: (w.float(), c.float())}

    def __call__(self, z: torch.Tensor) -> torch.Tensor:
        w, c = self._weights.get(z.dtype) or self._weights[torch.float64]
        if w.device != z.device:
            w, c = w.to(z.device), c.to(z.device)
            self._weights[z.dtype] = (w, c)
        return torch.addmm(c.to(z.dtype), w.to(z.dtype), z.T).view(-1, 3, len(z))
