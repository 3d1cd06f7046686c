"""Compiled (numba) geometric kernels of the exact labeler, one module per concern (import each name from the
module that defines it):

* :mod:`~neuralcol.collision.kernels.vec`: 3-vector helpers and the margins of computed lower bounds;
* :mod:`~neuralcol.collision.kernels.broadphase`: triangle boxes and the uniform grid that pairs them;
* :mod:`~neuralcol.collision.kernels.depth`: SAT penetration depth, separation tests, edge/triangle crossings;
* :mod:`~neuralcol.collision.kernels.distance`: triangle distances, box gaps, corner (wedge) gaps;
* :mod:`~neuralcol.collision.kernels.pair_terms`: the rest near table and the terms of one triangle pair;
* :mod:`~neuralcol.collision.kernels.label_pass`: the verdict, the reference pass over every pair and PD_i;
* :mod:`~neuralcol.collision.kernels.pruned_pass`: the pruned near and far passes (the default path);
* :mod:`~neuralcol.collision.kernels.clusters`: the rest mesh's triangle clusters that find the far pass's pairs.

Every function is pure: arrays in, arrays or scalars out. Triangles are given as vertex arrays
``verts (V, 3) float64`` plus ``faces (F, 3) int64``. See :mod:`neuralcol.collision.labeler` for how they
combine into the verdict and the penetration depth.

numba's on-disk cache (``cache=True``) does not notice edits to another module a kernel calls or inlines: after
changing one of these modules, delete ``neuralcol/collision/kernels/__pycache__`` (or set ``NUMBA_CACHE_DIR``
to a fresh folder) so every kernel is compiled again.
"""
