"""Exact self-collision labels of triangle meshes: verdict, signed penetration depth PD and per-part PD_i.

Definitions (units: those of the vertex coordinates; ``ell`` = mean edge length and ``diag`` = bounding-box
diagonal of the rest mesh the labeler is built with):

* **Adjacency.** Two triangles are adjacent iff they share an edge; adjacent pairs never count. Pairs that
  share one vertex count when they meet anywhere other than that vertex (a local fold); pairs sharing
  no vertex count when their interiors meet at all.
* **Intersecting pair** (exact). The two triangles' relative interiors intersect: they cross, or they lie in one
  plane and overlap with positive area; touching (a corner on the other triangle, an edge along it, coplanar
  triangles meeting along an edge) does not count, and a triangle with collinear corners has no interior.
  Decided with exact orientation predicates on the float coordinates given
  (:mod:`~neuralcol.collision.kernels.predicates`), so at every scale.
* **Pair depth.** ``d(s, t)`` = translational penetration depth of the two triangles, by the separating-axis
  theorem over the 17 face normals of their Minkowski difference (2 normals, 9 edge-edge, 6 in-plane edge
  normals). It is > 0 when the triangles cross, 0 when they merely touch (a shared vertex, an edge lying on
  a face), continuous in the vertices. A coplanar overlap (17-axis depth 0) takes its in-plane depth, over
  the 6 in-plane edge normals alone.
* **Verdict.** The mesh self-collides iff some non-adjacent pair intersects (with ``touch_tol > 0``, and has
  ``d > tau``, ``tau = touch_tol * ell``: crossings that shallow count as touching; default ``touch_tol = 0``,
  exact). A counted pair's penetration is ``max(d - tau, 2**-126)``, so ``PD > 0`` iff the mesh collides even
  for a crossing below round-off.
* **Penetrating vertices.** Every edge of a counted pair that properly crosses the other triangle is a
  crossing edge; its endpoint behind the pierced triangle (against the outward normal) is a seed. On a
  closed mesh the penetrating region of a seed is everything reachable from it over edges that do not cross
  the surface (a flood fill bounded by the intersection curves): the part of the surface inside another
  part's volume. On a mesh with boundary (cloth) a region is its seeds only.
* **Depth.** A penetrating vertex's depth is its distance to the opposing surface: the triangles its region
  pierces plus the triangles of the other penetrating regions (for two overlapping spheres, the cap of one
  that lies inside the other). On a mesh with boundary, a seed's depth is the distance of the nearer
  endpoint of its crossing edge to the pierced triangle (how far the edge must move to stop crossing).
* **Clearance.** Every non-adjacent pair whose boxes are within ``cap = clearance_cap * diag`` contributes
  a term ``c(s, t)`` that is 0 exactly when the pair overlaps (beyond ``tau``) and grows as it separates:
  pairs that are farther apart than ``cap`` in the rest mesh ("far") contribute their Euclidean distance;
  pairs within ``cap`` in the rest mesh ("near", including all pairs sharing one vertex) contribute
  ``cap * m / m_rest``, their separation relative to the rest mesh, where ``m`` is the SAT separation of
  the two triangles (the largest gap between their projections on the 17 axes above, a lower bound of
  the distance) or, for pairs sharing one vertex, the chordal gap between the two corners at that vertex.
  So the rest mesh's own neighbourhoods sit at the cap and only count once they come closer than at rest,
  while separate parts (two fingers, an arm and the torso) count with their real distance. Which formula
  a pair uses is fixed by the rest mesh, so ``c`` is continuous in the vertices.
* **PD_i and PD.** Given a vertex partition into K parts (one part if none is given):
  ``PD_i = max(depth of the penetrating vertices of part i, penetration of the counted pairs touching
  part i)`` if that is > 0, otherwise ``PD_i = -min(cap, min c(s, t) over pairs touching part i)``.
  ``PD = max_i PD_i``. So ``PD > 0`` iff the mesh self-collides; PD is the deepest penetration when it
  does and minus the (capped) clearance when it does not; both sides go to 0 at the contact, and a part
  that is not involved in a collision keeps its clearance. Units: length, like the vertices.
* **Clearance limit** (labels for training). ``label(v, clearance_limit=L)`` caps clearances at
  ``min(cap, L)`` instead of ``cap``: ``PD_i = max(PD_i, -L)``, everything else unchanged (verdict, counted
  pairs, positive PD_i bit for bit). The detector's targets are clipped to a band of the cap (``detector.targets``),
  so with ``L`` at the band's edge the clipped targets are bit for bit those of the full label, while the passes
  skip every pair that could only lower a clearance that is already below ``L`` (about half of a free
  mesh's label).

See ``docs/labels.md`` for the reasoning, and why python-fcl's triangle-pair contact depth was not used for
PD (measured: it jumps from 0 to a large value when a triangle enters another from its side).
"""

from __future__ import annotations

from functools import cached_property
from typing import NamedTuple

import numpy as np

from neuralcol.collision.kernels.broadphase import drop_adjacent, grid_pairs, triangle_aabbs
from neuralcol.collision.kernels.closed_rule import closed_pairs_mask, degenerate_faces
from neuralcol.collision.kernels.clusters import cluster_boxes, rest_clusters, static_blocks
from neuralcol.collision.kernels.depth import triangle_axes
from neuralcol.collision.kernels.distance import corner_cones
from neuralcol.collision.kernels.label_pass import counted_pass, finish_label, label_mesh, verdict_kernel
from neuralcol.collision.kernels.pair_terms import counted_mask, near_table
from neuralcol.collision.kernels.penetration import crossing_seeds, penetration
from neuralcol.collision.kernels.pruned_pass import far_pass, far_pass_clusters, near_pass
from neuralcol.collision.kernels.vec import GAP_ROUNDOFF
from neuralcol.geometry.topology import edge_faces, edge_topology, vertex_neighbors


class Penetrations(NamedTuple):
    """The penetrating vertices of one mesh (:meth:`ExactLabeler.penetrations`).

    Attributes:
        n_pairs: counted intersecting triangle pairs (0: the mesh is free).
        depth: (V,) each vertex's penetration depth (0 where it does not penetrate; the labeler's PD is the largest).
        vector: (V, 3) from each penetrating vertex to the nearest point of its opposing surface (zeros elsewhere;
            on a mesh with boundary or in a local fold: from the nearer end of a crossing edge to the triangle it
            pierces, given to that end).
        crossing_pairs: (P, 2) int64 sorted rows, the counted triangle pairs (sharing no edge, depth > touch
            tolerance) with an edge of one through the other among the crossing records (each record's edge gives
            both its triangles): the intersecting pairs without a second broadphase (the untangle contour step).
    """

    n_pairs: int
    depth: np.ndarray
    vector: np.ndarray
    crossing_pairs: np.ndarray


class Label(NamedTuple):
    """Label of one mesh.

    Attributes:
        collides: the verdict.
        n_pairs: number of counted intersecting triangle pairs.
        pd: signed penetration depth (> 0 iff ``collides``).
        pd_sub: (K,) float64 per-part PD_i (``pd == pd_sub.max()``).
    """

    collides: bool
    n_pairs: int
    pd: float
    pd_sub: np.ndarray


class Labels(NamedTuple):
    """Labels of a batch of B meshes: collides (B,) bool, n_pairs (B,) int64, pd (B,) float64,
    pd_sub (B, K) float64."""

    collides: np.ndarray
    n_pairs: np.ndarray
    pd: np.ndarray
    pd_sub: np.ndarray

    @staticmethod
    def stack(labels: list[Label], n_parts: int = 1) -> Labels:
        """Stack single labels; ``n_parts`` gives pd_sub's width when ``labels`` is empty."""
        if not labels:
            return Labels(np.zeros(0, bool), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, n_parts)))
        return Labels(np.array([lb.collides for lb in labels], dtype=bool),
                      np.array([lb.n_pairs for lb in labels], dtype=np.int64),
                      np.array([lb.pd for lb in labels], dtype=np.float64),
                      np.stack([lb.pd_sub for lb in labels]).astype(np.float64))


def gap_roundoff(vertices: np.ndarray) -> float:
    """How far a computed gap between two triangles of this mesh (V, 3) may be off by round-off:
    ``GAP_ROUNDOFF`` x the largest coordinate. A pair apart by more is apart without the exact test."""
    return float(GAP_ROUNDOFF * np.abs(vertices).max()) if vertices.size else 0.0


# On meshes of this many faces or more, the counted pairs are found again only where the mesh moved since the last
# check (ExactLabeler._counted_pairs), unless more than this share of its triangles moved.
INCREMENTAL_FACES = 20_000
INCREMENTAL_SHARE = 0.25

# The definition of the labels, part of the label caches' key (neuralcol.samples.cache): 2 = exact verdicts
# (orientation predicates; coplanar overlaps count; touch_tol 0 by default).
LABEL_VERSION = 2

SUBSET_POSITIVE, SUBSET_NEGATIVE, SUBSET_BOUNDARY = 0, 1, 2
SUBSET_NAMES = ("D_p", "D_n", "D_b")


def split_subsets(pd: np.ndarray, eps: float) -> np.ndarray:
    """Paper eq. 1: D_p (PD > eps) -> 0, D_n (PD < 0) -> 1, D_b (0 <= PD <= eps) -> 2.

    Args:
        pd: (B,) signed penetration depths.
        eps: absolute threshold (the labeler's ``eps`` = ``boundary_eps * diag``).

    Returns:
        (B,) int8 subset codes.
    """
    pd = np.asarray(pd)
    out = np.full(pd.shape, SUBSET_BOUNDARY, dtype=np.int8)
    out[pd > eps] = SUBSET_POSITIVE
    out[pd < 0] = SUBSET_NEGATIVE
    return out


def checked_partition(partition, n_vertices: int) -> np.ndarray:
    """The vertex partition as (V,) int64 in [0, K) (None: one part, all zeros); ValueError if malformed."""
    if partition is None:
        return np.zeros(n_vertices, dtype=np.int64)
    part = np.asarray(partition, dtype=np.int64).reshape(-1)
    if part.shape != (n_vertices,):
        raise ValueError(f"partition has shape {part.shape}, expected ({n_vertices},)")
    if part.min() < 0:
        raise ValueError("partition entries must be >= 0")
    return part


def limit_clearance(label: Label, clearance_limit: float | None) -> Label:
    """``label`` with its clearances capped at ``clearance_limit`` (``PD_i = max(PD_i, -limit)``; None: as is):
    what ``ExactLabeler.label(v, clearance_limit=...)`` returns, for labelers that only compute the full label."""
    if clearance_limit is None:
        return label
    pd_sub = np.maximum(label.pd_sub, -float(clearance_limit))
    return Label(label.collides, label.n_pairs, float(pd_sub.max()), pd_sub)


def check_clearance_limit(clearance_limit) -> float | None:
    """``clearance_limit`` as a float > 0 (None stays None); ValueError otherwise."""
    if clearance_limit is None:
        return None
    limit = float(clearance_limit)
    if not limit > 0:  # also NaN
        raise ValueError(f"clearance_limit={clearance_limit!r} must be > 0 (a length), or None for the full label")
    return limit


class MeshByMesh:
    """``label_batch`` and ``subsets`` of a labeler that labels one mesh at a time with its ``label`` (and has
    ``n_vertices``, ``n_parts`` and ``eps``), and the check of one mesh's vertices: :class:`ExactLabeler` and
    :class:`~neuralcol.collision.fcl_labeler.FCLLabeler`."""

    def _check(self, vertices) -> np.ndarray:
        """One mesh's vertices as (V, 3) contiguous float64; ValueError if the shape is wrong or not finite."""
        v = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64))
        if v.shape != (self.n_vertices, 3):
            raise ValueError(f"vertices have shape {v.shape}, expected ({self.n_vertices}, 3)")
        if not np.isfinite(v).all():
            raise ValueError("vertices contain NaN or inf; cannot label")
        return v

    def label_batch(self, vertices, clearance_limit: float | None = None) -> Labels:
        """Labels of a batch (B, V, 3), one mesh after the other in this process (worker processes:
        :class:`~neuralcol.collision.pool.LabelPool`); ``clearance_limit`` as :meth:`label_limited`."""
        v = np.asarray(vertices)
        if v.ndim != 3:
            raise ValueError(f"vertices have shape {v.shape}, expected (B, {self.n_vertices}, 3)")
        return Labels.stack([self.label_limited(x, clearance_limit) for x in v], self.n_parts)

    def label_limited(self, vertices, clearance_limit: float | None = None) -> Label:
        """:meth:`label` with clearances capped at ``clearance_limit`` (module docstring of
        :mod:`neuralcol.collision.labeler`); a labeler without a faster path caps its full label."""
        return limit_clearance(self.label(vertices), check_clearance_limit(clearance_limit))

    def subsets(self, pd: np.ndarray) -> np.ndarray:
        """D_p / D_n / D_b codes of PD values with this labeler's ``eps`` (see :func:`split_subsets`)."""
        return split_subsets(pd, self.eps)


class ExactLabeler(MeshByMesh):
    """Exact self-collision labels for meshes of one topology (see the module docstring).

    Args:
        faces: (F, 3) int triangles.
        rest_vertices: (V, 3) float rest mesh: sets ``ell``, ``diag`` and the rest distances of the
            clearance; it should be free of self-intersections.
        partition: (V,) int part of each vertex in [0, K) for PD_i; None means one part.
        touch_tol: 0 (default): exact verdicts; > 0: crossings no deeper than ``tau = touch_tol * ell`` count as
            touching.
        clearance_cap: ``cap = clearance_cap * diag``; clearances are capped there.
        boundary_eps: ``eps = boundary_eps * diag`` for the D_p / D_b split (paper eq. 1).
        cell_factor: grid cell size of the broadphase in units of the mean triangle box size.
        prune: skip the pairs that provably cannot lower a part's clearance (default); False evaluates every
            pair within cap, the reference path (same labels, quadratic in the mesh density; see
            ``docs/studies/labeler_scaling.md``).
        far_clusters: triangles per rest-mesh cluster (1-8) of the far pass's broadphase
            (:mod:`~neuralcol.collision.kernels.clusters`); 0 uses one grid over every triangle instead, the path
            before clusters (same labels bit for bit, slower).
        clearance: True (default): the full label. False: no clearance is measured: the verdict, the counted pairs
            and the PD_i of every part a counted pair or a penetrating vertex touches are those of the full label (bit
            for bit), every other part's PD_i is ``-cap`` (what the full label gives a mesh at its rest clearance,
            e.g. the rest mesh itself). Only the pairs whose boxes overlap are visited, so the labeler never builds
            the rest mesh's near table: set-up and label linear in the faces, where the table grows with the square
            of the mesh's density (124 k faces: ~2 min and GBs). For checks and repairs of large meshes.

    The near table and the far pass's clusters are built on the first call that needs a clearance (``label``,
    ``label_limited``, ``vertex_depths`` with ``clearance=True``); ``verdict``, ``intersecting_pairs`` and
    ``penetrations`` never build them.
    """

    backend = "cpu"  # labeling=cpu (conf/labeling/cpu.yaml)
    label_version = LABEL_VERSION

    def __init__(self, faces, rest_vertices, partition=None, touch_tol: float = 0.0,
                 clearance_cap: float = 0.01, boundary_eps: float = 2e-3, cell_factor: float = 2.0,
                 prune: bool = True, far_clusters: int = 6, clearance: bool = True):
        self.clearance = bool(clearance)
        self.faces = np.ascontiguousarray(np.asarray(faces, dtype=np.int64))
        rest = np.ascontiguousarray(np.asarray(rest_vertices, dtype=np.float64))
        if rest.ndim != 2 or rest.shape[1] != 3:
            raise ValueError(f"rest_vertices have shape {rest.shape}, expected (V, 3)")
        if touch_tol < 0 or clearance_cap <= 0 or boundary_eps < 0:
            raise ValueError("touch_tol and boundary_eps must be >= 0 and clearance_cap > 0")
        self.rest = rest
        self.prune = bool(prune)
        self.n_vertices = len(rest)
        self.touch_tol = float(touch_tol)
        self.diag = float(np.linalg.norm(rest.max(0) - rest.min(0)))
        self.cap = clearance_cap * self.diag
        self.eps = boundary_eps * self.diag
        tri = rest[self.faces]
        ext = (tri.max(1) - tri.min(1)).max(1)
        self.cell = cell_factor * float(ext.mean())
        self.set_partition(partition)
        self._rest_centroids = np.ascontiguousarray(tri.mean(1))
        self._cell_factor = float(cell_factor)
        self.far_clusters = int(far_clusters)
        if not 0 <= self.far_clusters <= 8:
            raise ValueError(f"far_clusters={far_clusters!r} must be in [0, 8] (0: no clusters)")
        self._near = None  # (near_ptr, near_b, near_rest, near_shared), built on first need (near_tables)
        self._cluster_state = None

    # ------------------------------------------------------------------ the mesh's edges, built on first need
    # (the verdict needs only the faces and their boxes: a large mesh's check does not pay for these)
    @cached_property
    def _topology(self):
        return edge_topology(self.faces)

    @cached_property
    def edges(self) -> np.ndarray:
        """(E, 2) the mesh's edges, sorted pairs (low, high)."""
        return self._topology.edges

    @cached_property
    def ell(self) -> float:
        """The rest mesh's mean edge length."""
        return float(np.linalg.norm(self.rest[self.edges[:, 0]] - self.rest[self.edges[:, 1]], axis=1).mean())

    def _scale(self) -> float:
        """The depth scale of a verdict: the depth is read only against a touching tolerance, so with none the
        edges need not be built."""
        return self.ell if self.touch_tol else 1.0

    @property
    def tau(self) -> float:
        """The touching tolerance ``touch_tol * ell`` (0: exact verdicts)."""
        return self.touch_tol * self.ell if self.touch_tol else 0.0

    @cached_property
    def closed(self) -> bool:
        """Every edge has two faces."""
        return bool((self._topology.face_count == 2).all())

    @cached_property
    def _edge_faces(self) -> np.ndarray:
        return edge_faces(self._topology.face_edges, len(self.edges))

    @cached_property
    def orient(self) -> float:
        """+1, or -1 where a closed rest mesh encloses a negative volume (its faces wound inwards)."""
        if not self.closed:
            return 1.0
        tri = self.rest[self.faces]
        vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0
        return 1.0 if vol >= 0 else -1.0

    @cached_property
    def _adjacency(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vertex adjacency in CSR form with edge ids (for the flood fill): adj_ptr, adj_idx, adj_eid."""
        nbr = vertex_neighbors(self.edges, self.n_vertices)
        counts = (nbr >= 0).sum(1)
        ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        idx = nbr[nbr >= 0].astype(np.int64)
        lo = np.minimum(np.repeat(np.arange(self.n_vertices), counts), idx)
        hi = np.maximum(np.repeat(np.arange(self.n_vertices), counts), idx)
        eid = np.searchsorted(self.edges[:, 0] * self.n_vertices + self.edges[:, 1],
                              lo * self.n_vertices + hi).astype(np.int64)
        return ptr, idx, eid

    @property
    def adj_ptr(self) -> np.ndarray:
        return self._adjacency[0]

    @property
    def adj_idx(self) -> np.ndarray:
        return self._adjacency[1]

    @property
    def adj_eid(self) -> np.ndarray:
        return self._adjacency[2]

    # ------------------------------------------------------------------ the rest mesh's tables, built on first need
    def near_tables(self) -> None:
        """Build the rest mesh's near table (and the far pass's clusters) if not built yet: every pair within
        ``cap`` at rest with its rest measure, in CSR form (the partners b, sorted, of triangle a are
        ``_near_b[_near_ptr[a]:_near_ptr[a + 1]]``). The clearance terms need it; the verdict does not."""
        if self._near is not None:
            return
        rest, n_faces = self.rest, len(self.faces)
        near_pairs = self.candidate_pairs(rest, inflate=0.5 * self.cap)
        near_keys, near_rest = near_table(rest, self.faces, near_pairs, self.cap, self.ell)
        del near_pairs
        near_b = near_keys % n_faces
        near_ptr = np.searchsorted(near_keys // n_faces, np.arange(n_faces + 1)).astype(np.int64)
        del near_keys
        near_shared = np.zeros(len(near_b), bool)
        a_rows = np.repeat(np.arange(n_faces), np.diff(near_ptr))
        for lo in range(0, len(near_b), 1 << 22):  # in chunks: (N, 3, 3) comparisons at once take GBs
            sl = slice(lo, lo + (1 << 22))
            near_shared[sl] = (self.faces[a_rows[sl], :, None] == self.faces[near_b[sl], None, :]).any((1, 2))
        self._near = (near_ptr, near_b, near_rest, near_shared)
        if self.far_clusters:
            self._make_clusters(self._cell_factor)

    @property
    def _near_ptr(self) -> np.ndarray:
        self.near_tables()
        return self._near[0]

    @property
    def _near_b(self) -> np.ndarray:
        self.near_tables()
        return self._near[1]

    @property
    def _near_rest(self) -> np.ndarray:
        self.near_tables()
        return self._near[2]

    @property
    def _near_shared(self) -> np.ndarray:
        self.near_tables()
        return self._near[3]

    @property
    def _clusters(self):
        self.near_tables()
        return self._cluster_state

    def _make_clusters(self, cell_factor: float) -> None:
        """The far pass's clusters (:mod:`~neuralcol.collision.kernels.clusters`): groups of ``far_clusters``
        triangles close at rest, their rest boxes, and as blocks the far triangle pairs of the cluster pairs whose
        rest boxes overlap (a cluster with itself included)."""
        order, ptr = rest_clusters(self._rest_centroids, self.far_clusters)
        n_clusters = len(ptr) - 1
        rest_lo, rest_hi = cluster_boxes(*triangle_aabbs(self.rest, self.faces, 0.0), order, ptr)
        cell = cell_factor * float((rest_hi - rest_lo).max(1).mean())  # of the grid over the cluster boxes
        close = grid_pairs(rest_lo, rest_hi, cell)
        pairs = np.concatenate([np.repeat(np.arange(n_clusters, dtype=np.int64), 2).reshape(-1, 2), close])
        pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
        blocks, masks = static_blocks(self.faces, order, ptr, pairs, self._near[0], self._near[1])
        n_bits = int(sum(bin(int(m) & 0xFFFFFFFFFFFFFFFF).count("1") for m in masks))
        self._cluster_state = (order, ptr, rest_lo, rest_hi, blocks, masks, n_bits, cell)

    # ------------------------------------------------------------------ configuration
    def set_partition(self, partition) -> None:
        """Set the vertex partition (V,) int in [0, K) used for PD_i (None: one part)."""
        part = checked_partition(partition, self.n_vertices)
        self.partition = part
        self.n_parts = int(part.max()) + 1
        self._tri_part = part[self.faces]  # (F, 3) part of each corner

    # ------------------------------------------------------------------ queries
    def candidate_pairs(self, vertices, inflate: float = 0.0) -> np.ndarray:
        """Non-adjacent triangle pairs whose boxes, grown by ``inflate``, overlap: (P, 2) int64."""
        v = self._check(vertices)
        lo, hi = triangle_aabbs(v, self.faces, inflate)
        return drop_adjacent(self.faces, grid_pairs(lo, hi, max(self.cell, 2 * inflate)))

    def verdict(self, vertices) -> bool:
        """True iff the mesh self-collides (early exit at the first counted pair)."""
        v = self._check(vertices)
        lo, hi = triangle_aabbs(v, self.faces, 0.0)
        return bool(verdict_kernel(v, self.faces, lo, hi, self.cell, self._scale(), self.tau))

    def intersecting_pairs(self, vertices) -> np.ndarray:
        """All counted intersecting triangle pairs, (P, 2) int64 sorted."""
        v = self._check(vertices)
        if len(self.faces) >= INCREMENTAL_FACES:
            return self._counted_pairs(v)
        pairs = self.candidate_pairs(v)
        return pairs[counted_mask(v, self.faces, pairs, self._scale(), self.tau)]

    def _counted_pairs(self, v: np.ndarray) -> np.ndarray:
        """The counted pairs of a large mesh, in lexicographic order, found again only where the mesh moved since the
        last call: a pair of two triangles that did not move keeps its verdict, and the pairs with a moved triangle
        are among the triangles whose boxes overlap the moved ones' bounding box. The repairs check a mesh hundreds of
        times while moving a small part of it; each check then costs the moved region, not the mesh (the same pairs
        as a whole-mesh check, tested)."""
        f = self.faces
        lo, hi = triangle_aabbs(v, f, 0.0)
        last = getattr(self, "_last_pairs", None)
        moved = None
        if last is not None and last[0].shape == v.shape:
            moved_v = (v != last[0]).any(1)
            moved = moved_v[f].any(1)
            if moved.sum() > INCREMENTAL_SHARE * len(f):
                moved = None  # most of the mesh moved (or another mesh): check it whole
        self._last_mode = "whole" if moved is None else ("same" if not moved.any() else "moved")
        if moved is None:
            pairs = drop_adjacent(f, grid_pairs(lo, hi, self.cell))
            pairs = pairs[counted_mask(v, f, pairs, self._scale(), self.tau)]
        elif not moved.any():
            pairs = last[1]
        else:
            old = last[1]
            keep = old[~moved[old].any(1)] if len(old) else old
            mlo, mhi = lo[moved].min(0), hi[moved].max(0)
            sub = np.flatnonzero((hi >= mlo).all(1) & (lo <= mhi).all(1))
            near = sub[grid_pairs(lo[sub], hi[sub], self.cell)]
            near = near[moved[near].any(1)]
            near = drop_adjacent(f, np.sort(near, axis=1))
            pairs = np.concatenate([keep, near[counted_mask(v, f, near, self._scale(), self.tau)]])
        pairs = np.sort(np.asarray(pairs, np.int64).reshape(-1, 2), axis=1)
        pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
        self._last_pairs = (v.copy(), pairs)
        return pairs

    def closed_rule_pairs(self, vertices) -> np.ndarray:
        """The intersecting pairs (P, 2) int64 sorted under CGAL's closed rule (touching counts, edge neighbours
        folded flat count: :mod:`~neuralcol.collision.kernels.closed_rule`), not the paper's; what CGAL's
        ``self_intersections`` reports, pair for pair."""
        v = self._check(vertices)
        lo, hi = triangle_aabbs(v, self.faces, 0.0)
        pairs = grid_pairs(lo, hi, self.cell)
        pairs = pairs[closed_pairs_mask(v, self.faces, pairs)]
        flat = np.flatnonzero(degenerate_faces(v, self.faces))  # CGAL reports a degenerate face with itself
        pairs = np.concatenate([pairs.reshape(-1, 2), np.stack([flat, flat], 1)]).astype(np.int64)
        return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]

    def label(self, vertices) -> Label:
        """Verdict, number of counted pairs, PD and PD_i of one mesh (V, 3)."""
        n_pairs, pd_sub, _ = self._label(vertices)
        return Label(bool(n_pairs > 0), int(n_pairs), float(pd_sub.max()), pd_sub)

    def label_limited(self, vertices, clearance_limit: float | None = None) -> Label:
        """:meth:`label` with clearances capped at ``clearance_limit`` (``PD_i = max(PD_i, -limit)``, module
        docstring): the passes start from that clearance, so every pair that could only lower a clearance below
        it is skipped. None: the full label."""
        limit = check_clearance_limit(clearance_limit)
        n_pairs, pd_sub, _ = self._label(vertices, np.inf if limit is None else limit)
        return Label(bool(n_pairs > 0), int(n_pairs), float(pd_sub.max()), pd_sub)

    def vertex_depths(self, vertices) -> np.ndarray:
        """Penetration depth of every vertex (V,) (0 for vertices that do not penetrate), e.g. to colour a mesh."""
        return self._label(vertices)[2]

    def _label(self, vertices, clearance_limit: float = np.inf):
        v = self._check(vertices)
        if not self.clearance:
            n_pairs, rec_key, rec_int, n_rec, floor = self._counted(v)
            clear = np.full(self.n_parts, np.inf)
            out, depth_v = finish_label(v, self.faces, rec_key, rec_int, n_rec, len(self.edges), floor, clear,
                                        self.partition, self.n_parts, self.cap, self.adj_ptr, self.adj_idx,
                                        self.adj_eid, self.closed)
            return n_pairs, np.maximum(out, -clearance_limit), depth_v
        if not self.prune:
            n_pairs, out, depth_v = self._label_reference(v)
            return n_pairs, (out if clearance_limit == np.inf else np.maximum(out, -clearance_limit)), depth_v
        n_pairs, rec_key, rec_int, n_rec, clear, floor = self._passes(v, clearance_limit)
        out, depth_v = finish_label(v, self.faces, rec_key, rec_int, n_rec, len(self.edges), floor, clear,
                                    self.partition, self.n_parts, self.cap, self.adj_ptr, self.adj_idx, self.adj_eid,
                                    self.closed)
        return n_pairs, out, depth_v

    def penetrations(self, vertices, max_region: float = 1.0, seed_vectors: bool = True) -> Penetrations:
        """The penetrating vertices of a mesh (V, 3) and how far each must move (module docstring: "Penetrating
        vertices", "Depth"): :class:`Penetrations`. What the untangle repair moves
        (:mod:`neuralcol.repair.untangle`). ``max_region``: a flood-filled region holding more than this share
        of the vertices is taken for the outside of an intersection curve that does not close, and keeps its seeds
        only (1.0: as the labeler's depth). ``seed_vectors`` False: vectors of the enclosed regions only (zeros at
        the seeds of local folds and of meshes with boundary). The crossing records come from the counted pairs
        alone, so no clearance term is computed: with the near table built, its pass with a clearance limit of 0
        (2.5x faster than a label on SCAPE); without it, the pairs whose boxes overlap (the same records bit for bit,
        about 10 % slower on SCAPE, and no table to build)."""
        v = self._check(vertices)
        if self._near is not None:  # the table at hand: its pass is a little faster (same records bit for bit)
            n_pairs, rec_key, rec_int, n_rec, _, _ = self._passes(v, 0.0)
        else:
            n_pairs, rec_key, rec_int, n_rec, _ = self._counted(v)
        seeds, blocked = crossing_seeds(rec_key, rec_int, n_rec, len(self.edges))
        depth, vec = penetration(v, self.faces, seeds, self.adj_ptr, self.adj_idx, self.adj_eid, blocked,
                                 self.closed, 2 if seed_vectors else 1, int(max_region * len(v)))
        return Penetrations(int(n_pairs), depth, vec, self._record_pairs(v, rec_int[:n_rec]))

    def _record_pairs(self, v: np.ndarray, rec_int: np.ndarray) -> np.ndarray:
        """:attr:`Penetrations.crossing_pairs` of the crossing records (R, 5)."""
        both = self._edge_faces[rec_int[:, 0]]  # (R, 2) the triangles of each crossing edge (-1: boundary)
        t = np.repeat(rec_int[:, 3], 2)
        s = both.ravel()
        shared = (self.faces[np.maximum(s, 0)][:, :, None] == self.faces[t][:, None, :]).sum((1, 2))
        keep = (s >= 0) & (shared < 2)  # as the broadphase: pairs sharing an edge are not candidates
        pairs = np.sort(np.stack([s[keep], t[keep]], 1), axis=1)
        if not len(pairs):
            return np.zeros((0, 2), np.int64)
        pairs = np.unique(pairs, axis=0)
        return pairs[counted_mask(v, self.faces, pairs, self.ell, self.tau)]  # counted, as intersecting_pairs

    def _counted(self, v):
        """The counted pairs and their crossing records, from the pairs whose boxes overlap (no clearance term):
        n_pairs, rec_key, rec_int, n_rec and the per-part pair-depth floors."""
        floor = np.zeros(self.n_parts)
        pairs = self._counted_pairs(v) if len(self.faces) >= INCREMENTAL_FACES else self.candidate_pairs(v)
        n_pairs, rec_key, rec_int, n_rec = counted_pass(v, self.faces, pairs, self.ell, self.tau,
                                                        self.partition, floor, self.adj_ptr, self.adj_idx,
                                                        self.adj_eid, self.orient)
        return n_pairs, rec_key, rec_int, n_rec, floor

    def _passes(self, v, clearance_limit: float):
        """The pruned near and far passes: counted pairs, crossing records, per-part clearances and pair-depth
        floors."""
        f = self.faces
        lo0, hi0 = triangle_aabbs(v, f, 0.0)
        lo_cap, hi_cap = triangle_aabbs(v, f, 0.5 * self.cap)
        clear = np.full(self.n_parts, clearance_limit)  # a term >= the limit cannot change a limited label
        floor = np.zeros(self.n_parts)
        gerr = gap_roundoff(v)
        rec_key = np.empty(64)
        rec_int = np.empty((64, 5), dtype=np.int64)
        # 1. near pairs, from the rest mesh's table (no broadphase): counted pairs among those with overlapping
        #    boxes, and the clearance terms a per-triangle SAT bound cannot rule out
        axes = triangle_axes(v, f, self.ell)
        units, normals = self._corner_scratch()
        cones = corner_cones(v, f, units, normals)
        n_near, rec_key, rec_int, n_rec = near_pass(
            v, f, self._near_ptr, self._near_b, self._near_rest, self._near_shared, lo0, hi0, lo_cap, hi_cap, *axes,
            *cones, units, normals, self.ell, self.tau, gerr, self.cap, clear, floor, self.partition, self.adj_ptr,
            self.adj_idx, self.adj_eid, self.orient, rec_key, rec_int, 0, *self._near_scratch())
        # 2. far pairs, one grid: counted pairs among those with overlapping boxes, and the clearance terms of
        #    the pairs closer than the clearance they would have to beat
        n_far, rec_key, rec_int, n_rec = self._far_pass(v, lo0, hi0, lo_cap, hi_cap, axes, gerr, clear, floor,
                                                        rec_key, rec_int, n_rec)
        return n_near + n_far, rec_key, rec_int, n_rec, clear, floor

    def _label_reference(self, v):
        """Every non-adjacent pair whose boxes are within cap (``prune=False``)."""
        lo, hi = triangle_aabbs(v, self.faces, 0.5 * self.cap)
        pairs = drop_adjacent(self.faces, grid_pairs(lo, hi, max(self.cell, self.cap)))
        return label_mesh(v, self.faces, pairs, self.ell, self.tau, gap_roundoff(v), self.cap, self.partition,
                          self.n_parts, self.adj_ptr, self.adj_idx, self.adj_eid, len(self.edges), self.closed,
                          self.orient, self._near_ptr, self._near_b, self._near_rest)

    def _near_scratch(self):
        """Work space of :func:`~neuralcol.collision.kernels.pruned_pass.near_pass`, made once per labeler (not
        pickled)."""
        scratch = getattr(self, "_scratch", None)
        if scratch is None:
            n = len(self._near_b)
            scratch = self._scratch = (np.empty((2, n), dtype=np.int64), np.empty(n))
        return scratch

    def _corner_scratch(self):
        """Corner frames of :func:`~neuralcol.collision.kernels.distance.corner_cones` ((F, 3, 2, 3) unit edge
        directions, (F, 3, 3) arc normals), filled per mesh into arrays made once per labeler (not pickled)."""
        scratch = getattr(self, "_corners", None)
        if scratch is None:
            n = len(self.faces)
            scratch = self._corners = (np.empty((n, 3, 2, 3)), np.empty((n, 3, 3)))
        return scratch

    def __getstate__(self):
        state = dict(self.__dict__)
        state.pop("_scratch", None)
        state.pop("_corners", None)
        state.pop("_last_pairs", None)
        return state

    def _far_pass(self, v, lo0, hi0, lo_cap, hi_cap, axes, gerr, clear, floor, rec_key, rec_int, n_rec):
        """Far pairs: those whose boxes grown by ``(r + margin) / 2`` overlap, with ``r`` the largest current
        ``min(clear_i, cap)``, found over the rest mesh's clusters
        (:func:`~neuralcol.collision.kernels.pruned_pass.far_pass_clusters`) or, with ``far_clusters=0``, with one
        grid over every triangle (:func:`~neuralcol.collision.kernels.pruned_pass.far_pass`; the same far pairs,
        the same labels bit for bit). They hold every far pair with overlapping boxes (they may be counted) and
        every far pair whose per-axis box gaps are all <= r + margin, so a far pair they miss has distance > r and
        cannot lower any clearance (``margin`` = 1e-9 cap covers the round-off of the grown boxes and of the
        distance, ~1e-16 of the coordinates). Triangles of parts whose clearance is already 0 start no clearance
        pairs, and pairs whose rest centroids are closer than cap are near pairs (their rest distance is below
        cap), not far ones."""
        thr = np.minimum(clear, self.cap)
        r = max(float(thr.max()), 0.0)
        margin = 1e-9 * self.cap
        near2 = (self.cap - margin) ** 2
        active = (thr > 0.0)[self._tri_part].any(1)
        lo, hi = triangle_aabbs(v, self.faces, 0.5 * (r + margin))
        if self.far_clusters:
            return far_pass_clusters(v, self.faces, lo, hi, *self._clusters, lo0, hi0, lo_cap, hi_cap, active,
                                     self._rest_centroids, near2, self._near_ptr, self._near_b, self._near_rest, *axes,
                                     self.ell, self.tau, gerr, self.cap, clear, floor, self.partition, self.adj_ptr,
                                     self.adj_idx, self.adj_eid, self.orient, rec_key, rec_int, n_rec)
        return far_pass(v, self.faces, lo, hi, max(self.cell, r + margin), lo0, hi0, lo_cap, hi_cap, active,
                        self._rest_centroids, near2, self._near_ptr, self._near_b, self._near_rest, *axes, self.ell,
                        self.tau, gerr, self.cap, clear, floor, self.partition, self.adj_ptr, self.adj_idx,
                        self.adj_eid, self.orient, rec_key, rec_int, n_rec)
