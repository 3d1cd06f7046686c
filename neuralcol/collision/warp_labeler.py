"""Batched labeler in NVIDIA Warp: the labels of :class:`~neuralcol.collision.labeler.ExactLabeler` for a batch of B
poses of one topology (``labeling=gpu``), with float verdicts on the device (see "Where its verdict is approximate").

The definitions are those of :mod:`neuralcol.collision.labeler` (verdict, pair count, PD and PD_i); the pair
formulas are ports of :mod:`neuralcol.collision.kernels` with the same float64 operations in the same order (and no
FMA contraction: ``fuse_fp`` is off for the Warp modules), so on the same device kind the values agree to
round-off (tests: ``tests/test_gpu_labeler.py``).

**Where its verdict is approximate.** The device counts a pair when its float SAT depth exceeds ``tau``, not with
the exact predicate; the host then judges every pair the device counted exactly (step 5), so a pose the device
calls colliding is colliding, and one whose counted pairs were contacts within round-off is relabeled on the host
and comes out free. What the device does not count stays uncounted: a **coplanar overlap** (SAT depth 0) and a
crossing shallower than round-off (a tilt of ~1e-15) are called free, where ``labeling=cpu`` calls them
intersecting. For exact verdicts everywhere use ``labeling=cpu``.

Where each stage runs (B poses, F triangles, N = rows of the rest near table):

1. **Device** (Warp kernels, dim B x F): every triangle's box, exact and grown by ``cap / 2`` (float64), plus a
   float32 copy rounded outwards for the broadphase.
2. **Device**, near pairs (dim B x N): the pairs of the fixed rest near table (``ExactLabeler._near_*``, built
   once) whose grown boxes overlap: SAT depth, one-vertex fold test, clearance term ``cap * m / m_rest`` or
   the corner gap (``kernels.pair_terms.pair_terms``).
3. **Device**, far pairs (dim B x F): a grouped ``wp.Bvh`` (one group per pose slot, its tree built once per
   batch size from the rest boxes and refitted to every batch) finds every non-adjacent pair whose grown
   boxes overlap; pairs sharing a vertex or in the near table are left out; SAT depth and Euclidean
   triangle distance (``far_clearances``).
4. **Device**: per pose, counted pairs (``d > tau`` with overlapping exact boxes: ``n_pairs``), the per-part
   floor ``max(d - tau)`` and the per-part clearance ``min c`` (atomics), and the list of counted pairs.
5. **Host** (numba, only for the poses that collide): the device's counted pairs judged again exactly (their
   count and per-part floor), then the penetration depth of the penetrating vertices:
   crossing edges of the counted pairs (``pair_pass`` on the device's pair list), parity of the crossings,
   flood fill of the penetrating regions and vertex depths (``finish_label``). Free poses take
   ``PD_i = -min(cap, clearance_i)`` straight from the device; colliding poses copy only their vertices to
   the host.

The device evaluates every non-adjacent pair within the cap (the reference path of ``ExactLabeler(prune=False)``,
which gives the same labels as the pruned one), apart from far pairs whose box gap alone is already >= cap
(their term is >= cap, so they cannot change ``-min(cap, clearance)``).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from neuralcol.collision.kernels.label_pass import finish_label, pair_pass
from neuralcol.collision.labeler import LABEL_VERSION, ExactLabeler, Label, Labels, gap_roundoff, split_subsets
from neuralcol.collision.warp_kernels import boxes_kernel, far_kernel, near_kernel

_EPS_AXIS = 1e-24  # as kernels.depth._EPS_AXIS
_MAX_TRI_POSES = 1 << 22  # triangle x pose slots per launch (about 200 bytes each on the device)


def default_device() -> str:
    """``cuda:0`` when Warp sees a CUDA device, else ``cpu``."""
    return "cuda:0" if wp.is_cuda_available() else "cpu"


class WarpLabeler:
    """Exact labels (those of :class:`~neuralcol.collision.labeler.ExactLabeler`) of batches of poses of one
    topology, with Warp kernels on a CUDA device or on Warp's CPU device (see the module docstring for which
    stage runs where).

    Args:
        faces: (F, 3) int triangles.
        rest_vertices: (V, 3) float rest mesh (sets ell, diag, the near table).
        partition: (V,) int part of each vertex, or None for one part.
        device: Warp device (``"cuda:0"``, ``"cpu"``, ...); None: ``cuda:0`` if available, else ``cpu``.
        touch_tol, clearance_cap, boundary_eps: as for ExactLabeler.
        cell_factor, prune, far_clusters: accepted for ExactLabeler's settings (far_clusters goes to the host
            reference); the device path does not use them (its broadphase is a BVH, and it evaluates every pair
            within cap, which gives the pruned labels).
        max_batch: poses per kernel launch; larger batches are labelled in slices of this size. It is lowered so
            that a launch holds at most 2**22 triangle-poses (about 200 bytes each on the device: 0.8 GB).

    Attributes as ExactLabeler (n_vertices, n_parts, faces, rest, ell, diag, tau, cap, eps, partition, ...),
    plus ``batched = True`` (LabelPool hands it whole chunks) and ``label_kind = "exact"`` (same labels, same
    cache). It pickles: the device arrays are rebuilt lazily in the receiving process (on Warp's CPU device
    if that process has no CUDA device).
    """

    backend = "gpu"  # labeling=gpu (conf/labeling/gpu.yaml)
    batched = True
    label_kind = "exact"
    label_version = LABEL_VERSION
    _min_pair_list = 1024  # initial room for counted pairs per launch (grown and rerun when it overflows)

    def __init__(self, faces, rest_vertices, partition=None, device: str | None = None, touch_tol: float = 0.0,
                 clearance_cap: float = 0.01, boundary_eps: float = 2e-3, cell_factor: float = 2.0,
                 prune: bool = True, max_batch: int = 1024, far_clusters: int = 6):
        del prune  # the device evaluates every pair within cap (the reference); the labels are the same
        self._ref = ExactLabeler(faces, rest_vertices, partition=partition, touch_tol=touch_tol,
                                 clearance_cap=clearance_cap, boundary_eps=boundary_eps, cell_factor=cell_factor,
                                 far_clusters=far_clusters)
        ref = self._ref
        self.faces, self.rest, self.n_vertices = ref.faces, ref.rest, ref.n_vertices
        self.edges, self.ell, self.diag = ref.edges, ref.ell, ref.diag
        self.tau, self.cap, self.eps = ref.tau, ref.cap, ref.eps
        self.closed, self.orient = ref.closed, ref.orient
        self.device = str(wp.get_device(device if device is not None else default_device()))
        if int(max_batch) < 1:
            raise ValueError("max_batch must be >= 1")
        # poses per launch: at most max_batch, and at most _MAX_TRI_POSES triangle-poses (device memory, int32)
        self.max_batch = max(1, min(int(max_batch), _MAX_TRI_POSES // max(len(ref.faces), 1)))
        self._tiny = _EPS_AXIS * self.ell**4
        n_faces = len(self.faces)
        self._near_a = np.repeat(np.arange(n_faces), np.diff(ref._near_ptr)).astype(np.int32)
        self._dev = None  # device arrays of the topology (built lazily; not pickled)
        self._bvh = {}  # batch size -> (lo32, hi32, groups, bvh), trees built from the rest boxes
        self.set_partition(partition)

    # ------------------------------------------------------------------ configuration
    def set_partition(self, partition) -> None:
        """Set the vertex partition (V,) int in [0, K) used for PD_i (None: one part)."""
        self._ref.set_partition(partition)
        self.partition = self._ref.partition
        self.n_parts = self._ref.n_parts
        if self._dev is not None:
            self._dev["part"] = wp.array(self.partition.astype(np.int32), dtype=wp.int32, device=self.device)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_dev"] = None
        state["_bvh"] = {}
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        if not wp.get_device(self.device).is_cpu and not wp.is_cuda_available():
            self.device = "cpu"  # unpickled where there is no GPU: label on Warp's CPU device

    def _device_arrays(self) -> dict:
        if self._dev is None:
            ref, d = self._ref, self.device
            self._dev = {
                "faces": wp.array(self.faces.astype(np.int32), dtype=wp.vec3i, device=d),
                "part": wp.array(self.partition.astype(np.int32), dtype=wp.int32, device=d),
                "near_a": wp.array(self._near_a, dtype=wp.int32, device=d),
                "near_b": wp.array(ref._near_b.astype(np.int32), dtype=wp.int32, device=d),
                "near_ptr": wp.array(ref._near_ptr.astype(np.int32), dtype=wp.int32, device=d),
                "near_rest": wp.array(ref._near_rest.astype(np.float64), dtype=wp.float64, device=d),
                "near_shared": wp.array(ref._near_shared.astype(np.int32), dtype=wp.int32, device=d),
            }
        return self._dev

    def _tree(self, n: int):
        """Grouped BVH for ``n`` pose slots (group = slot), built once from the rest boxes, refitted per batch."""
        if n not in self._bvh:
            if len(self._bvh) >= 4:
                self._bvh.pop(next(iter(self._bvh)))
            dev = self._device_arrays()
            n_faces = len(self.faces)
            rest = wp.array(np.broadcast_to(self.rest, (n, self.n_vertices, 3)).copy(), dtype=wp.vec3d,
                            device=self.device)
            shape = (n, n_faces)
            tmp = [wp.empty(shape, dtype=wp.vec3d, device=self.device) for _ in range(4)]
            lo32 = wp.empty(n * n_faces, dtype=wp.vec3, device=self.device)
            hi32 = wp.empty(n * n_faces, dtype=wp.vec3, device=self.device)
            wp.launch(boxes_kernel, dim=shape, device=self.device,
                      inputs=[rest, dev["faces"], 0.5 * self.cap, 1e-7 * self.cap, *tmp, lo32, hi32])
            groups = wp.array(np.repeat(np.arange(n, dtype=np.int32), n_faces), dtype=wp.int32, device=self.device)
            self._bvh[n] = (lo32, hi32, groups, wp.Bvh(lo32, hi32, groups=groups))
        return self._bvh[n]

    # ------------------------------------------------------------------ input
    def _as_device_batch(self, vertices):
        """(B, V, 3) numpy or torch -> (Warp (B, V) vec3d array on self.device, host accessor of one pose)."""
        n = self.n_vertices
        if hasattr(vertices, "detach"):  # torch tensor
            import torch

            t = vertices.detach()
            if t.ndim != 3 or tuple(t.shape[1:]) != (n, 3):
                raise ValueError(f"vertices have shape {tuple(t.shape)}, expected (B, {n}, 3)")
            if t.dtype.is_complex or not (t.dtype.is_floating_point or t.dtype in (torch.int32, torch.int64)):
                raise ValueError(f"vertices have dtype {t.dtype}, expected real floats")
            dev = wp.get_device(self.device)
            if dev.is_cuda:
                t = t.to(device=wp.device_to_torch(dev), dtype=torch.float64).contiguous()
                if not bool(torch.isfinite(t).all()):
                    raise ValueError("vertices contain NaN or inf; cannot label")
                return wp.from_torch(t, dtype=wp.vec3d), (lambda i: t[i].cpu().numpy())
            vertices = t.cpu().numpy()
        v = np.asarray(vertices)
        if v.ndim != 3 or v.shape[1:] != (n, 3):
            raise ValueError(f"vertices have shape {v.shape}, expected (B, {n}, 3)")
        if not np.issubdtype(v.dtype, np.number) or np.issubdtype(v.dtype, np.complexfloating):
            raise ValueError(f"vertices have dtype {v.dtype}, expected real floats")
        v = np.ascontiguousarray(v, dtype=np.float64)
        if not np.isfinite(v).all():
            raise ValueError("vertices contain NaN or inf; cannot label")
        return wp.array(v, dtype=wp.vec3d, device=self.device), (lambda i: v[i])

    # ------------------------------------------------------------------ labels
    def label_batch(self, vertices) -> Labels:
        """Labels of a batch (B, V, 3) numpy or torch (any device; a CUDA tensor stays on the device)."""
        n_batch = int(vertices.shape[0]) if hasattr(vertices, "shape") else len(vertices)
        if n_batch == 0 or n_batch <= self.max_batch:
            return self._label_slice(vertices)
        parts = [self._label_slice(vertices[i:i + self.max_batch]) for i in range(0, n_batch, self.max_batch)]
        return Labels(*(np.concatenate([getattr(p, k) for p in parts]) for k in Labels._fields))

    def _label_slice(self, vertices) -> Labels:
        verts, host = self._as_device_batch(vertices)
        n_batch = verts.shape[0]
        k_parts = self.n_parts
        if n_batch == 0:
            return Labels.stack([], k_parts)
        dev, d = self._device_arrays(), self.device
        n_faces = len(self.faces)
        shape = (n_batch, n_faces)
        lo32, hi32, _, bvh = self._tree(n_batch)
        lo0, hi0, lo_cap, hi_cap = (wp.empty(shape, dtype=wp.vec3d, device=d) for _ in range(4))
        wp.launch(boxes_kernel, dim=shape, device=d,
                  inputs=[verts, dev["faces"], 0.5 * self.cap, 1e-7 * self.cap, lo0, hi0, lo_cap, hi_cap, lo32, hi32])
        bvh.refit()
        n_near = len(self._near_a)
        pair_cap = max(self._min_pair_list, 16 * n_batch)
        while True:
            clear = wp.array(np.full((n_batch, k_parts), np.inf), dtype=wp.float64, device=d)
            floor = wp.zeros((n_batch, k_parts), dtype=wp.float64, device=d)
            n_pairs = wp.zeros(n_batch, dtype=wp.int32, device=d)
            out_pairs = wp.empty((pair_cap, 3), dtype=wp.int32, device=d)
            out_count = wp.zeros(1, dtype=wp.int32, device=d)
            common = [clear, floor, n_pairs, out_pairs, out_count]
            scalars = [self._tiny, self.tau, self.cap]
            if n_near:
                wp.launch(near_kernel, dim=(n_batch, n_near), device=d,
                          inputs=[verts, dev["faces"], dev["part"], dev["near_a"], dev["near_b"], dev["near_rest"],
                                  dev["near_shared"], lo0, hi0, lo_cap, hi_cap, *scalars, *common])
            wp.launch(far_kernel, dim=shape, device=d,
                      inputs=[verts, dev["faces"], dev["part"], dev["near_ptr"], dev["near_b"], bvh.id, lo32, hi32,
                              lo0, hi0, lo_cap, hi_cap, *scalars, *common])
            count = int(out_count.numpy()[0])
            if count <= pair_cap:
                break
            pair_cap = count  # the list overflowed: run again with room for every counted pair
        clear_h = clear.numpy()
        n_pairs_h = n_pairs.numpy().astype(np.int64)
        pd_sub = -np.minimum(self.cap, clear_h)
        hit = np.flatnonzero(n_pairs_h > 0)
        if len(hit):
            self._finish_colliding(hit, out_pairs.numpy()[:count], host, clear_h, n_pairs_h, pd_sub)
        return Labels(n_pairs_h > 0, n_pairs_h, pd_sub.max(1), pd_sub)

    def _finish_colliding(self, hit, pairs, host, clear, n_pairs, pd_sub) -> None:
        """The poses the device found colliding, on the host: the device's counted pairs judged again with the exact
        predicate (``pair_pass``; the device counts float SAT depths > tau), their count and per-part floor, then
        PD_i from the crossing edges, flood fill and vertex depths (numba). ``n_pairs`` and ``pd_sub`` are updated
        in place; a pose none of whose pairs is counted exactly is free and labeled on the host in full."""
        ref = self._ref
        order = np.lexsort((pairs[:, 2], pairs[:, 1], pairs[:, 0]))
        pairs = pairs[order].astype(np.int64)
        starts = np.searchsorted(pairs[:, 0], hit)
        ends = np.searchsorted(pairs[:, 0], hit, side="right")
        k_parts = self.n_parts
        for p, s, e in zip(hit, starts, ends):
            v = np.ascontiguousarray(host(int(p)), dtype=np.float64)
            pp = np.ascontiguousarray(pairs[s:e, 1:])
            floor = np.zeros(k_parts)
            n_exact, rec_key, rec_int, n_rec = pair_pass(v, self.faces, pp, self.ell, self.tau, gap_roundoff(v),
                                                         self.cap, self.partition, np.full(k_parts, np.inf), floor,
                                                         ref.adj_ptr, ref.adj_idx, ref.adj_eid, self.orient,
                                                         ref._near_ptr, ref._near_b, ref._near_rest)
            n_pairs[p] = n_exact
            if n_exact == 0:  # the device counted contacts within round-off only: free; its clearances on the
                pd_sub[p] = ref.label(v).pd_sub  # device took those pairs for 0, so the host labels this pose
                continue
            out, _ = finish_label(v, self.faces, rec_key, rec_int, n_rec, len(self.edges), floor, clear[p].copy(),
                                  self.partition, k_parts, self.cap, ref.adj_ptr, ref.adj_idx, ref.adj_eid,
                                  self.closed)
            pd_sub[p] = out

    def label(self, vertices) -> Label:
        """Verdict, number of counted pairs, PD and PD_i of one mesh (V, 3) (a batch of one)."""
        v = vertices[None] if hasattr(vertices, "detach") else np.asarray(vertices)[None]
        lb = self.label_batch(v)
        return Label(bool(lb.collides[0]), int(lb.n_pairs[0]), float(lb.pd[0]), lb.pd_sub[0])

    def verdict(self, vertices) -> bool:
        """True iff the mesh self-collides."""
        return self.label(vertices).collides

    def subsets(self, pd: np.ndarray) -> np.ndarray:
        """D_p / D_n / D_b codes of PD values with this labeler's ``eps``."""
        return split_subsets(pd, self.eps)

    def __repr__(self) -> str:
        return (f"WarpLabeler(device={self.device!r}, n_vertices={self.n_vertices}, n_faces={len(self.faces)}, "
                f"n_parts={self.n_parts})")
