"""Per-sub-domain summaries of every close vertex pair of a mesh: contact geometry read where it happens.

:mod:`neuralcol.geometry.contact_pairs` measures a fixed list of vertex pairs, chosen on example meshes; a
collision between two vertices that never came close in those examples is invisible to it. The summaries here read
*every* close pair of the mesh at hand, found anew per mesh (a compiled grid search), and pool them per sub-domain, so
they do not depend on which pair closes nor on the parts far from the contact: what a detector needs to carry from the
codes it trained on to the meshes a user brings.

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
from numba import njit

from neuralcol.geometry.contact_pairs import hop_neighbourhood

SUMMARIES = ("log_count", "min_ratio", "min_dist", "min_offset")


@njit(cache=True)
def _close_pairs_kernel(v, rest, radius, fold_ratio, near_ptr, near_idx):  # pragma: no cover (compiled)
    """Close pairs (i < j) of one mesh: a uniform grid of cell ``radius``, then the distance, the fold rule and the
    hop rule (``near_idx[near_ptr[i]:near_ptr[i + 1]]``, sorted, the vertices near i)."""
    n = v.shape[0]
    lo = v[0].copy()
    for i in range(n):
        for c in range(3):
            lo[c] = min(lo[c], v[i, c])
    cell = np.empty((n, 3), np.int64)
    dims = np.ones(3, np.int64)
    for i in range(n):
        for c in range(3):
            cell[i, c] = int((v[i, c] - lo[c]) / radius)
            dims[c] = max(dims[c], cell[i, c] + 1)
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    n_cells = dims[0] * dims[1] * dims[2]
    start = np.zeros(n_cells + 1, np.int64)  # counting sort: the vertices of cell k are order[start[k]:start[k + 1]]
    for i in range(n):
        start[key[i] + 1] += 1
    for k in range(n_cells):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        order[fill[key[i]]] = i
        fill[key[i]] += 1
    r2, f2 = radius * radius, fold_ratio * fold_ratio
    cap = 4 * n
    out = np.empty((cap, 2), np.int64)
    m = 0
    for i in range(n):
        ci0, ci1, ci2 = cell[i, 0], cell[i, 1], cell[i, 2]
        for o in range(13, 27):  # i's own cell and the 13 after it: each pair of cells once
            a, b, c = ci0 + o // 9 - 1, ci1 + (o // 3) % 3 - 1, ci2 + o % 3 - 1
            if a < 0 or b < 0 or c < 0 or a >= dims[0] or b >= dims[1] or c >= dims[2]:
                continue
            k = (a * dims[1] + b) * dims[2] + c
            for s in range(start[k], start[k + 1]):
                j = order[s]
                if o == 13 and j <= i:
                    continue
                d2 = 0.0
                for e in range(3):
                    t = v[j, e] - v[i, e]
                    d2 += t * t
                if d2 >= r2:
                    continue
                q2 = 0.0
                for e in range(3):
                    u = rest[j, e] - rest[i, e]
                    q2 += u * u
                if d2 >= f2 * q2:
                    continue
                lo_n, hi_n = near_ptr[i], near_ptr[i + 1]
                at = lo_n + np.searchsorted(near_idx[lo_n:hi_n], j)
                if at < hi_n and near_idx[at] == j:
                    continue
                if m == cap:
                    grown = np.empty((2 * cap, 2), np.int64)
                    grown[:m] = out[:m]
                    out, cap = grown, 2 * cap
                out[m, 0] = min(i, j)
                out[m, 1] = max(i, j)
                m += 1
    return out[:m]


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
        self.min_hops, self.fold_ratio, self.clip = int(min_hops), float(fold_ratio), float(clip)
        n = len(self.rest)
        if self.partition.shape != (n,) or (n and (self.partition.min() < 0 or self.partition.max() >= n_parts)):
            raise ValueError(f"partition must be ({n},) with values in [0, {n_parts})")
        if not self.radius > 0:
            raise ValueError(f"radius must be > 0, got {radius}")
        near = hop_neighbourhood(self.faces, n, self.min_hops).tocsr()
        near.sort_indices()
        self._near_ptr = near.indptr.astype(np.int64)  # vertices within min_hops edges of i: sorted, CSR
        self._near_idx = near.indices.astype(np.int64)
        corner = np.argsort(self.faces.ravel(), kind="stable")  # the faces around each vertex, CSR
        self._vf_idx = corner // 3
        self._vf_ptr = np.concatenate([[0], np.cumsum(np.bincount(self.faces.ravel(), minlength=n))])

    @property
    def n_summaries(self) -> int:
        return len(SUMMARIES)

    def close_pairs(self, vertices: np.ndarray) -> np.ndarray:
        """(P, 2) int64 close pairs of one mesh (V, 3), i < j, in the grid search's order (see the module doc; a
        compiled search of a uniform grid of cell ``radius``, about 0.5 ms on 2 500 vertices)."""
        v = np.ascontiguousarray(vertices, dtype=np.float64)
        if v.shape != self.rest.shape:
            raise ValueError(f"vertices have shape {v.shape}, expected {self.rest.shape}")
        if not np.isfinite(v).all():
            raise ValueError("vertices hold NaN or infinite values")
        return _close_pairs_kernel(v, self.rest, self.radius, self.fold_ratio, self._near_ptr, self._near_idx)

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
            partition = torch.as_tensor(self.partition, device=device)
            i, j = pr[:, 0], pr[:, 1]
            delta = vertices[mesh, j] - vertices[mesh, i]  # (Q, 3)
            d = delta.norm(dim=1)
            d_rest = (rest[j] - rest[i]).norm(dim=1)
            normal_of = self._pair_normals(vertices, mesh.cpu().numpy(), pr.cpu().numpy())
            off = torch.minimum((delta * normal_of[0]).sum(1), (-delta * normal_of[1]).sum(1))
            off = (off / self.radius).clamp(-self.clip, self.clip)
            for side in (i, j):
                slot = mesh * k + partition[side]
                count = count.index_add(0, slot, torch.ones_like(d))
                ratio = ratio.scatter_reduce(0, slot, d / d_rest, "amin")
                dist = dist.scatter_reduce(0, slot, d / self.radius, "amin")
                offset = offset.scatter_reduce(0, slot, off, "amin")
        return torch.stack([torch.log1p(count), ratio, dist, offset], dim=1).view(b, k, len(SUMMARIES))

    def _pair_normals(self, vertices: torch.Tensor, mesh: np.ndarray, pr: np.ndarray) -> tuple[torch.Tensor, ...]:
        """The unit area-weighted vertex normals (differentiable) at both ends of every pair, (Q, 3) each: only
        the faces around those vertices are read."""
        n_vert = len(self.rest)
        keys = np.concatenate([mesh * n_vert + pr[:, 0], mesh * n_vert + pr[:, 1]])
        need, back = np.unique(keys, return_inverse=True)  # (mesh, vertex) pairs whose normal is read
        nm, nv = need // n_vert, need % n_vert
        deg = self._vf_ptr[nv + 1] - self._vf_ptr[nv]
        owner = np.repeat(np.arange(len(need)), deg)
        at = np.arange(len(owner)) - np.repeat(np.cumsum(deg) - deg, deg)
        fid = self._vf_idx[self._vf_ptr[nv][owner] + at]
        device = vertices.device
        tri = torch.as_tensor(self.faces[fid], device=device)  # (T, 3)
        m = torch.as_tensor(nm[owner], device=device)
        a, b, c = (vertices[m, tri[:, q]] for q in range(3))
        fn = torch.cross(b - a, c - a, dim=1)  # twice the area times the unit normal
        n = torch.zeros(len(need), 3, dtype=vertices.dtype, device=device).index_add(
            0, torch.as_tensor(owner, device=device), fn)
        n = n / n.norm(dim=1, keepdim=True).clamp_min(torch.finfo(vertices.dtype).tiny)
        back = torch.as_tensor(back, device=device)
        return n[back[:len(pr)]], n[back[len(pr):]]
