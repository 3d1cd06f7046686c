"""The exact repairs: self-intersections removed from any triangle mesh, checked by the exact labeler, no training.

One home for every repair that moves a mesh's vertices until the exact labeler calls it free, for any topology
(numpy in, numpy out). ``neuralcol.resolve`` without a run, ``neuralcol resolve`` and a trained run's
``resolve`` (after its learned handler) all call these.

* :mod:`~neuralcol.repair.contact`: the contact push (the two triangles of each intersecting pair pushed apart,
  the push diffused over the surface).
* :mod:`~neuralcol.repair.untangle`: the region push (each vertex inside another part's volume moved back out, as
  one smooth field) and intersection contour minimisation (the intersection curves shrunk until they vanish).
* :mod:`~neuralcol.repair.meshes`: :func:`repair_meshes` (the push, the untangle where it fails, a wider untangle
  where both fail) and :func:`repair` (the whole path for a batch: the verdicts, the repairs, the cap; its result
  type :class:`Repaired`).
* :mod:`~neuralcol.repair.cap`: the smallest cap on a freed mesh's vertex moves that keeps it free, and the moves.
* :mod:`~neuralcol.repair.settings`: :class:`RepairSettings` (``handler.repair`` in ``conf/handler/default.yaml``).

    from neuralcol.collision.labeler import ExactLabeler
    from neuralcol.repair import repair
    out = repair(meshes, faces, ExactLabeler(faces, rest), rest=rest)   # Repaired: vertices, pd_after, freed, ...
"""

from neuralcol.repair.meshes import Repaired, repair, repair_meshes
from neuralcol.repair.settings import RepairSettings, repair_from_config, repair_settings

__all__ = ["Repaired", "RepairSettings", "repair", "repair_from_config", "repair_meshes", "repair_settings"]
