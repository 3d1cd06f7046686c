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

These jump when a pair enters or leaves the close set. The smooth form (``smooth=True``) weights each pair by how close
it is, ``w = 1 - max(d / radius, d / (fold_ratio d_rest))``, and pulls each minimum toward its value by w (see
:class:`ContactSummary`): every summary is then continuous in the vertices.

Cost. One compiled pass per mesh finds the close pairs (a hashed uniform grid: memory O(V) however far the vertices
spread), measures them and keeps, for each minimum, the pair behind it; with gradients only those pairs (at most 3 K a
mesh, of the thousands a deep collision has) are measured again in torch. An optimiser that asks about the same meshes
again and again (the handler, the projector) runs inside :func:`reusing_neighbours`, where each mesh's candidates
within a skin are kept and reused while it moves less than half the skin (:class:`NeighbourLists`; same results). On a
mesh with more than ``max_vertices`` vertices the pairs are those among that many vertices spread evenly.

Symbols: B or N meshes, V vertices, F faces, K sub-domains, S = len(SUMMARIES) summaries.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import torch

from neuralcol.geometry.contact_pairs import hop_neighbourhood
from neuralcol.geometry.contact_summary_kernels import (
    batch_pairs,
    match_kernel,
    sample_pairs,
    soft_count_grad,
    summaries_kernel,
    summaries_of_candidates,
)

SUMMARIES = ("log_count", "min_ratio", "min_dist", "min_offset")

_REUSING = [0]  # how many reusing_neighbours() blocks are open


@contextmanager
def reusing_neighbours() -> Iterator[None]:
    """Within this block the summaries keep each mesh's candidate pairs and reuse them for meshes that come back
    barely moved (:class:`NeighbourLists`): for optimisers (the handler, the projector) that ask about the same
    meshes again and again. Same results, less time; outside it every mesh is searched anew (nothing is kept)."""
    _REUSING[0] += 1
    try:
        yield
    finally:
        _REUSING[0] -= 1


def _on_every_core(kernel, *args):
    """Run a numba kernel whose meshes run in parallel, then give torch back its intra-op thread count: numba's
    OpenMP layer sets the process's OpenMP thread count, which torch reads as its own, and a run pins torch's count
    for numbers that repeat on every machine (:mod:`neuralcol.utils.threads`)."""
    threads = torch.get_num_threads()
    try:
        return kernel(*args)
    finally:
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)


class NeighbourLists:
    """Candidate pairs kept for meshes that come back barely moved: a neighbour list with a skin (a Verlet list).

    An optimiser (the handler, the projector) asks for the summaries of the same few hundred meshes again and
    again, each moved a little. For a mesh ``x`` the list keeps ``x`` and every pair that passes the closeness
    rule loosened by ``skin`` (distance below ``radius + skin``, below ``fold_ratio`` times the rest distance plus
    ``skin``). A later mesh ``y`` whose every vertex lies within ``skin / 2`` of ``x``'s changes each pair's
    distance by less than ``skin``, so its close pairs are among those candidates: they are filtered by the exact
    rule instead of searched anew. The answer is the same as a fresh search; only the time differs.

    Args:
        summary: the :class:`ContactSummary` served. skin: in units of its radius.
        max_bytes: memory kept for the stored meshes and their candidates (the oldest unused go first).
    """

    n_signature = 32  # vertices compared first to find the stored mesh nearest a new one

    def __init__(self, summary: ContactSummary, skin: float = 0.5, max_bytes: int = 64 << 20):
        self.summary, self.skin = summary, float(skin) * summary.radius
        n = len(summary.rest)
        self.capacity = max(1, min(1024, int(max_bytes) // max(1, 40 * n)))
        self._sig = np.unique(np.linspace(0, n - 1, min(n, self.n_signature)).astype(np.int64))
        self.clear()

    def clear(self) -> None:
        """Forget every stored mesh."""
        self.__dict__.update(self._empty())

    def _empty(self) -> dict:
        n = len(self.summary.rest)
        return {"_meshes": np.empty((0, n, 3)),  # grown by doubling up to the capacity
                "_sigs": np.empty((0, len(self._sig) * 3)), "_cands": [], "_used": np.empty(0, np.int64),
                "_last": np.empty(0, np.int64),  # the stored mesh each row of the last call used
                "_clock": 0, "searches": 0, "reuses": 0}

    def __getstate__(self):  # copies and pickles start empty (the stored meshes are a cache)
        return {**self.__dict__, **self._empty()}

    def candidates(self, vs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Meshes (B, V, 3) -> (candidates (Q, 2), offsets (B + 1,)): mesh m's candidates are
        ``candidates[offsets[m]:offsets[m + 1]]``, stored ones where it lies within ``skin / 2`` of a stored mesh,
        else found by a fresh search (and stored)."""
        s, half2 = self.summary, (self.skin / 2) ** 2
        self._clock += 1
        b, c = len(vs), len(self._cands)
        guess = np.full(b, -1, np.int64)  # first the mesh the same row used last time
        guess[:min(b, len(self._last))] = self._last[:b]
        pick = match_kernel(vs, self._meshes, self._sigs, self._sig, c, guess, half2)
        found = []
        for m in range(b):
            if pick[m] >= 0:
                self._used[pick[m]] = self._clock
                found.append(self._cands[pick[m]])
                self.reuses += 1
                continue
            cand = sample_pairs(vs[m], s.sample, s._rest_sample, s.radius + self.skin, s.fold_ratio, s._near_ptr,
                                s._near_idx, self.skin)
            found.append(cand)
            pick[m] = self._store(vs[m], cand)
            self.searches += 1
        self._last = pick
        offsets = np.concatenate([[0], np.cumsum([len(f) for f in found])]).astype(np.int64)
        cand = np.concatenate(found) if found else np.zeros((0, 2), np.int64)
        return cand.astype(np.int64, copy=False), offsets

    def _store(self, mesh: np.ndarray, cand: np.ndarray) -> int:
        """Store a mesh and its candidates; returns its index."""
        c = len(self._cands)
        if c >= self.capacity:  # the one unused longest makes room
            e = int(np.argmin(self._used))
            self._cands[e] = cand
        else:
            if c == len(self._meshes):
                grow = min(self.capacity, max(16, 2 * c))
                self._meshes = np.concatenate([self._meshes, np.empty((grow - c, *mesh.shape))])
                self._sigs = np.concatenate([self._sigs, np.empty((grow - c, self._sigs.shape[1]))])
                self._used = np.concatenate([self._used, np.zeros(grow - c, np.int64)])
            e = c
            self._cands.append(cand)
        self._meshes[e] = mesh
        self._sigs[e] = mesh[self._sig].ravel()
        self._used[e] = self._clock
        return e


class _SmoothCount(torch.autograd.Function):
    """The smooth form's ``log(1 + weighted count)`` (B, K), its gradient from :func:`soft_count_grad`."""

    @staticmethod
    def forward(ctx, vertices, log_count, summary, cand, ptr):
        ctx.save_for_backward(log_count)
        ctx.summary, ctx.cand, ctx.ptr = summary, cand, ptr
        ctx.v = vertices.detach().cpu().numpy().astype(np.float64)
        return log_count.clone()

    @staticmethod
    def backward(ctx, grad):
        (log_count,) = ctx.saved_tensors
        s = ctx.summary
        coef = (grad / torch.exp(log_count)).detach().cpu().numpy().astype(np.float64)  # d log(1 + S) / dS
        g = soft_count_grad(ctx.v, ctx.cand, ctx.ptr, s.rest, s.radius, s.fold_ratio, s.partition, coef)
        return torch.as_tensor(g, dtype=grad.dtype, device=grad.device), None, None, None, None


def farthest_point_sample(points: np.ndarray, n: int) -> np.ndarray:
    """(n,) ascending indices of ``n`` of ``points`` (P, 3) spread evenly: greedy farthest-point sampling from the
    point nearest the centroid (deterministic)."""
    p = np.asarray(points, np.float64)
    n = min(int(n), len(p))
    pick = np.empty(n, np.int64)
    pick[0] = int(np.argmin(((p - p.mean(0)) ** 2).sum(1)))
    gap = ((p - p[pick[0]]) ** 2).sum(1)
    for q in range(1, n):
        pick[q] = int(np.argmax(gap))
        np.minimum(gap, ((p - p[pick[q]]) ** 2).sum(1), out=gap)
    return np.sort(pick)


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
        max_vertices: on a mesh with more vertices, the pairs are those among this many vertices spread evenly over
            the rest mesh (:func:`farthest_point_sample`): a fixed-radius search costs about V times the vertices
            within a radius, which grows with V on a finer mesh (13 348 vertices: ~17 ms a mesh, 4 096: ~2 ms).
            None: every vertex.
        smooth: each close pair counts with the weight ``w = 1 - max(d / radius, d / (fold_ratio d_rest))`` (1 for
            touching surfaces, 0 where the pair stops being close) and pulls each minimum toward its value by w:
            ``log(1 + sum w)``, ``min 1 - w (1 - ratio)``, ``min 1 - w (1 - d / radius)``, ``min clip - w (clip -
            offset)``; every summary is then continuous in the vertices (the plain form jumps when a pair enters or
            leaves), which an optimiser through the detector (the handler, the projector) prefers.
    """

    def __init__(self, rest: np.ndarray, faces: np.ndarray, partition: np.ndarray, n_parts: int, radius: float,
                 min_hops: int = 2, fold_ratio: float = 0.5, clip: float = 3.0, max_vertices: int | None = None,
                 smooth: bool = False):
        self.smooth = bool(smooth)
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
        self.max_vertices = None if max_vertices is None else int(max_vertices)
        if self.max_vertices is not None and self.max_vertices < 2:
            raise ValueError(f"max_vertices must be >= 2 or None, got {max_vertices}")
        few = self.max_vertices is None or n <= self.max_vertices
        self.sample = np.arange(n, dtype=np.int64) if few else farthest_point_sample(self.rest, self.max_vertices)
        self._rest_sample = np.ascontiguousarray(self.rest[self.sample])
        near = hop_neighbourhood(self.faces, n, self.min_hops).tocsr()
        if not few:  # the sample's own pairs, numbered within the sample
            near = near[self.sample][:, self.sample].tocsr()
        near.sort_indices()
        self._near_ptr = near.indptr.astype(np.int64)  # vertices within min_hops edges of i: sorted, CSR
        self._near_idx = near.indices.astype(np.int64)
        corner = np.argsort(self.faces.ravel(), kind="stable")  # the faces around each vertex, CSR
        self._vf_idx = corner // 3
        self._vf_ptr = np.concatenate([[0], np.cumsum(np.bincount(self.faces.ravel(), minlength=n))])
        self.neighbour_lists = NeighbourLists(self)  # candidates reused inside reusing_neighbours()

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
        return sample_pairs(v, self.sample, self._rest_sample, self.radius, self.fold_ratio, self._near_ptr,
                            self._near_idx, 0.0)

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
            r, t = d / d_rest, d / self.radius
            w = np.ones_like(d)
            if self.smooth:
                w = 1.0 - np.maximum(t, r / self.fold_ratio)
                r, t, off = 1.0 - w * (1.0 - r), 1.0 - w * (1.0 - t), self.clip - w * (self.clip - off)
            for side in (i, j):
                part = self.partition[side]
                np.add.at(count, part, w)
                np.minimum.at(ratio, part, r)
                np.minimum.at(dist, part, t)
                np.minimum.at(offset, part, off)
        return np.stack([np.log1p(count), ratio, dist, offset], axis=1)

    def summarize_torch(self, vertices: torch.Tensor) -> torch.Tensor:
        """(B, V, 3) -> (B, K, S) summaries, differentiable in the vertices. A compiled pass over each mesh's
        close pairs gives the values and, for each minimum, the pair that attains it; with gradients, those pairs
        alone (at most 3 K a mesh, of the thousands of close pairs a colliding mesh has) are measured again in
        torch, so each minimum passes its gradient to its pair (the count is piecewise constant). Equal to
        :meth:`summarize` up to round-off."""
        if vertices.ndim != 3 or tuple(vertices.shape[1:]) != self.rest.shape:
            raise ValueError(f"vertices have shape {tuple(vertices.shape)}, expected (B, {len(self.rest)}, 3)")
        v = np.ascontiguousarray(vertices.detach().cpu().numpy(), dtype=np.float64)
        if not np.isfinite(v).all():
            raise ValueError("vertices hold NaN or infinite values")
        cand = offsets = None
        if _REUSING[0]:  # an optimiser's call: the same meshes come back, moved a little
            cand, offsets = self.neighbour_lists.candidates(v)
        elif self.smooth and vertices.requires_grad:  # the count's gradient reads every close pair
            cand, offsets = batch_pairs(v, self.sample, self._rest_sample, self.radius, self.fold_ratio,
                                        self._near_ptr, self._near_idx)
        if cand is not None:
            vals, arg = _on_every_core(summaries_of_candidates, v, cand, offsets, self.rest, self.radius,
                                       self.fold_ratio, self.faces, self.partition, self.n_parts, self.clip,
                                       self.smooth)
        else:
            vals, arg = _on_every_core(summaries_kernel, v, self.sample, self._rest_sample, self.radius,
                                       self.fold_ratio, self._near_ptr, self._near_idx, self.rest, self.faces,
                                       self.partition, self.n_parts, self.clip, self.smooth)
        out = torch.as_tensor(vals, dtype=vertices.dtype, device=vertices.device)
        if not vertices.requires_grad:
            return out
        return self._attach_gradients(vertices, out, arg, cand, offsets)

    def _attach_gradients(self, vertices: torch.Tensor, out: torch.Tensor, arg: np.ndarray, cand, offsets
                          ) -> torch.Tensor:
        """``out`` (B, K, 4) with its three minima measured again, differentiably, at the pairs ``arg``
        (B, K, 3, 2) that attain them (and, in the smooth form, the count given its gradient over the pairs among
        the candidates ``cand``).

        Every vertex those measurements read (both ends of each pair, and the faces around the vertex whose normal
        the offset reads) is gathered from ``vertices`` in one indexing: its backward writes one (B, V, 3)
        gradient, where an indexing per quantity would write, and add, one each (a handler's backward was
        dominated by them)."""
        b, k, n_sum = out.shape
        device, dtype, flat = vertices.device, vertices.dtype, out.reshape(b * k, n_sum)
        if self.smooth:
            first = _SmoothCount.apply(vertices, out[..., 0], self, cand, offsets).reshape(b * k)
        else:
            first = flat[:, 0]
        pairs = arg.reshape(b * k, 3, 2)
        slots = [np.flatnonzero(pairs[:, s, 0] >= 0) for s in range(3)]
        if not any(len(sl) for sl in slots):
            return torch.stack([first, flat[:, 1], flat[:, 2], flat[:, 3]], dim=1).view(b, k, n_sum)
        n_vert = len(self.rest)
        meshes = [sl // k for sl in slots]
        ends = [pairs[sl, s] for s, sl in enumerate(slots)]  # (Q_s, 2) per minimum
        a = ends[2][:, 0]  # the offset's normal is read at the pair's first vertex: the faces around it
        deg = self._vf_ptr[a + 1] - self._vf_ptr[a]
        owner = np.repeat(np.arange(len(a)), deg)
        at = np.arange(len(owner)) - np.repeat(np.cumsum(deg) - deg, deg)
        tri = self.faces[self._vf_idx[self._vf_ptr[a][owner] + at]]  # (T, 3)
        keys = [(m[:, None] * n_vert + e).ravel() for m, e in zip(meshes, ends)]
        keys.append((meshes[2][owner][:, None] * n_vert + tri).ravel())
        need, back = np.unique(np.concatenate(keys), return_inverse=True)  # (mesh, vertex) rows read
        g = vertices[torch.as_tensor(need // n_vert, device=device), torch.as_tensor(need % n_vert, device=device)]
        sizes = np.cumsum([0] + [len(x) for x in keys])
        rows = [torch.as_tensor(back[sizes[q]:sizes[q + 1]], device=device) for q in range(4)]
        columns = [first]
        for s, col in enumerate((1, 2, 3)):
            if not len(slots[s]):
                columns.append(flat[:, col])
                continue
            r = rows[s].view(-1, 2)
            delta = g[r[:, 1]] - g[r[:, 0]]
            d = delta.norm(dim=1)
            e = ends[s]
            d_rest = torch.as_tensor(np.linalg.norm(self.rest[e[:, 1]] - self.rest[e[:, 0]], axis=1), dtype=dtype,
                                     device=device)
            ratio, dist = d / d_rest, d / self.radius
            if col == 3:  # (x_b - x_a) . n_a over radius, clipped; n_a area-weighted over the faces around a
                t = g[rows[3].view(-1, 3)]  # (T, 3 corners, 3)
                fn = torch.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0], dim=1)  # twice the area times the normal
                normal = torch.zeros(len(a), 3, dtype=dtype, device=device).index_add(
                    0, torch.as_tensor(owner, device=device), fn)
                normal = normal / normal.norm(dim=1, keepdim=True).clamp_min(torch.finfo(dtype).tiny)
                value = ((delta * normal).sum(1) / self.radius).clamp(-self.clip, self.clip)
            else:
                value = dist if col == 2 else ratio
            if self.smooth:  # pulled toward its value by the pair's weight
                w = 1.0 - torch.maximum(dist, ratio / self.fold_ratio)
                top = self.clip if col == 3 else 1.0
                value = top - w * (top - value)
            columns.append(flat[:, col].index_put((torch.as_tensor(slots[s], device=device),), value))
        return torch.stack(columns, dim=1).view(b, k, n_sum)
