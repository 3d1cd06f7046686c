"""The paper's labeler: self-collision verdict, PD and PD_i from python-fcl (``labeling=fcl``).

Tan et al. (ICML 2022) label their meshes with FCL. :class:`FCLLabeler` does the same with python-fcl and
exposes the interface of :class:`~neuralcol.collision.labeler.ExactLabeler` (``label``, ``verdict``,
``label_batch``, ``subsets``, ``n_vertices``, ``n_parts``, ``tau``, ``cap``, ``eps``, ...), so
:class:`~neuralcol.collision.pool.LabelPool`, the oracle and the detector stage use it unchanged. Its PD is
*not* ours (see "Differences" below), so ``label_kind = "fcl"`` keeps its labels in a cache of their own.

Definitions (``ell``, ``diag``, ``tau = touch_tol * ell``, ``cap = clearance_cap * diag``,
``eps = boundary_eps * diag`` as in :mod:`neuralcol.collision.labeler`):

* **Contacts.** FCL's mesh-mesh collision (``fcl.collide`` of two ``BVHModel``\\ s, OBBRSS, with
  ``enable_contact``) between triangles. Three ways to enumerate the triangle pairs, same contacts:

  - ``method="broadphase"`` (default): FCL's ``DynamicAABBTreeCollisionManager`` over the triangles' boxes
    finds the pairs whose boxes overlap; pairs that share a vertex are dropped, and each remaining pair goes
    through ``fcl.collide`` of two one-triangle ``BVHModel``\\ s (global coordinates, identity transform).
  - ``method="bvh"``: the literal way, one ``BVHModel`` of the whole mesh collided with itself (every
    contact collected, ~60k per SCAPE mesh, almost all between neighbours, which are then dropped). About
    4x slower; kept as the reference the tests compare ``broadphase`` with.
  - ``method="grid"``: the candidate pairs from neuralcol's own uniform-grid box test (ExactLabeler's
    broadphase, cell ``cell_factor`` mean triangle boxes), the contacts from FCL as in ``broadphase``. The
    same pairs (both are exact box-overlap tests; tested), without the ~100 ms per SCAPE mesh that
    python-fcl's per-pair Python callback costs: ~0.55x the full label's time and ~0.4x the verdict's.

* **Adjacency.** Every pair of triangles that shares a vertex (one vertex or an edge, and a triangle with
  itself) is dropped, whatever FCL reports for it: FCL's triangle test reports touching neighbours as
  contacts with an arbitrary depth, so it cannot tell two one-vertex neighbours that fold through each other
  from two that merely touch at their vertex. ``ExactLabeler`` does tell them apart (it counts such a local
  fold), so a fold that intersects only one-vertex neighbours is a collision there and not here.
* **Verdict.** A pair is counted iff one of its FCL contacts has ``penetration_depth > tau``; the mesh
  self-collides iff some pair is counted (:meth:`FCLLabeler.verdict` stops at the first).
* **PD_i (colliding part).** For part ``i`` of the vertex partition (one part if none): if a counted pair
  touches part ``i`` (a corner of one of its triangles lies in part ``i``), ``PD_i`` = the largest FCL
  ``penetration_depth`` of the counted pairs touching it (> tau > 0).
* **PD_i (free part): clearance.** Otherwise ``PD_i = -min(cap, clearance_i)``, where ``clearance_i`` is the
  smallest ``fcl.distance`` between two *patches* that are far apart in the rest mesh, one of them touching
  part ``i``. Patches: the triangles are grouped by the set of parts their corners lie in, and each group is
  cut (median splits of the rest centroids along the widest axis) into patches of at most ``patch_size``
  triangles (default 16, ~4 edge lengths across). Two patches are *near* when their ``fcl.distance`` in the
  rest mesh is ``<= cap`` (so every pair of triangles sharing a vertex, and the mesh's own neighbourhoods,
  are near) and *far* otherwise; only far pairs of patches count, each through a ``DistanceRequest``
  between the two patches' ``BVHModel``\\ s (candidates from the same box broadphase with boxes grown by
  ``cap / 2``; a pair whose lower bound, the larger of its box gap and bounding-sphere gap, cannot lower a
  free part's clearance is skipped). So the rest mesh has ``PD = -cap``, and separate parts (an arm and the
  torso, two legs) count with their real distance as they approach each other.
* **PD.** ``PD = max_i PD_i``: > 0 iff the mesh self-collides (then the deepest FCL contact depth),
  otherwise minus the capped clearance.

Differences from ``ExactLabeler`` (``docs/studies/fcl_backend.md``):

* verdict, approximate: FCL's triangle test is in floating point with its own tolerances, so configurations within
  round-off of contact (coplanar overlaps, near-coplanar crossings, exact touching) may be judged either way;
  ``ExactLabeler`` decides them exactly (``labeling=cpu``);
* verdict: one-vertex neighbours that fold through each other are not counted (above);
* colliding PD: FCL's contact depth is local to a triangle pair and not continuous: it jumps from "no
  contact" to about the height of the piercing triangle when a triangle enters another through its edge
  (``python -m research.fcl_depth_continuity``), where ours is the translational depth of the penetrating
  region, 0 at first contact;
* free PD: near pairs (within cap in the rest mesh, at patch granularity) never lower the clearance, so
  a fold or two nearby surfaces closing in keep ``PD = -cap`` until they collide (ours measures their
  separation relative to the rest mesh); far pairs count with their distance, as ours do, but a pair is
  "near" here when their *patches* are within cap at rest, which excludes a little more;
* speed (``python -m bench.run --only fcl``, SCAPE, one core): full label ~210 ms per mesh against ~17 ms
  for ours (~12x), verdict ~130 ms against ~4 ms; ``method="grid"`` ~115 / ~50 ms; ``method="bvh"``
  ~600 ms for the contacts alone.

Every FCL object is built per call from numpy arrays, so the labeler pickles (LabelPool sends it to its
worker processes) with no FCL state.
"""

from __future__ import annotations

import numpy as np

from neuralcol.collision.labeler import Label, MeshByMesh, checked_partition
from neuralcol.geometry.topology import edge_topology

METHODS = ("broadphase", "bvh", "grid")
_FACE = np.array([[0, 1, 2]], dtype=np.int64)
_MAX_CONTACTS = 64  # contacts kept per triangle pair (FCL reports a few per pair)


def _fcl():
    import fcl

    return fcl


def _bvh(vertices: np.ndarray, faces: np.ndarray):
    """A python-fcl ``BVHModel`` (global coordinates) wrapped in a ``CollisionObject`` (identity transform)."""
    fcl = _fcl()
    m = fcl.BVHModel()
    m.beginModel(len(vertices), len(faces))
    m.addSubModel(vertices, faces)
    m.endModel()
    return fcl.CollisionObject(m)


def _bits_hash(x: np.ndarray) -> np.ndarray:
    """(N, 3) float64 -> (N,) int64 hash of the exact bits (wrapping arithmetic)."""
    b = np.ascontiguousarray(x, dtype=np.float64).view(np.int64).reshape(-1, 3)
    with np.errstate(over="ignore"):
        return (b[:, 0] * np.int64(-7046029254386353131)) ^ (b[:, 1] * np.int64(-4658895280553007687)) ^ b[:, 2]


def box_pairs(lo: np.ndarray, hi: np.ndarray, grow: float = 0.0) -> np.ndarray:
    """Pairs of boxes that overlap once grown by ``grow`` on every side, from FCL's dynamic AABB tree.

    Each box becomes an ``fcl.Box`` placed at its centre; python-fcl passes the two objects of a pair back to
    the callback as new wrappers whose only usable handle is their translation, so every box gets a distinct
    translation (boxes that share a centre, e.g. the two triangles of an axis-aligned quad, are shifted apart
    by a few ulps and grown by as much) and the pairs are mapped back through it.

    Args:
        lo, hi: (N, 3) float box corners.
        grow: margin added on every side.

    Returns:
        (P, 2) int64 pairs ``i < j``, sorted, unique.
    """
    fcl = _fcl()
    lo = np.asarray(lo, dtype=np.float64) - grow
    hi = np.asarray(hi, dtype=np.float64) + grow
    n = len(lo)
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64)
    centers = np.ascontiguousarray(0.5 * (lo + hi))
    size = np.maximum(hi - lo, 0.0)
    for _ in range(100):  # make the centres' hashes distinct (equal centres have equal hashes)
        h = _bits_hash(centers)
        order = np.argsort(h, kind="stable")
        dup = np.zeros(n, dtype=bool)
        dup[order[1:]] = h[order[1:]] == h[order[:-1]]
        if not dup.any():
            break
        shift = np.abs(centers[dup, 0]) * 1e-14 + 1e-300
        centers[dup, 0] += shift
        size[dup, 0] += 4.0 * shift
    else:  # pragma: no cover - would need ~100 boxes at one centre
        raise RuntimeError("could not give the boxes distinct centres")
    h_sorted = h[order]
    objs = [fcl.CollisionObject(fcl.Box(*s), fcl.Transform(c)) for s, c in zip(size.tolist(), centers)]
    manager = fcl.DynamicAABBTreeCollisionManager()
    manager.registerObjects(objs)
    manager.setup()
    found: list[np.ndarray] = []

    def collect(o1, o2, _data) -> bool:
        found.append(o1.getTranslation())
        found.append(o2.getTranslation())
        return False  # never done: every overlapping pair

    manager.collide(None, collect)
    if not found:
        return np.zeros((0, 2), dtype=np.int64)
    query = np.asarray(found, dtype=np.float64)
    ids = order[np.minimum(np.searchsorted(h_sorted, _bits_hash(query)), n - 1)]
    if not (centers[ids] == query).all():  # pragma: no cover - FCL returns the translations it was given
        raise RuntimeError("python-fcl returned a box translation that matches no box")
    ids = ids.reshape(-1, 2)
    ids = ids[ids[:, 0] != ids[:, 1]]
    keys = np.unique(np.minimum(ids[:, 0], ids[:, 1]) * n + np.maximum(ids[:, 0], ids[:, 1]))
    return np.stack([keys // n, keys % n], axis=1)


def _box_gap(lo: np.ndarray, hi: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Euclidean gap between the boxes of each pair (0 when they overlap): a lower bound of the distance."""
    a, b = pairs[:, 0], pairs[:, 1]
    d = np.maximum(0.0, np.maximum(lo[a] - hi[b], lo[b] - hi[a]))
    return np.sqrt((d * d).sum(1))


class FCLLabeler(MeshByMesh):
    """The paper's labels from python-fcl, with ExactLabeler's interface (see the module docstring).

    Args:
        faces: (F, 3) int triangles.
        rest_vertices: (V, 3) float rest mesh: sets ``ell``, ``diag`` and which patches are near (it should be
            free of self-intersections).
        partition: (V,) int part of each vertex in [0, K) for PD_i; None means one part.
        touch_tol: ``tau = touch_tol * ell``; contacts up to tau deep do not count.
        clearance_cap: ``cap = clearance_cap * diag``; clearances are capped there.
        boundary_eps: ``eps = boundary_eps * diag`` for the D_p / D_b split (paper eq. 1).
        cell_factor: grid cell in mean triangle box sizes, for ``method="grid"`` only (accepted for the same
            settings as ExactLabeler, ``conf/labeling``; FCL's dynamic AABB tree needs no cell size).
        patch_size: most triangles per clearance patch (see the module docstring).
        method: ``"broadphase"`` (per-triangle pairs from FCL's AABB tree, default), ``"bvh"`` (the whole
            mesh's BVH collided with itself) or ``"grid"`` (candidate pairs from neuralcol's grid, contacts from
            FCL); same contacts.
    """

    backend = "fcl"  # labeling=fcl (conf/labeling/fcl.yaml)
    label_kind = "fcl"  # another definition of PD than ExactLabeler's: cached apart (neuralcol.samples.cache)
    batched = False

    def __init__(self, faces, rest_vertices, partition=None, touch_tol: float = 1e-6,
                 clearance_cap: float = 0.01, boundary_eps: float = 1e-4, cell_factor: float = 2.0,
                 patch_size: int = 16, method: str = "broadphase", far_clusters: int = 6):
        del far_clusters  # ExactLabeler's far-pass setting (labeling=fcl shares conf/labeling/cpu.yaml); unused here
        _fcl()  # fail early, with the import error, when python-fcl is missing
        self.faces = np.ascontiguousarray(np.asarray(faces, dtype=np.int64))
        rest = np.ascontiguousarray(np.asarray(rest_vertices, dtype=np.float64))
        if rest.ndim != 2 or rest.shape[1] != 3:
            raise ValueError(f"rest_vertices have shape {rest.shape}, expected (V, 3)")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise ValueError(f"faces have shape {self.faces.shape}, expected (F, 3)")
        if touch_tol < 0 or clearance_cap <= 0 or boundary_eps < 0:
            raise ValueError("touch_tol and boundary_eps must be >= 0 and clearance_cap > 0")
        if method not in METHODS:
            raise ValueError(f"method={method!r}: use one of {', '.join(METHODS)}")
        if int(patch_size) < 1:
            raise ValueError("patch_size must be >= 1")
        self.method = method
        self.patch_size = int(patch_size)
        self.cell_factor = float(cell_factor)
        self.rest = rest
        self.n_vertices = len(rest)
        edges = edge_topology(self.faces).edges
        self.ell = float(np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1).mean())
        self.diag = float(np.linalg.norm(rest.max(0) - rest.min(0)))
        tri = rest[self.faces]
        self.cell = self.cell_factor * float((tri.max(1) - tri.min(1)).max(1).mean()) if len(tri) else 1.0
        self.tau = touch_tol * self.ell
        self.cap = clearance_cap * self.diag
        self.eps = boundary_eps * self.diag
        self._margin = 1e-9 * self.diag  # box round-off (FCL stores a box as centre +- half size)
        self.set_partition(partition)

    # ------------------------------------------------------------------ configuration
    def set_partition(self, partition) -> None:
        """Set the vertex partition (V,) int in [0, K) used for PD_i (None: one part); rebuilds the patches."""
        part = checked_partition(partition, self.n_vertices)
        self.partition = part
        self.n_parts = int(part.max()) + 1
        self._tri_part = part[self.faces]  # (F, 3) part of each corner
        self._build_patches()

    def _build_patches(self) -> None:
        """Clearance patches (module docstring) and the pairs of them that are near in the rest mesh."""
        n_faces = len(self.faces)
        s = np.sort(self._tri_part, axis=1)
        canon = s.copy()  # the set of parts of each triangle: sorted, repeats replaced by -1, sorted again
        canon[:, 1] = np.where(s[:, 1] == s[:, 0], -1, s[:, 1])
        canon[:, 2] = np.where(s[:, 2] == s[:, 1], -1, s[:, 2])
        canon.sort(axis=1)
        _, group = np.unique(canon, axis=0, return_inverse=True)
        group = group.reshape(-1)
        centroids = self.rest[self.faces].mean(1)
        patch_of = np.empty(n_faces, dtype=np.int64)
        n_patches = 0
        for g in range(int(group.max()) + 1 if n_faces else 0):
            stack = [np.flatnonzero(group == g)]
            while stack:
                ids = stack.pop()
                if len(ids) <= self.patch_size:
                    patch_of[ids] = n_patches
                    n_patches += 1
                    continue
                c = centroids[ids]
                axis = int(np.argmax(c.max(0) - c.min(0)))
                order = ids[np.argsort(c[:, axis], kind="stable")]
                half = len(order) // 2
                stack += [order[half:], order[:half]]
        self.n_patches = n_patches
        self._patch_of = patch_of
        self._patch_order = np.argsort(patch_of, kind="stable")
        self._patch_ptr = np.searchsorted(patch_of[self._patch_order], np.arange(n_patches + 1)).astype(np.int64)
        parts = np.zeros((n_patches, self.n_parts), dtype=bool)
        parts[np.repeat(patch_of, 3), self._tri_part.reshape(-1)] = True
        self._patch_parts = parts
        # near patch pairs: FCL distance in the rest mesh <= cap (candidates: boxes within cap)
        lo, hi = self._patch_boxes(self.rest)
        cand = box_pairs(lo, hi, 0.5 * self.cap + self._margin)
        objs: dict[int, object] = {}
        near = [self._patch_distance(self.rest, int(p), int(q), objs) <= self.cap for p, q in cand]
        near_pairs = cand[np.asarray(near, dtype=bool)] if len(cand) else cand
        self._near_keys = np.sort(near_pairs[:, 0] * max(n_patches, 1) + near_pairs[:, 1])

    # ------------------------------------------------------------------ helpers
    def _patch_boxes(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tri = v[self.faces[self._patch_order]]  # (F, 3, 3) in patch order
        starts = self._patch_ptr[:-1]
        return np.minimum.reduceat(tri.min(1), starts), np.maximum.reduceat(tri.max(1), starts)

    def _patch_gaps(self, v: np.ndarray, lo: np.ndarray, hi: np.ndarray, pairs: np.ndarray) -> np.ndarray:
        """Lower bound of each patch pair's distance: the larger of their boxes' gap and their bounding spheres'
        gap (centre: the box centre); ``lo, hi``: the patches' boxes. Tighter bounds (the gaps between the
        patches' triangle boxes) cost about as much as the distance queries they save."""
        center = 0.5 * (lo + hi)
        tri = v[self.faces[self._patch_order]]
        reach = np.linalg.norm(tri - center[self._patch_of[self._patch_order], None, :], axis=2).max(1)
        radius = np.maximum.reduceat(reach, self._patch_ptr[:-1])
        p, q = pairs[:, 0], pairs[:, 1]
        sphere = np.linalg.norm(center[p] - center[q], axis=1) - radius[p] - radius[q]
        return np.maximum(_box_gap(lo, hi, pairs), sphere)

    def _patch_distance(self, v: np.ndarray, p: int, q: int, objs: dict) -> float:
        """``fcl.distance`` between patches p and q (their BVHs built once per call, kept in ``objs``)."""
        fcl = _fcl()
        for k in (p, q):
            if k not in objs:
                tris = self._patch_order[self._patch_ptr[k]:self._patch_ptr[k + 1]]
                objs[k] = _bvh(v[self.faces[tris]].reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3))
        res = fcl.DistanceResult()
        d = fcl.distance(objs[p], objs[q], fcl.DistanceRequest(), res)
        return max(float(d), 0.0)

    def _shares_vertex(self, pairs: np.ndarray) -> np.ndarray:
        f = self.faces
        return (f[pairs[:, 0], :, None] == f[pairs[:, 1], None, :]).any((1, 2))

    def _pair_depth(self, v: np.ndarray, a: int, b: int, objs: dict) -> float:
        """Deepest FCL contact of triangles a and b (-inf when FCL reports none)."""
        fcl = _fcl()
        for k in (a, b):
            if k not in objs:
                objs[k] = _bvh(v[self.faces[k]], _FACE)
        res = fcl.CollisionResult()
        fcl.collide(objs[a], objs[b], fcl.CollisionRequest(num_max_contacts=_MAX_CONTACTS, enable_contact=True), res)
        return max((c.penetration_depth for c in res.contacts), default=-np.inf)

    def candidate_pairs(self, vertices) -> np.ndarray:
        """Triangle pairs sharing no vertex whose boxes overlap (FCL's AABB tree, or the grid with
        ``method="grid"``): (P, 2) int64, ``a < b``, sorted."""
        v = self._check(vertices)
        tri = v[self.faces]
        lo, hi = tri.min(1) - self._margin, tri.max(1) + self._margin
        if self.method == "grid":
            from neuralcol.collision.kernels.broadphase import grid_pairs

            found = np.sort(grid_pairs(lo, hi, self.cell), axis=1)
            n = len(self.faces)
            keys = np.unique(found[:, 0] * n + found[:, 1])
            pairs = np.stack([keys // n, keys % n], axis=1)
        else:
            pairs = box_pairs(lo, hi)
        return pairs[~self._shares_vertex(pairs)] if len(pairs) else pairs

    def counted_pairs(self, vertices, first_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Counted pairs (module docstring) and their depths: (P, 2) int64 sorted, (P,) float64.

        ``first_only``: stop at the first counted pair (the verdict; not with ``method="bvh"``, which collects
        every contact in one call).
        """
        v = self._check(vertices)
        if self.method == "bvh":
            return self._counted_pairs_bvh(v)
        objs: dict[int, object] = {}
        keep, depth = [], []
        for a, b in self.candidate_pairs(v):
            d = self._pair_depth(v, int(a), int(b), objs)
            if d > self.tau:
                keep.append((a, b))
                depth.append(d)
                if first_only:
                    break
        if not keep:
            return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
        return np.asarray(keep, dtype=np.int64), np.asarray(depth, dtype=np.float64)

    def _counted_pairs_bvh(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The whole mesh's BVH collided with itself; every contact collected, then filtered."""
        fcl = _fcl()
        obj = _bvh(v, self.faces)
        res = fcl.CollisionResult()
        fcl.collide(obj, obj, fcl.CollisionRequest(num_max_contacts=2**62, enable_contact=True), res)
        if not res.contacts:
            return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
        b = np.array([(c.b1, c.b2) for c in res.contacts], dtype=np.int64)
        depth = np.array([c.penetration_depth for c in res.contacts], dtype=np.float64)
        b.sort(axis=1)
        ok = ~self._shares_vertex(b) & (depth > self.tau)
        b, depth = b[ok], depth[ok]
        if not len(b):
            return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
        pairs, inv = np.unique(b, axis=0, return_inverse=True)
        best = np.full(len(pairs), -np.inf)
        np.maximum.at(best, inv.reshape(-1), depth)
        return pairs, best

    # ------------------------------------------------------------------ queries
    def verdict(self, vertices) -> bool:
        """True iff the mesh self-collides (FCL contact deeper than tau between triangles sharing no vertex)."""
        return bool(len(self.counted_pairs(vertices, first_only=True)[0]))

    def intersecting_pairs(self, vertices) -> np.ndarray:
        """All counted triangle pairs, (P, 2) int64 sorted."""
        return self.counted_pairs(vertices)[0]

    def clearances(self, vertices, skip=None) -> np.ndarray:
        """``min(cap, clearance_i)`` of every part (module docstring), (K,) float64.

        Args:
            vertices: (V, 3).
            skip: (K,) bool, parts whose clearance is not needed (e.g. colliding ones): pairs touching only
                such parts are not evaluated, and their entries are not meaningful.
        """
        v = self._check(vertices)
        clear = np.full(self.n_parts, self.cap)
        need = np.ones(self.n_parts, dtype=bool) if skip is None else ~np.asarray(skip, dtype=bool)
        if self.n_patches < 2 or not need.any():
            return clear
        lo, hi = self._patch_boxes(v)
        cand = box_pairs(lo, hi, 0.5 * self.cap + self._margin)
        if not len(cand):
            return clear
        keys = cand[:, 0] * self.n_patches + cand[:, 1]
        pos = np.minimum(np.searchsorted(self._near_keys, keys), max(len(self._near_keys) - 1, 0))
        far = ~(self._near_keys[pos] == keys) if len(self._near_keys) else np.ones(len(cand), dtype=bool)
        cand = cand[far]
        gap = self._patch_gaps(v, lo, hi, cand)
        order = np.argsort(gap, kind="stable")
        objs: dict[int, object] = {}
        for p, q, g in zip(cand[order, 0], cand[order, 1], gap[order]):
            touched = (self._patch_parts[p] | self._patch_parts[q]) & need
            if not touched.any() or g >= clear[touched].max():
                continue  # cannot lower any needed part's clearance
            d = self._patch_distance(v, int(p), int(q), objs)
            clear[touched] = np.minimum(clear[touched], d)
        return clear

    def label(self, vertices) -> Label:
        """Verdict, number of counted pairs, PD and PD_i of one mesh (V, 3)."""
        v = self._check(vertices)
        pairs, depth = self.counted_pairs(v)
        pen = np.zeros(self.n_parts)
        if len(pairs):
            parts = self._tri_part[pairs].reshape(len(pairs), 6)
            np.maximum.at(pen, parts.reshape(-1), np.repeat(depth, 6))
        colliding = pen > 0.0
        clear = self.clearances(v, skip=colliding)
        pd_sub = np.where(colliding, pen, -np.minimum(clear, self.cap))
        return Label(bool(len(pairs) > 0), int(len(pairs)), float(pd_sub.max()), pd_sub)

    def __getstate__(self) -> dict:
        # numpy arrays and settings only: every FCL object is built per call, none is ever an attribute
        return dict(self.__dict__)

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
