"""Standalone forms of a run's decoder and detector, for TorchScript and ONNX export (experiments/export.py).

* :class:`DecoderExport`: codes ``(B, D)`` -> vertices ``(B, V, 3)`` (``output="vertices"``), or the raw ACAP
  features ``(B, V, 9)`` (``output="features"``). The vertex form replaces the ACAP inverse's sparse LU solve
  (SciPy, not exportable) by one dense float64 matrix ``M (V, V)``: the pinned-Laplacian inverse with the
  anchor row inserted and the centroid removed, so ``p = M b + centroid`` is the same linear map as
  :meth:`neuralcol.geometry.acap.ACAP.decode`. ``M`` costs ``8 V^2`` bytes (50 MB at V = 2 514).
* :class:`DetectorExport`: codes ``(B, D)`` -> (prob ``(B,)``, pd ``(B,)``): the collision probability and
  the detector's PD estimate in mesh units (``pd_unit * smooth_max(S, temperature)``).

Both are plain ``nn.Module`` s holding copies of the run's weights; their forward passes use only tensor ops
that ``torch.jit.trace`` and ``torch.onnx.export`` handle.
"""

from __future__ import annotations

import copy

import numpy as np
import torch
from torch import nn

from neuralcol.geometry.acap import rotvec_to_matrix, split_features, sym_from_entries
from neuralcol.nn.detector import CollisionDetector, smooth_max
from neuralcol.nn.latent_space import LatentSpace

DECODER_OUTPUTS = ("vertices", "features")


def dense_acap_inverse(space: LatentSpace) -> torch.Tensor:
    """The ACAP inverse's solve as a dense matrix: ``M (V, V)`` float64 with ``p = M b + centroid``.

    ``b (V, 3)`` is the right-hand side of :meth:`ACAP.decode`; the anchor vertex is pinned (its column of M is
    0) and every column sums to 0 (the decoded mesh's centroid is added afterwards).
    """
    acap = space.acap
    n = acap.n_vertices
    keep = acap._keep.numpy()
    inv = acap._lu.solve(np.eye(n - 1))  # (V-1, V-1) pinned-Laplacian inverse
    m = np.zeros((n, n))
    m[np.ix_(keep, keep)] = inv
    return torch.from_numpy(m - m.mean(0, keepdims=True))  # (V, V): centroid removed


def incidence_table(edges: np.ndarray, n_vertices: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Edges incident to each vertex, padded: (index (V, M) long into the E edges, E = padding; sign (V, M) float32:
    +1 where the vertex is the edge's first end, -1 where it is the second, 0 for padding). edges: (E, 2)."""
    ends = np.concatenate([edges[:, 0], edges[:, 1]])
    eid = np.concatenate([np.arange(len(edges))] * 2)
    sgn = np.concatenate([np.ones(len(edges)), -np.ones(len(edges))])
    order = np.argsort(ends, kind="stable")
    ends, eid, sgn = ends[order], eid[order], sgn[order]
    count = np.bincount(ends, minlength=n_vertices)
    slot = np.arange(len(ends)) - np.repeat(np.cumsum(count) - count, count)  # position within its vertex's row
    index = np.full((n_vertices, int(count.max())), len(edges), dtype=np.int64)
    sign = np.zeros(index.shape, dtype=np.float32)
    index[ends, slot], sign[ends, slot] = eid, sgn
    return torch.from_numpy(index), torch.from_numpy(sign)


class DecoderExport(nn.Module):
    """Codes (B, D) -> vertices (B, V, 3) or raw ACAP features (B, V, 9), float32.

    Args:
        space: the run's latent space (its network is copied).
        output: ``"vertices"`` (dense ACAP inverse, see the module docstring) or ``"features"``.
    """

    def __init__(self, space: LatentSpace, output: str = "vertices"):
        super().__init__()
        if output not in DECODER_OUTPUTS:
            raise ValueError(f"output={output!r}; use one of {DECODER_OUTPUTS}")
        self.output = output
        # a PCA space (autoencoder=pca) has no network: its decoder is mean + z W
        self.basis = getattr(space, "basis", None) if getattr(space, "net", None) is None else None
        acap = space.acap
        self.n_vertices = acap.n_vertices
        if self.basis is not None:
            if self.basis == "vertex" and output == "features":
                raise ValueError("a vertex-PCA latent space decodes to vertices, not ACAP features; export it with "
                                 "output='vertices'")
            self.register_buffer("pca_mean", space.pca_mean.detach().cpu().float().clone())
            self.register_buffer("pca_components", space.pca_components.detach().cpu().float().clone())
            self.register_buffer("rest_centroid", space.rest_vertices.detach().cpu().mean(0).float().clone())
        else:
            self.net = copy.deepcopy(space.net).cpu().float().eval()
            self.register_buffer("norm_center", space.norm_center.detach().cpu().float().clone())
            self.register_buffer("norm_half_range", space.norm_half_range.detach().cpu().float().clone())
            self.norm_bound = float(space.norm_bound)
        if output == "vertices" and self.basis != "vertex":
            self.register_buffer("edge_i", acap._edge_i.clone())
            self.register_buffer("edge_j", acap._edge_j.clone())
            incident, sign = incidence_table(acap.edges, acap.n_vertices)
            self.register_buffer("incident", incident)  # (V, M)
            self.register_buffer("incident_sign", sign)  # (V, M)
            self.register_buffer("edge_vec_w", acap._edge_vec_w.float().clone())  # (E, 3)
            self.register_buffer("solve", dense_acap_inverse(space))  # (V, V) float64
            self.register_buffer("centroid", torch.as_tensor(acap._rest_centroid, dtype=torch.float64))

    def features(self, z_all: torch.Tensor) -> torch.Tensor:
        """(B, D) -> raw ACAP features (B, V, 9), as :meth:`LatentSpace.decode_features`."""
        if self.basis == "acap":
            return (self.pca_mean + z_all @ self.pca_components).view(z_all.shape[0], self.n_vertices, 9)
        return self.net.decode(z_all) / self.norm_bound * self.norm_half_range + self.norm_center

    def forward(self, z_all: torch.Tensor) -> torch.Tensor:
        if self.basis == "vertex":
            return (self.pca_mean + z_all @ self.pca_components).view(z_all.shape[0], self.n_vertices, 3) \
                + self.rest_centroid
        feats = self.features(z_all)
        if self.output == "features":
            return feats
        rv, sym = split_features(feats)
        t = rotvec_to_matrix(rv) @ sym_from_entries(sym)  # (B, V, 3, 3)
        g = 0.5 * ((t[:, self.edge_i] + t[:, self.edge_j]) @ self.edge_vec_w[None, :, :, None])[..., 0]  # (B, E, 3)
        # b_i = sum of +g over the edges (i, j), -g over the edges (j, i): a gather, not index_add (the ONNX
        # exporter turns index_add with repeated indices into a scatter that overwrites)
        g = torch.cat([g, torch.zeros_like(g[:, :1])], dim=1)  # (B, E + 1, 3), row E = 0 pads the table
        b = (g[:, self.incident] * self.incident_sign[..., None]).sum(2)  # (B, V, 3)
        p = torch.matmul(self.solve, b.double()) + self.centroid  # (B, V, 3)
        return p.float()


class DetectorExport(nn.Module):
    """Codes (B, D) -> (prob (B,), pd (B,)): collision probability and PD estimate in mesh units, float32.

    Args:
        detector: the run's detector (copied). pd_unit: its PD unit. temperature: its smooth-max temperature.
    """

    def __init__(self, detector: CollisionDetector, pd_unit: float, temperature: float):
        super().__init__()
        self.net = copy.deepcopy(detector).cpu().float().eval()
        self.pd_unit = float(pd_unit)
        self.temperature = float(temperature)

    def forward(self, z_all: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.net(z_all)
        return out.prob, smooth_max(out.s, self.temperature) * self.pd_unit
