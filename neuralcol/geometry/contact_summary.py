"""Per-sub-domain summaries of every close vertex pair of a mesh: contact geometry read where it happens.

:mod:`neuralcol.geometry.contact_pairs` measures a fixed list of vertex pairs, chosen on example meshes; a
collision between two vertices that never came close in those examples is invisible to it. The summaries here read
*every* close pair of the mesh at hand, found anew per mesh (a k-d tree), and pool them per sub-domain, so they do not
depend on which pair closes nor on the parts far from the contact: what a detector needs to carry from the codes it
trained on to the meshes a user brings.

A pair (i, j) is *close* in a mesh ``x`` when ``|x_j - x_i| < radius``, the two vertices lie more than ``min_hops``
edges apart, and ``|x_j - x_i| < fold_ratio * |r_j - r_i|`` (their distance in the rest mesh ``r``): two pieces of
surface that came together, not a surface's own closeness (the rule :func:`close_pair_scores` uses to choose the
fixed pairs). Each close pair counts in the sub-domains of both its vertices. Per sub-domain, :data:`SUMMARIES`:

* ``log_count``: log(1 + the number of close pairs);
* ``min_ratio``: the smallest ``|x_j - x_i| / |r_j - r_i|`` (1 when there is no close pair);
* ``min_dist``: the smallest ``|x_j - x_i| / radius`` (1 when none);
* ``min_offset``: the smallest signed offset along a vertex normal, ``(x_j - x_i) . n_i`` and ``(x_i - x_j) . n_j``,
  over ``radius`` and clipped to ``[-clip, clip]`` (``clip`` when none): negative once a vertex has passed behind
  the other surface, which tells a penetration from a touch.

Symbols: B or N meshes, V vertices, F faces, K sub-domains, S = len(SUMMARIES) summaries.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree

from neuralcol.geometry.contact_pairs import hop_neighbourhood

SUMMARIES = ("log_count", "min_ratio", "min_dist", "min_offset")


def vertex_normals_np(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) unit area-weighted vertex normals of one mesh (zero where a vertex's faces have no area)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # twice the area times the unit normal
    n = np.zeros_like(v)
    for c in range(3):
        np.add.at(n, f[:, c], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


class ContactSummary:
    """The summaries of one topology (its rest mesh, faces and partition), for any number of meshes.

    Args:
        rest: (V, 3) rest mesh. faces: (F, 3) triangles. partition: (V,) sub-domain of each vertex in [0, K).
        n_parts: K. radius: closeness radius, absolute (e.g. 0.02 x the rest mesh's bounding-box diagonal).
        min_hops: pairs within this many edges are never close. fold_ratio: see the module doc.
        clip: the signed offsets' clip, in radii.
    """

    def __init__(self, rest: np.ndarray, faces: np.ndarray, partition: np.ndarray, n_parts: int, radius: float,
                 min_hops: int = 2, fold_ratio: float = 0.5, clip: float = 3.0):
        self.rest = np.asarray(rest, np.float64)
        self.faces = np.asarray(faces, np.int64)
        self.partition = np.asarray(partition, np.int64)
        self.n_parts, self.radius = int(n_parts), float(radius)
        self.fold_ratio, self.clip = float(fold_ratio), float(clip)
        n = len(self.rest)
        if self.partition.shape != (n,) or (n and (self.partition.min() < 0 or self.partition.max() >= n_parts)):
            raise ValueError(f"partition must be ({n},) with values in [0, {n_parts})")
        if not self.radius > 0:
            raise ValueError(f"radius must be > 0, got {radius}")
        near = hop_neighbourhood(self.faces, n, int(min_hops)).tocoo()
        self._near_keys = np.unique(near.row.astype(np.int64) * n + near.col)  # sorted packed keys i * V + j

    @property
    def n_summaries(self) -> int:
        return len(SUMMARIES)

    def close_pairs(self, vertices: np.ndarray) -> np.ndarray:
        """(P, 2) int64 close pairs of one mesh (V, 3), i < j (see the module doc)."""
        v = np.asarray(vertices, np.float64)
        pr = cKDTree(v).query_pairs(self.radius, output_type="ndarray").astype(np.int64)
        if len(pr) == 0:
            return np.zeros((0, 2), np.int64)
        d = np.linalg.norm(v[pr[:, 1]] - v[pr[:, 0]], axis=1)
        d_rest = np.linalg.norm(self.rest[pr[:, 1]] - self.rest[pr[:, 0]], axis=1)
        pr = pr[d < self.fold_ratio * d_rest]  # first: it leaves few of the pairs a surface's own closeness makes
        pr.sort(axis=1)
        keys = pr[:, 0] * len(v) + pr[:, 1]
        at = np.minimum(np.searchsorted(self._near_keys, keys), len(self._near_keys) - 1)
        return pr[self._near_keys[at] != keys]

    def summarize(self, meshes: np.ndarray) -> np.ndarray:
        """(N, K, S) float32 summaries of meshes (N, V, 3) (numpy, no gradients)."""
        meshes = np.asarray(meshes, np.float64)
        if meshes.ndim != 3 or meshes.shape[1:] != self.rest.shape:
            raise ValueError(f"meshes have shape {meshes.shape}, expected (N, {len(self.rest)}, 3)")
        out = np.empty((len(meshes), self.n_parts, self.n_summaries), np.float32)
        for n, v in enumerate(meshes):
            out[n] = self._summarize_one(v, self.close_pairs(v))
        return out

    def _summarize_one(self, v: np.ndarray, pr: np.ndarray) -> np.ndarray:
        k = self.n_parts
        count = np.zeros(k)
        ratio, dist, offset = np.ones(k), np.ones(k), np.full(k, self.clip)
        if len(pr):
            i, j = pr[:, 0], pr[:, 1]
            delta = v[j] - v[i]
            d = np.linalg.norm(delta, axis=1)
            d_rest = np.linalg.norm(self.rest[j] - self.rest[i], axis=1)
            normals = vertex_normals_np(v, self.faces)
            off = np.minimum(np.einsum("pc,pc->p", delta, normals[i]), np.einsum("pc,pc->p", -delta, normals[j]))
            off = np.clip(off / self.radius, -self.clip, self.clip)
            for side in (i, j):
                part = self.partition[side]
                np.add.at(count, part, 1.0)
                np.minimum.at(ratio, part, d / d_rest)
                np.minimum.at(dist, part, d / self.radius)
                np.minimum.at(offset, part, off)
        return np.stack([np.log1p(count), ratio, dist, offset], axis=1)

    def summarize_torch(self, vertices: torch.Tensor) -> torch.Tensor:
        """(B, V, 3) -> (B, K, S) summaries, differentiable in the vertices: each mesh's close pairs are found
        without gradients, then the distances, ratios and offsets of all meshes' pairs are taken in torch at once
        (the count is piecewise constant; each minimum passes its gradient to its pair). Equal to
        :meth:`summarize` up to round-off."""
        if vertices.ndim != 3 or tuple(vertices.shape[1:]) != self.rest.shape:
            raise ValueError(f"vertices have shape {tuple(vertices.shape)}, expected (B, {len(self.rest)}, 3)")
        dtype, device = vertices.dtype, vertices.device
        b, k = len(vertices), self.n_parts
        found = [self.close_pairs(v) for v in vertices.detach().cpu().numpy()]
        mesh = torch.as_tensor(np.repeat(np.arange(b), [len(p) for p in found]), device=device)
        pr = torch.as_tensor(np.concatenate(found) if found else np.zeros((0, 2), np.int64), device=device)
        count = torch.zeros(b * k, dtype=dtype, device=device)
        ratio = torch.ones(b * k, dtype=dtype, device=device)
        dist = torch.ones(b * k, dtype=dtype, device=device)
        offset = torch.full((b * k,), self.clip, dtype=dtype, device=device)
        if len(pr):
            rest = torch.as_tensor(self.rest, dtype=dtype, device=device)
            faces = torch.as_tensor(self.faces, device=device)
            partition = torch.as_tensor(self.partition, device=device)
            i, j = pr[:, 0], pr[:, 1]
            delta = vertices[mesh, j] - vertices[mesh, i]  # (Q, 3)
            d = delta.norm(dim=1)
            d_rest = (rest[j] - rest[i]).norm(dim=1)
            used = torch.unique(mesh)  # vertex normals of the meshes with close pairs only
            x = vertices[used]
            fn = torch.cross(x[:, faces[:, 1]] - x[:, faces[:, 0]], x[:, faces[:, 2]] - x[:, faces[:, 0]], dim=2)
            normals = torch.zeros_like(x)
            for c in range(3):
                normals = normals.index_add(1, faces[:, c], fn)
            normals = normals / normals.norm(dim=2, keepdim=True).clamp_min(torch.finfo(dtype).tiny)
            row = torch.searchsorted(used, mesh)  # each pair's mesh among ``used``
            off = torch.minimum((delta * normals[row, i]).sum(1), (-delta * normals[row, j]).sum(1))
            off = (off / self.radius).clamp(-self.clip, self.clip)
            for side in (i, j):
                slot = mesh * k + partition[side]
                count = count.index_add(0, slot, torch.ones_like(d))
                ratio = ratio.scatter_reduce(0, slot, d / d_rest, "amin")
                dist = dist.scatter_reduce(0, slot, d / self.radius, "amin")
                offset = offset.scatter_reduce(0, slot, off, "amin")
        return torch.stack([torch.log1p(count), ratio, dist, offset], dim=1).view(b, k, len(SUMMARIES))
