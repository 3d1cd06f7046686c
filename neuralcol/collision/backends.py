"""Choosing the exact labeler's backend: ``labeling.backend = cpu | gpu | fcl | auto``.

* ``cpu``: :class:`~neuralcol.collision.labeler.ExactLabeler` (numba kernels, one mesh at a time; the
  reference).
* ``gpu``: :class:`~neuralcol.collision.gpu_labeler.BatchedLabeler` (NVIDIA Warp kernels over a batch of poses
  of one topology; same verdicts as ``cpu``, PD / PD_i within 1e-6 of the bounding-box diagonal). It runs on a
  CUDA device, or on the CPU through Warp's CPU backend (that is how CI tests it).
* ``fcl``: :class:`~neuralcol.collision.fcl_labeler.FCLLabeler`, the paper's labeler (python-fcl BVH
  self-collision and contact depth). Its PD differs from ours (docs/labels.md), so its labels are cached apart.
* ``auto``: ``gpu`` when a CUDA device and Warp are available, ``cpu`` otherwise.

Every backend takes the settings of ``labeling.labeler`` (touch_tol, clearance_cap, boundary_eps, ...) and
exposes ``label(vertices) -> Label``, ``n_vertices``, ``n_parts``, ``eps``, ``cap``, ``tau``, ``diag`` and
``subsets``, so :class:`~neuralcol.collision.pool.LabelPool` and the oracle use any of them.
"""

from __future__ import annotations

from typing import Any

BACKENDS = ("cpu", "gpu", "fcl", "auto")


def cuda_available() -> bool:
    """True when torch sees a CUDA device."""
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a dependency
        return False
    return bool(torch.cuda.is_available())


def resolve_backend(backend: str | None) -> str:
    """``auto`` -> ``gpu`` with a CUDA device and Warp, else ``cpu``; other names are checked and returned."""
    name = "cpu" if backend is None else str(backend)
    if name not in BACKENDS:
        raise ValueError(f"labeling.backend={name!r}: use one of {', '.join(BACKENDS)}")
    if name == "auto":
        if not cuda_available():
            return "cpu"
        try:
            import warp  # noqa: F401
        except ImportError:
            return "cpu"
        return "gpu"
    return name


def labeler_settings(labeling_cfg: Any) -> dict:
    """The labeler's keyword settings from ``labeling.labeler`` (without Hydra's ``_target_`` / ``_partial_``)."""
    from omegaconf import DictConfig, OmegaConf

    lab = labeling_cfg["labeler"] if "labeler" in labeling_cfg else labeling_cfg
    if isinstance(lab, DictConfig):
        lab = OmegaConf.to_container(lab, resolve=True)
    return {k: v for k, v in dict(lab).items() if not str(k).startswith("_")}


def build_labeler(labeling_cfg: Any, faces, rest_vertices, partition=None):
    """The labeler of ``labeling.backend`` for meshes of one topology.

    Args:
        labeling_cfg: the ``labeling`` config group (``backend``, ``labeler``, optional ``device``).
        faces: (F, 3) int triangles.
        rest_vertices: (V, 3) float rest mesh.
        partition: (V,) int part of each vertex (PD_i), or None for one part.

    Returns:
        A labeler (see the module docstring).
    """
    backend = resolve_backend(labeling_cfg.get("backend", "cpu"))
    kwargs = labeler_settings(labeling_cfg)
    if backend == "cpu":
        from neuralcol.collision.labeler import ExactLabeler

        return ExactLabeler(faces, rest_vertices, partition=partition, **kwargs)
    if backend == "gpu":
        from neuralcol.collision.gpu_labeler import BatchedLabeler

        device = labeling_cfg.get("device", None)
        return BatchedLabeler(faces, rest_vertices, partition=partition, device=device, **kwargs)
    from neuralcol.collision.fcl_labeler import FCLLabeler

    return FCLLabeler(faces, rest_vertices, partition=partition, **kwargs)
