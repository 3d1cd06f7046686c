"""The certified cascade of a :class:`~neuralcol.api.TrainedRun` (docs/cascade.md): the run's calibration set, the
band of doubt of a target FNR, and the exact labels of the rows inside it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from neuralcol.api.results import Detection
from neuralcol.errors import UserInputError
from neuralcol.rundir import RunDir


class CascadeMixin:
    """:class:`~neuralcol.api.TrainedRun`'s cascade methods (they use its label pool, config and detector)."""

    def _certified(self, det: Detection, band, vertices, z: torch.Tensor) -> Detection:
        """``det`` with the cascade of ``band`` applied: the band's rows labeled exactly (``vertices``: the user's
        meshes, judged themselves; None: the codes ``z`` decoded)."""
        from neuralcol.metrics.cascade import apply_band

        failed = np.zeros(len(z), dtype=bool)

        def exact_fn(rows: np.ndarray) -> np.ndarray:
            if vertices is not None:
                meshes = self._vertices(vertices)[torch.as_tensor(rows)].numpy()
            else:
                meshes = self.decode(z[torch.as_tensor(rows, device=z.device)]).double().cpu().numpy()
            pool = self.label_pool()
            if pool.workers <= 1:  # in this process: the verdict alone (early exit), all an exact call needs
                out = np.ones(len(rows), dtype=bool)
                for k, mesh in enumerate(meshes):
                    try:
                        out[k] = bool(self._exact.verdict(mesh))
                    except Exception:  # a mesh the labeler fails on is never certified free
                        failed[rows[k]] = True
                return out
            report = pool.label_report(meshes)
            failed[rows] = ~report.ok
            return np.where(report.ok, report.labels.collides, True)  # a failed label never certifies "free"

        verdict, used = apply_band(det.logit.double().cpu().numpy(), band, exact_fn)
        used &= ~failed
        dev = det.logit.device
        collides = torch.as_tensor(verdict, device=dev)
        exact = torch.as_tensor(used, device=dev)
        prob = torch.where(exact, collides.to(det.prob.dtype), det.prob)
        return det._replace(prob=prob, collides=collides, exact=exact)


    def calibration(self) -> tuple[np.ndarray, np.ndarray]:
        """The run's calibration set for the cascade (``cascade.npz``): the final detector's logits (N,) float64
        on its codes and their exact labels (N,) bool.

        Raises:
            UserInputError: the run has none (it predates the cascade, or ran with detector.cascade.enabled=false).
        """
        if self._calibration is None:
            from neuralcol.stages.cascade import load_calibration

            path = RunDir(self.run_dir).cascade
            if not path.is_file():
                raise UserInputError(
                    f"{path}: missing; this run has no calibration set for the certified cascade (it predates "
                    "the cascade or ran with detector.cascade.enabled=false). Fix: run.calibrate() labels one and "
                    "writes it into the run directory (once), or run the run's command again with "
                    "detector.cascade.enabled=true")
            self._calibration = load_calibration(path)
        return self._calibration

    def band(self, target_fnr: float, min_accuracy="run"):
        """The cascade's band of doubt for ``target_fnr`` (:func:`~neuralcol.metrics.cascade.choose_band` on the
        run's calibration set; any target in [0, 1), not only the run's ``detector.cascade.targets``).

        ``min_accuracy``: ``"run"`` (the run's ``detector.cascade.min_accuracy``, ``"pointwise"`` if unset),
        ``"detector"``, ``"pointwise"``, a float accuracy floor, or None (docs/cascade.md)."""
        from neuralcol.metrics.cascade import POINTWISE, choose_band

        if min_accuracy == "run":
            min_accuracy = OmegaConf.select(self.cfg, "detector.cascade.min_accuracy", default=POINTWISE)
        logits, collides = self.calibration()
        try:
            return choose_band(logits, collides, float(target_fnr), min_accuracy,
                               OmegaConf.select(self.cfg, "detector.cascade.confidence", default=None))
        except (TypeError, ValueError) as e:
            raise UserInputError(f"certify={target_fnr!r}: {e}") from e

    def calibrate(self, size: int | None = None, seed: int | None = None) -> Path:
        """Label a calibration set for the cascade and write ``cascade.npz`` into the run directory (for runs made
        before it existed): ``size`` uniform codes from U(Z) of ``seed`` (None: the run's
        ``detector.cascade.calibration_size`` / ``calibration_seed``), labeled through the run's label pool and
        cached beside its test set like the pipeline's. Returns the file's path."""
        from neuralcol.handler.resolve import detector_logits
        from neuralcol.samples.cache import calibration_set
        from neuralcol.stages.cascade import save_calibration

        size = size if size is not None else OmegaConf.select(self.cfg, "detector.cascade.calibration_size")
        seed = seed if seed is not None else OmegaConf.select(self.cfg, "detector.cascade.calibration_seed")
        if size is None or seed is None:
            raise UserInputError("calibrate: this run's config has no detector.cascade; give size= and seed= (the "
                                 "pipeline's defaults: detector.cascade in conf/detector/cpu.yaml)")
        if int(seed) == int(self.cfg.detector.test_seed):
            raise UserInputError(f"calibrate: seed={seed} is the run's test_seed; the calibration set must differ")
        det_cfg = {"cascade": {"calibration_size": int(size), "calibration_seed": int(seed)}}
        ctx = self.context()
        rows, _, _ = calibration_set(ctx.oracle(self.label_pool()), det_cfg, self.metrics["autoencoder"]["cache_key"],
                                     self.cfg.paths.cache_dir)
        path = RunDir(self.run_dir).cascade
        save_calibration(path, detector_logits(self.on_codes, rows.z), rows.collides, int(seed))
        self._calibration = None
        return path
