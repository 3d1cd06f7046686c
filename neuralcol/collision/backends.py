"""Building the exact labeler of the ``labeling`` config group: ``labeling=cpu | gpu | fcl | auto``.

Each backend is a file of ``conf/labeling/`` whose ``labeler._target_`` Hydra instantiates:

* ``cpu`` (default): :class:`~neuralcol.collision.labeler.ExactLabeler` (numba kernels, one mesh at a time; the
  reference).
* ``gpu``: :class:`~neuralcol.collision.warp_labeler.WarpLabeler` (NVIDIA Warp kernels over a batch of poses of
  one topology; same verdicts as ``cpu``, PD / PD_i within 1e-6 of the bounding-box diagonal). It runs on a CUDA
  device, or on the CPU through Warp's CPU backend (that is how CI tests it); ``labeler.device`` picks it.
* ``fcl``: :class:`~neuralcol.collision.fcl_labeler.FCLLabeler`, the paper's labeler (python-fcl BVH
  self-collision and contact depth). Its PD differs from ours (docs/labels.md), so its labels are cached apart.
* ``auto``: :func:`auto_labeler`, ``gpu`` when a CUDA device and Warp are available, ``cpu`` otherwise.

Every backend takes the settings of ``labeling.labeler`` (touch_tol, clearance_cap, boundary_eps, ...) and
exposes ``label(vertices) -> Label``, ``n_vertices``, ``n_parts``, ``eps``, ``cap``, ``tau``, ``diag`` and
``subsets``, so :class:`~neuralcol.collision.pool.LabelPool` and the oracle use any of them. Its class names its
backend (``backend = "cpu"``, ...), which ``labeling.backend`` (set by the group's file) must match.
"""

from __future__ import annotations

import inspect
from typing import Any

MESH_ARGS = ("faces", "rest_vertices", "partition")  # given by build_labeler, not by the config


def gpu_available() -> bool:
    """True when torch sees a CUDA device and Warp is installed."""
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a dependency
        return False
    if not torch.cuda.is_available():
        return False
    try:
        import warp  # noqa: F401
    except ImportError:
        return False
    return True


def auto_labeler(faces, rest_vertices, partition=None, device: str | None = None, **settings):
    """``labeling=auto``: a :class:`~neuralcol.collision.warp_labeler.WarpLabeler` on ``device`` when a CUDA device
    and Warp are available (:func:`gpu_available`), else an :class:`~neuralcol.collision.labeler.ExactLabeler`;
    ``settings`` are the labeler's (touch_tol, clearance_cap, ...)."""
    if gpu_available():
        from neuralcol.collision.warp_labeler import WarpLabeler

        return WarpLabeler(faces, rest_vertices, partition=partition, device=device, **settings)
    from neuralcol.collision.labeler import ExactLabeler

    return ExactLabeler(faces, rest_vertices, partition=partition, **settings)


def _locate(path: str):
    """The class or function at a dotted path; ImportError saying why not (no such name, or the module fails)."""
    import pydoc

    try:
        obj = pydoc.locate(path)
    except pydoc.ErrorDuringImport as exc:  # the module (or one it imports) raised
        value = getattr(exc, "value", exc)
        raise ImportError(f"{type(value).__name__}: {value}") from exc
    if obj is None:
        raise ImportError("no such module, class or function")
    return obj


def _labeler_cfg(labeling_cfg: Any):
    lab = labeling_cfg.get("labeler") if hasattr(labeling_cfg, "get") else None
    return lab if lab is not None else {}


def labeler_problems(labeling_cfg: Any) -> list[str]:
    """Problems of a ``labeling`` config's labeler, as ``key=value: rule`` strings (empty: fine): a
    ``labeler._target_`` that cannot be imported, a setting its labeler does not take, a ``backend`` name that is
    not the target's."""
    lab = _labeler_cfg(labeling_cfg)
    target = lab.get("_target_")
    if not target:
        return [f"labeling.labeler._target_={target!r}: must name the labeler's class; choose a backend with "
                "labeling=<name> (conf/labeling/<name>.yaml)"]
    try:
        made = _locate(str(target))
    except ImportError as exc:
        return [f"labeling.labeler._target_={target!r}: cannot be imported ({exc})"]
    problems = []
    try:
        params = inspect.signature(made).parameters
    except (TypeError, ValueError):
        params = None
    if params is not None and not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        known = [k for k in params if k not in MESH_ARGS]
        for key in lab:
            key = str(key)
            if not key.startswith("_") and key not in known:
                problems.append(f"labeling.labeler.{key}={lab[key]!r}: not a setting of {target} (its settings: "
                                f"{', '.join(known)})")
    backend = labeling_cfg.get("backend") if hasattr(labeling_cfg, "get") else None
    name = getattr(made, "backend", None)
    if backend is not None and isinstance(name, str) and backend != name:
        problems.append(f"labeling.backend={backend!r}: the labeler ({target}) is the {name} backend; choose a "
                        f"backend with labeling={backend} (labeling.backend only names it)")
    return problems


def build_labeler(labeling_cfg: Any, faces, rest_vertices, partition=None):
    """The labeler of the ``labeling`` config for meshes of one topology: Hydra instantiates ``labeler``.

    Args:
        labeling_cfg: the ``labeling`` config group (``backend``, ``labeler`` with its ``_target_``; a DictConfig
            or a dict).
        faces: (F, 3) int triangles.
        rest_vertices: (V, 3) float rest mesh.
        partition: (V,) int part of each vertex (PD_i), or None for one part.

    Returns:
        A labeler (see the module docstring).

    Raises:
        ValueError: the problems :func:`labeler_problems` finds (each naming its key), or a setting the labeler
            rejects.
    """
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate

    problems = labeler_problems(labeling_cfg)
    if problems:
        raise ValueError("; ".join(problems))
    lab = _labeler_cfg(labeling_cfg)
    try:
        make = instantiate(lab, _partial_=True)  # faces, rest mesh and partition come from the caller
    except InstantiationException as exc:
        raise ValueError(f"labeling.labeler: {exc}") from exc
    return make(faces, rest_vertices, partition=partition)
