"""What kind of self-intersection a mesh has, so that resolve's failures are reported by kind.

* ``deep``: a part inside another part's volume: the exact labeler's flood fill finds an enclosed penetrating
  region with a vertex deeper than ``deep_edges`` mean edge lengths
  (:meth:`~neuralcol.collision.labeler.ExactLabeler.penetrations`; an arm in the torso, a thigh in a calf);
* ``local fold``: otherwise, and most intersecting triangle pairs lie within ``local_rings`` edges of each other
  on the mesh (a vertex of one reaches a vertex of the other in that many edge hops: skin folding over itself at
  a bent joint, a crease of cloth);
* ``distant contact``: otherwise: shallow intersections between parts apart on the surface (two fingers, an
  arm grazing the torso, cloth through cloth, two separate components).
"""

from __future__ import annotations

import numpy as np

from neuralcol.geometry.topology import edge_adjacency

KINDS = ("deep", "local fold", "distant contact")


def collision_kind(labeler, vertices, deep_edges: float = 1.0, local_rings: int = 6) -> str | None:
    """The kind (:data:`KINDS`) of a mesh's (V, 3) self-intersection, or None if the labeler counts no pair.
    ``labeler``: an :class:`~neuralcol.collision.labeler.ExactLabeler`."""
    from scipy.sparse.csgraph import dijkstra

    v = np.asarray(vertices, np.float64)
    pairs = labeler.intersecting_pairs(v)
    if len(pairs) == 0:
        return None
    pen = labeler.penetrations(v, 0.3, seed_vectors=False)
    if np.linalg.norm(pen.vector, axis=1).max(initial=0.0) > deep_edges * labeler.ell:
        return "deep"
    f = labeler.faces
    sources, where = np.unique(f[pairs[:, 0]], return_inverse=True)
    hops = dijkstra(edge_adjacency(f, labeler.n_vertices), unweighted=True, indices=sources, limit=local_rings + 0.5)
    # hop distance of each pair: the least over its first triangle's 3 vertices and its second's 3
    d = hops[where.reshape(-1, 3)[:, :, None], f[pairs[:, 1]][:, None, :]].min((1, 2))
    return "local fold" if np.mean(d <= local_rings) >= 0.5 else "distant contact"


def kinds_of(labeler, meshes) -> list[str | None]:
    """:func:`collision_kind` of each mesh (n, V, 3)."""
    return [collision_kind(labeler, m) for m in meshes]


def outcome_by_kind(kinds: list[str | None], freed: np.ndarray) -> dict[str, dict[str, float]]:
    """For colliding inputs' kinds (:func:`kinds_of`) and whether each was freed (n,) bool: per kind, how many
    inputs (``n``), how many freed (``freed``) and the rate (``rate``; NaN for none); inputs of no kind (the
    labeler finds them free) are left out."""
    freed = np.asarray(freed, bool)
    out = {}
    for k in KINDS:
        rows = np.array([c == k for c in kinds], bool)
        n = int(rows.sum())
        out[k] = {"n": n, "freed": int(freed[rows].sum()), "rate": float(freed[rows].mean()) if n else float("nan")}
    return out
