"""ACAP deformation features (Gao et al. 2019, "Sparse data driven mesh deformation") and their inverse.

Definitions (rest mesh q, deformed mesh p, 1-ring N(i), edge vectors ``e_ij = q_j - q_i``):

* **Deformation gradient.** ``T_i = argmin_T sum_{j in N(i)} w_ij |e'_ij - T e_ij|^2 + w_n,i |h'_i n'_i - T h_i n_i|^2``
  with clamped cotangent weights ``w_ij`` (or uniform weights), and one extra "normal edge": the vertex
  normal ``n_i`` scaled by the mean 1-ring edge length ``h_i`` (``n'``, ``h'`` on the deformed mesh),
  weighted ``w_n,i = normal_weight * mean_j w_ij``. The 1-ring edges of a flat region are coplanar and leave
  the normal column of ``T_i`` undetermined; the normal edge fixes it (as in deformation transfer). The rest
  mesh gives ``T_i = I`` and a uniformly scaled mesh ``T_i = s I`` exactly.
* **Polar decomposition** ``T_i = R_i S_i`` (SVD, ``det R_i = +1``), feature ``f_i = (r_i, S_i)`` with
  ``r_i`` the rotation vector (axis * angle) of ``R_i`` and the 6 upper-triangular entries of the symmetric
  ``S_i``: ``(r_x, r_y, r_z, S_xx, S_xy, S_xz, S_yy, S_yz, S_zz)``. The rest mesh encodes to
  ``(0, 0, 0, 1, 0, 0, 1, 0, 1)`` at every vertex.
* **Consistent rotation vectors.** ``r_i`` and ``r_i + 2 pi k n_i`` (``n_i`` its unit axis, any integer ``k``;
  ``k < 0`` flips the axis) are the same rotation. Starting at a root vertex, vertices are visited in
  breadth-first levels and each takes the ``k`` that brings it closest to its already visited neighbours
  (vectorized per level and over the batch), so features are continuous where the shape is, e.g. a tube
  twisted past pi keeps increasing angles. Across a data set, the root's ``k`` is chosen among
  ``{-1, 0, 1}`` to bring the whole mesh closest to the reference (rest) features, i.e. ``r = 0``.
* **Inverse.** ``T_i = exp(r_i) S_i``; vertex positions minimise
  ``sum_i sum_{j in N(i)} w_ij |(p_j - p_i) - T_i e_ij|^2``, i.e. solve ``L p = b`` with the weighted graph
  Laplacian ``L`` and ``b_i = sum_j w_ij (T_i + T_j)/2 (q_i - q_j)``. ``L`` depends on the rest mesh only; with
  one anchor vertex pinned it is factorised once (sparse LU) and reused by every batch, also in the backward
  pass (``L`` is symmetric). The decoded mesh is translated so its centroid is the rest mesh's centroid.

The solve runs in float64 on the CPU (SciPy SuperLU); inputs on another device are copied there and back.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.csgraph import breadth_first_order, connected_components
from scipy.sparse.linalg import splu
from scipy.spatial.transform import Rotation

from neuralcol.geometry.topology import edge_topology, vertex_neighbors

FEATURE_DIM = 9
IDENTITY_FEATURE = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0)
_SYM_IDX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def cotangent_weights(vertices: np.ndarray, faces: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Cotangent edge weights ``(cot a + cot b) / 2`` (one term for a boundary edge).

    Args:
        vertices: (V, 3) float64.
        faces: (F, 3) int.
        edges: (E, 2) sorted undirected edges, as from :func:`edge_topology`.

    Returns:
        (E,) float64 weights (may be negative for obtuse angles).
    """
    topo = edge_topology(faces)
    if not np.array_equal(topo.edges, edges):
        raise ValueError("edges must be the sorted edge list of faces")
    tri = vertices[faces]  # (F, 3, 3)
    w = np.zeros(len(edges))
    for c in range(3):  # angle at corner c is opposite edge (c+1, c+2)
        a = tri[:, (c + 1) % 3] - tri[:, c]
        b = tri[:, (c + 2) % 3] - tri[:, c]
        cot = (a * b).sum(-1) / np.maximum(np.linalg.norm(np.cross(a, b), axis=-1), 1e-300)
        np.add.at(w, topo.face_edges[:, (c + 1) % 3], 0.5 * cot)
    return w


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals of (..., V, 3) vertices; returns (..., V, 3)."""
    tri = vertices[..., faces, :]  # (..., F, 3, 3)
    fn = np.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :])  # (..., F, 3)
    inc = sp.csr_matrix((np.ones(faces.size), (faces.reshape(-1), np.repeat(np.arange(len(faces)), 3))),
                        shape=(vertices.shape[-2], len(faces)))  # (V, F) vertex-face incidence
    vn = sparse_sum(inc, fn)
    return vn / np.maximum(np.linalg.norm(vn, axis=-1, keepdims=True), 1e-300)


def sparse_sum(mat: sp.spmatrix, values: np.ndarray, axis: int = -2) -> np.ndarray:
    """Contract a sparse (n, m) matrix with ``values`` along ``axis`` (of length m); that axis becomes n.

    Args:
        mat: (n, m) sparse matrix.
        values: (..., m, ...) array.
        axis: the axis of ``values`` to contract.

    Returns:
        The array with ``values.shape[axis]`` replaced by n.
    """
    moved = np.moveaxis(values, axis, 0)  # (m, ...)
    out = mat @ moved.reshape(moved.shape[0], -1)
    return np.moveaxis(np.asarray(out).reshape(mat.shape[0], *moved.shape[1:]), 0, axis)


class SplitFeatures(NamedTuple):
    """Feature parts. rotvec: (..., V, 3); sym: (..., V, 6) upper-triangular entries of S."""

    rotvec: torch.Tensor
    sym: torch.Tensor


def split_features(features: torch.Tensor) -> SplitFeatures:
    """Split (..., V, 9) features into rotation vectors (..., V, 3) and S entries (..., V, 6)."""
    return SplitFeatures(features[..., :3], features[..., 3:])


def sym_from_entries(entries: torch.Tensor) -> torch.Tensor:
    """(..., 6) upper-triangular entries -> (..., 3, 3) symmetric matrices."""
    xx, xy, xz, yy, yz, zz = entries.unbind(-1)
    row0 = torch.stack([xx, xy, xz], -1)
    row1 = torch.stack([xy, yy, yz], -1)
    row2 = torch.stack([xz, yz, zz], -1)
    return torch.stack([row0, row1, row2], -2)


SMALL_ANGLE = 1e-2  # radians: below it Rodrigues' coefficients use their Taylor series


def rotvec_to_matrix(rotvec: torch.Tensor, small_angle: float = SMALL_ANGLE) -> torch.Tensor:
    """Rodrigues' formula, differentiable everywhere (Taylor series below ``small_angle`` radians).

    Args:
        rotvec: (..., 3) rotation vectors (axis * angle).
        small_angle: below this angle the coefficients use their 4th-order Taylor series.

    Returns:
        (..., 3, 3) rotation matrices, same dtype and device.
    """
    theta2 = (rotvec * rotvec).sum(-1)
    small = theta2 < small_angle**2
    theta2_safe = torch.where(small, torch.ones_like(theta2), theta2)
    theta = theta2_safe.sqrt()
    a = torch.where(small, 1 - theta2 / 6 + theta2 * theta2 / 120, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24 + theta2 * theta2 / 720, (1 - torch.cos(theta)) / theta2_safe)
    x, y, z = rotvec.unbind(-1)
    zero = torch.zeros_like(x)
    k = torch.stack([torch.stack([zero, -z, y], -1), torch.stack([z, zero, -x], -1),
                     torch.stack([-y, x, zero], -1)], -2)  # (..., 3, 3)
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device).expand_as(k)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


class _SparseSolve(torch.autograd.Function):
    """x = L^{-1} b for a symmetric L factorised once; backward reuses the factorisation."""

    @staticmethod
    def forward(ctx, b: torch.Tensor, lu) -> torch.Tensor:  # b: (B, n, 3)
        ctx.lu = lu
        return _lu_solve(lu, b)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        return _lu_solve(ctx.lu, grad), None


def _lu_solve(lu, b: torch.Tensor) -> torch.Tensor:
    bsz, n, d = b.shape
    rhs = b.detach().to("cpu", torch.float64).permute(1, 0, 2).reshape(n, bsz * d).numpy()
    x = lu.solve(np.ascontiguousarray(rhs))  # (n, B*3)
    out = torch.from_numpy(np.ascontiguousarray(x.reshape(n, bsz, d).transpose(1, 0, 2)))
    return out.to(device=b.device, dtype=b.dtype)


class ACAP:
    """ACAP feature transform of one mesh topology around a rest mesh.

    Args:
        rest_vertices: (V, 3) float rest (reference) mesh.
        faces: (F, 3) int triangles.
        weights: ``"cotan"`` (clamped cotangent weights) or ``"uniform"``.
        min_weight_ratio: cotangent weights are clamped below at this fraction of their mean absolute value,
            so every weight is positive and the Laplacian is positive definite once the anchor is pinned.
        normal_weight: weight of the normal edge relative to the mean 1-ring weight of a vertex.
        root: vertex where the rotation-consistency propagation starts (and the anchor pinned in decode).
        max_turns: the rotation consistency considers ``k`` in ``[-max_turns, max_turns]``.
    """

    def __init__(self, rest_vertices, faces, weights: str = "cotan", min_weight_ratio: float = 0.01,
                 normal_weight: float = 0.05, root: int = 0, max_turns: int = 3):
        q = _np64(rest_vertices)
        f = _np(faces).astype(np.int64)
        if q.ndim != 2 or q.shape[1] != 3:
            raise ValueError(f"rest_vertices have shape {q.shape}, expected (V, 3)")
        if weights not in ("cotan", "uniform"):
            raise ValueError(f"weights='{weights}': choose 'cotan' or 'uniform'")
        n_vert = len(q)
        self.settings = {"weights": weights, "min_weight_ratio": min_weight_ratio, "normal_weight": normal_weight,
                         "root": int(root), "max_turns": int(max_turns)}
        self.n_vertices = n_vert
        self.rest_vertices = q
        self.faces = f
        self.root = int(root)
        self.max_turns = int(max_turns)
        topo = edge_topology(f)
        self.edges = topo.edges  # (E, 2)
        if weights == "cotan":
            w = cotangent_weights(q, f, self.edges)
            floor = min_weight_ratio * np.abs(w).mean()
            w = np.maximum(w, floor)
        else:
            w = np.ones(len(self.edges))
        self.edge_weights = w  # (E,)
        # directed edges i -> j (both directions), for the fitting sums
        self._src = np.concatenate([self.edges[:, 0], self.edges[:, 1]])
        self._dst = np.concatenate([self.edges[:, 1], self.edges[:, 0]])
        self._dw = np.concatenate([w, w])
        e = q[self._dst] - q[self._src]  # (2E, 3)
        wsum = np.bincount(self._src, weights=self._dw, minlength=n_vert)
        deg = np.bincount(self._src, minlength=n_vert)
        self._degree = deg
        if (deg == 0).any():
            raise ValueError(f"vertex {int(np.argmin(deg))} belongs to no face; remove unreferenced vertices")
        self._normal_w = normal_weight * wsum / deg  # (V,)
        a = np.zeros((n_vert, 3, 3))
        # (V, 2E) sum over the outgoing directed edges of each vertex
        self._out_sum = sp.csr_matrix((np.ones(len(self._src)), (self._src, np.arange(len(self._src)))),
                                      shape=(n_vert, len(self._src)))
        a += sparse_sum(self._out_sum, self._dw[:, None, None] * e[:, :, None] * e[:, None, :], axis=0)
        nh = vertex_normals(q, f) * self._mean_edge_length(q)[:, None]
        a += self._normal_w[:, None, None] * nh[:, :, None] * nh[:, None, :]
        self._rest_edges = e
        self._rest_normal_scaled = nh  # (V, 3)
        self._a_inv = np.linalg.inv(a)  # (V, 3, 3)
        # Laplacian with the root pinned, factorised once
        lap = sp.coo_matrix((np.concatenate([-w, -w]), (self._src, self._dst)), shape=(n_vert, n_vert)).tocsr()
        lap = lap + sp.diags(np.bincount(self._src, weights=self._dw, minlength=n_vert))
        n_comp, _ = connected_components(lap, directed=False)
        if n_comp != 1:
            raise ValueError(f"the mesh has {n_comp} connected components; ACAP needs one connected mesh")
        keep = np.setdiff1d(np.arange(n_vert), [self.root])
        self._keep = torch.as_tensor(keep)
        self._lap_pinned = lap[keep][:, keep].tocsc()  # kept to factorise again after unpickling (SuperLU is not
        self._lu = splu(self._lap_pinned)  # picklable; a label pool's workers decode with a pickled copy)
        self._rest_centroid = q.mean(0)
        # decode right-hand side: b_i += w (T_i + T_j)/2 (q_i - q_j), b_j -= same, per undirected edge
        self._edge_i = torch.as_tensor(self.edges[:, 0])
        self._edge_j = torch.as_tensor(self.edges[:, 1])
        self._edge_vec_w = torch.as_tensor(w[:, None] * (q[self.edges[:, 0]] - q[self.edges[:, 1]]))  # (E, 3)
        self._levels = self._bfs_levels(n_vert)
        # numpy copies for the no-gradient decode (acap_kernels.decode_rhs)
        self._edge_i_np = np.ascontiguousarray(self.edges[:, 0], dtype=np.int64)
        self._edge_j_np = np.ascontiguousarray(self.edges[:, 1], dtype=np.int64)
        self._edge_vec_w_np = np.ascontiguousarray(self._edge_vec_w.numpy(), dtype=np.float64)
        self._keep_np = keep

    def __getstate__(self):
        state = dict(self.__dict__)
        state.pop("_lu", None)  # SuperLU cannot be pickled: factorised again from the pinned Laplacian
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._lu = splu(self._lap_pinned)

    # ------------------------------------------------------------------ encode
    def _mean_edge_length(self, verts: np.ndarray) -> np.ndarray:
        """Mean 1-ring edge length per vertex, (..., V, 3) -> (..., V)."""
        lengths = np.linalg.norm(verts[..., self._dst, :] - verts[..., self._src, :], axis=-1)  # (..., 2E)
        return sparse_sum(self._out_sum, lengths, axis=-1) / self._degree

    def deformation_gradients(self, vertices) -> np.ndarray:
        """Per-vertex deformation gradients T_i, (B, V, 3) -> (B, V, 3, 3) float64 numpy."""
        p = _np64(vertices)
        if p.ndim != 3 or p.shape[1:] != (self.n_vertices, 3):
            raise ValueError(f"vertices have shape {p.shape}, expected (B, {self.n_vertices}, 3)")
        e_def = p[:, self._dst] - p[:, self._src]  # (B, 2E, 3)
        contrib = self._dw[None, :, None, None] * e_def[..., :, None] * self._rest_edges[None, :, None, :]
        bmat = sparse_sum(self._out_sum, contrib, axis=1)  # (B, V, 3, 3)
        nh_def = vertex_normals(p, self.faces) * self._mean_edge_length(p)[..., None]  # (B, V, 3)
        bmat += self._normal_w[None, :, None, None] * nh_def[..., :, None] * self._rest_normal_scaled[None, :, None, :]
        return bmat @ self._a_inv[None]  # (B, V, 3, 3)

    def encode(self, vertices: torch.Tensor) -> torch.Tensor:
        """ACAP features of deformed meshes.

        Args:
            vertices: (B, V, 3) float tensor (or (V, 3) for one mesh).

        Returns:
            (B, V, 9) features (or (V, 9)), same dtype and device as ``vertices``.
        """
        single = vertices.ndim == 2
        v = vertices[None] if single else vertices
        t = self.deformation_gradients(v)  # (B, V, 3, 3)
        u, _, vh = np.linalg.svd(t)
        det = np.linalg.det(u @ vh)
        u[..., :, 2] *= det[..., None]  # proper rotation R = U diag(1, 1, det) V^T
        rot = u @ vh  # (B, V, 3, 3)
        s = np.swapaxes(rot, -1, -2) @ t
        s = 0.5 * (s + np.swapaxes(s, -1, -2))
        rv = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_rotvec().reshape(*rot.shape[:-2], 3)
        rv = self.consistent_rotvecs(rv)
        sym = np.stack([s[..., i, j] for i, j in _SYM_IDX], -1)
        feats = torch.from_numpy(np.concatenate([rv, sym], -1)).to(device=vertices.device, dtype=vertices.dtype)
        return feats[0] if single else feats

    def _bfs_levels(self, n_vert: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """Breadth-first levels from the root: per level (vertices (n,), visited-neighbour table (n, K))."""
        adj = sp.coo_matrix((np.ones(len(self.edges)), (self.edges[:, 0], self.edges[:, 1])),
                            shape=(n_vert, n_vert))
        adj = (adj + adj.T).tocsr()
        order, pred = breadth_first_order(adj, self.root, directed=False, return_predecessors=True)
        depth = np.zeros(n_vert, dtype=np.int64)
        for v in order[1:]:
            depth[v] = depth[pred[v]] + 1
        nbr = vertex_neighbors(self.edges, n_vert)  # (V, K)
        levels = []
        for d in range(1, int(depth.max()) + 1):
            verts = np.nonzero(depth == d)[0]
            table = nbr[verts]
            table = np.where((table >= 0) & (depth[np.maximum(table, 0)] < d), table, -1)
            levels.append((verts, table))  # every vertex at depth d has a neighbour at depth d - 1
        return levels

    def consistent_rotvecs(self, rotvec: np.ndarray) -> np.ndarray:
        """Choose ``r + 2 pi k n`` per vertex so rotation vectors vary continuously over the mesh.

        For a vertex with principal angle ``theta`` and axis ``a``, the candidates are ``(theta + 2 pi k) a``;
        the summed squared distance to the m visited neighbours ``r_u`` is a parabola in
        ``phi = theta + 2 pi k`` with minimum at ``phi* = a . sum_u r_u / m``, so the best ``k`` is
        ``round((phi* - theta) / 2 pi)``, clipped to ``[-max_turns, max_turns]``.

        Args:
            rotvec: (B, V, 3) principal rotation vectors (angle in [0, pi]).

        Returns:
            (B, V, 3) consistent rotation vectors (see the module docstring).
        """
        theta = np.linalg.norm(rotvec, axis=-1)  # (B, V)
        axis = np.where(theta[..., None] > 1e-12, rotvec / np.maximum(theta, 1e-300)[..., None], 0.0)
        two_pi = 2 * np.pi
        best, best_cost = None, None
        for k_root in (0, -1, 1):
            out = rotvec.copy()
            out[:, self.root] += two_pi * k_root * axis[:, self.root]
            for verts, table in self._levels:
                mask = (table >= 0)[None, :, :, None]  # (1, n, K, 1)
                nsum = (out[:, np.maximum(table, 0)] * mask).sum(2)  # (B, n, 3)
                phi = (axis[:, verts] * nsum).sum(-1) / mask.sum(2)[..., 0]  # (B, n)
                k = np.clip(np.rint((phi - theta[:, verts]) / two_pi), -self.max_turns, self.max_turns)
                out[:, verts] = rotvec[:, verts] + (two_pi * k)[..., None] * axis[:, verts]
            mesh_cost = (out**2).sum(-1).mean(-1)  # (B,) distance to the reference features r = 0
            if best is None:
                best, best_cost = out, mesh_cost
            else:
                better = mesh_cost < best_cost - 1e-9
                best = np.where(better[:, None, None], out, best)
                best_cost = np.minimum(best_cost, mesh_cost)
        return best

    # ------------------------------------------------------------------ decode
    def gradients_from_features(self, features: torch.Tensor) -> torch.Tensor:
        """T_i = exp(r_i) S_i, (..., V, 9) -> (..., V, 3, 3), differentiable."""
        rv, sym = split_features(features)
        return rotvec_to_matrix(rv) @ sym_from_entries(sym)

    def decode(self, features: torch.Tensor, fast: bool = False) -> torch.Tensor:
        """Vertex positions from ACAP features (differentiable, batched).

        Args:
            features: (B, V, 9) float tensor (or (V, 9)).
            fast: where no graph is needed (``torch.no_grad()`` or features without ``requires_grad``) and on the
                CPU, build the solve's right-hand side in one numba pass (float64; ~4x faster on SCAPE, equal to
                round-off). Opt-in: as the default it moved ``make run``'s accuracy by -0.59 points over 3 seeds,
                beyond the rule registered in docs/studies/acap_fast_decode.md (round-off carried by training;
                labels unchanged).

        Returns:
            (B, V, 3) vertices (or (V, 3)) with the rest mesh's centroid; same dtype and device.
        """
        single = features.ndim == 2
        f = features[None] if single else features
        if f.ndim != 3 or f.shape[1:] != (self.n_vertices, FEATURE_DIM):
            raise ValueError(f"features have shape {tuple(features.shape)}, expected (B, {self.n_vertices}, 9)")
        if fast and f.device.type == "cpu" and not (torch.is_grad_enabled() and f.requires_grad):
            p = self._decode_no_grad(f)
            return p[0] if single else p
        dev, dt = f.device, f.dtype
        keep = self._keep.to(dev)
        x = _SparseSolve.apply(self._rhs(f), self._lu)  # (B, V-1, 3)
        p = torch.zeros(f.shape[0], self.n_vertices, 3, dtype=dt, device=dev).index_copy(1, keep, x)
        centroid = torch.as_tensor(self._rest_centroid, dtype=dt, device=dev)
        p = p - p.mean(1, keepdim=True) + centroid
        return p[0] if single else p

    def _rhs(self, f: torch.Tensor) -> torch.Tensor:
        """The solve's right-hand side ``b`` of features (B, V, 9) at the unpinned vertices: (B, V-1, 3)."""
        t = self.gradients_from_features(f)  # (B, V, 3, 3)
        dev, dt = f.device, f.dtype
        ei, ej = self._edge_i.to(dev), self._edge_j.to(dev)
        evw = self._edge_vec_w.to(device=dev, dtype=dt)  # (E, 3)
        g = 0.5 * ((t[:, ei] + t[:, ej]) @ evw[None, :, :, None])[..., 0]  # (B, E, 3)
        b = torch.zeros(f.shape[0], self.n_vertices, 3, dtype=dt, device=dev)
        b = b.index_add(1, ei, g).index_add(1, ej, -g)
        return b[:, self._keep.to(dev)]

    def vertex_selector(self, idx) -> torch.Tensor:
        """The (K, V-1) float64 matrix ``M`` with ``decode(f)[:, idx] = M @ b + centroid`` (``b``: the solve's
        right-hand side at the unpinned vertices): rows ``idx`` of ``L^-1`` (zero for the pinned vertex) minus
        their mean over all vertices, which the centroid shift subtracts. Built with K + 1 solves of the
        factorisation and kept for the last few index sets."""
        idx = np.asarray(_np(idx), dtype=np.int64).reshape(-1)
        if idx.size and (idx.min() < 0 or idx.max() >= self.n_vertices):
            raise ValueError(f"vertex indices must lie in [0, {self.n_vertices}); got {idx.min()}..{idx.max()}")
        key = idx.tobytes()
        cache = self.__dict__.setdefault("_selectors", {})
        if key not in cache:
            n = self.n_vertices - 1
            pos = np.full(self.n_vertices, -1, dtype=np.int64)  # row of each vertex among the unpinned ones
            pos[self._keep.numpy()] = np.arange(n)
            rows = np.zeros((n, len(idx) + 1))
            free = pos[idx] >= 0
            rows[pos[idx][free], np.flatnonzero(free)] = 1.0
            rows[:, -1] = 1.0 / self.n_vertices  # the mean over all vertices (the pinned one is 0)
            sol = self._lu.solve(rows, trans="T")  # (n, K + 1): columns of L^-T, i.e. rows of L^-1
            sol[:, :-1][:, ~free] = 0.0
            cache[key] = torch.from_numpy(np.ascontiguousarray((sol[:, :-1] - sol[:, -1:]).T))
            while len(cache) > 4:
                cache.pop(next(iter(cache)))
        return cache[key]

    def decode_vertices(self, features: torch.Tensor, idx) -> torch.Tensor:
        """Positions of the vertices ``idx`` only: ``decode(features)[..., idx, :]`` to round-off, differentiable,
        as one dense product with :meth:`vertex_selector` (no sparse solve, no copy to the CPU: it runs on the
        features' device). For detectors that read a few vertices of every decoded mesh.

        Args:
            features: (B, V, 9) or (V, 9) ACAP features.
            idx: (K,) vertex indices.

        Returns:
            (B, K, 3) (or (K, 3)) positions, the features' dtype and device.
        """
        single = features.ndim == 2
        f = features[None] if single else features
        if f.ndim != 3 or f.shape[1:] != (self.n_vertices, FEATURE_DIM):
            raise ValueError(f"features have shape {tuple(features.shape)}, expected (B, {self.n_vertices}, 9)")
        m = self.vertex_selector(idx).to(device=f.device, dtype=f.dtype)
        centroid = torch.as_tensor(self._rest_centroid, dtype=f.dtype, device=f.device)
        p = torch.einsum("kn,bnc->bkc", m, self._rhs(f)) + centroid
        return p[0] if single else p

    def _decode_no_grad(self, f: torch.Tensor) -> torch.Tensor:
        """:meth:`decode` without a graph, on the CPU: the right-hand side in one numba pass per mesh (float64,
        :func:`~neuralcol.geometry.acap_kernels.decode_rhs`), then the same factorised solve; returns the input's
        dtype. Equal to the differentiable path to round-off, ~4x faster on SCAPE."""
        from neuralcol.geometry.acap_kernels import decode_rhs

        fn = np.ascontiguousarray(f.detach().numpy(), dtype=np.float64)
        rhs = np.zeros((fn.shape[0], self.n_vertices, 3))
        decode_rhs(fn, self._edge_i_np, self._edge_j_np, self._edge_vec_w_np, SMALL_ANGLE**2, rhs)
        keep = self._keep_np
        x = self._lu.solve(np.ascontiguousarray(rhs[:, keep].transpose(1, 0, 2).reshape(len(keep), -1)))
        p = np.zeros_like(rhs)
        p[:, keep] = x.reshape(len(keep), fn.shape[0], 3).transpose(1, 0, 2)
        p += self._rest_centroid - p.mean(1, keepdims=True)
        return torch.from_numpy(p).to(f.dtype)

    def identity_features(self, batch: int = 1, dtype=torch.float32, device=None) -> torch.Tensor:
        """Features of the rest mesh, (batch, V, 9)."""
        one = torch.tensor(IDENTITY_FEATURE, dtype=dtype, device=device)
        return one.expand(batch, self.n_vertices, FEATURE_DIM).clone()


def _np(x) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def _np64(x) -> np.ndarray:
    return _np(x).astype(np.float64)
