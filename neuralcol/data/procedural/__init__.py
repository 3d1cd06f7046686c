"""Procedural mesh data sets that need no download: an articulated hand and a folded skirt.

Both generators (:func:`neuralcol.data.procedural.hand.make_proc_hand`,
:func:`neuralcol.data.procedural.cloth.make_proc_cloth`) return ``vertices (N, V, 3) float64`` and
``faces (F, 3) int64`` (one topology for all poses), are deterministic by ``seed``
(``np.random.default_rng(seed)``, no global RNG) and take their geometry and pose-range settings as keyword
arguments (listed in the docstring of their module); an unknown keyword raises
:class:`~neuralcol.errors.UserInputError` listing the valid ones. Units are arbitrary (palm width 0.89,
skirt height 1). 100 poses take well under a second each.

``anny_body`` (:func:`neuralcol.data.procedural.body.make_anny_body`) poses anny's realistic body
model (13 348 vertices, ``pip install anny``) in action sequences.

``GENERATORS`` maps the data-set name (``proc_hand``, ``proc_cloth``, ``anny_body``) to its generator
(used by :func:`neuralcol.data.datasets.load_procedural_dataset`).
"""

from __future__ import annotations

from neuralcol.data.procedural.body import make_anny_body
from neuralcol.data.procedural.cloth import make_proc_cloth
from neuralcol.data.procedural.hand import make_proc_hand

__all__ = ["GENERATORS"]

GENERATORS = {"proc_hand": make_proc_hand, "proc_cloth": make_proc_cloth,
              "anny_body": make_anny_body}  # anny_body needs the optional anny package
