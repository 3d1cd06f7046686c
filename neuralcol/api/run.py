"""A finished run as one object: :func:`load_run` and :class:`TrainedRun` (see :mod:`neuralcol.api`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig

from neuralcol.api.cascade import CascadeMixin
from neuralcol.api.files import (
    _check_targets,
    _pd_unit,
    _read_model_file,
    _run_settings,
    check_run_dir,
)
from neuralcol.api.package import check_package
from neuralcol.api.resolve import ResolveMixin
from neuralcol.api.results import Detection, check_removed_choice
from neuralcol.errors import UserInputError
from neuralcol.nn.detector import CollisionDetector, smooth_max
from neuralcol.nn.latent_space import LatentSpace
from neuralcol.nn.part_geometry import DetectorOnCodes
from neuralcol.rundir import CacheDir, RunDir


def load_run(run_dir: str | Path, device: str | torch.device = "cpu", workers: int | None = 0,
             progress: bool = False, trust_config: bool = False) -> TrainedRun:
    """Load a finished run: its config, latent space and final detector.

    Args:
        run_dir: output directory of a finished ``python -m experiments.run``, or a packed run (``pretrained/<name>``,
            ``python -m experiments.pack``: its latent space inside, its files checked against ``package.json``).
        device: where the detector and the latent space's network run (the ACAP solve is on the CPU).
        workers: label worker processes for :meth:`TrainedRun.label` (0, the default: in this process, which
            works from notebooks, stdin and scripts alike; N > 0 or None (the run's ``labeling.pool.workers``):
            worker processes, started by spawning, so a script must call this under
            ``if __name__ == "__main__":``).
        progress: progress bars while labeling.
        trust_config: accept a config whose ``_target_`` entries name callables outside neuralcol, torch.optim
            and lightning (refused by default: Hydra would call them; a shared run could name any function).

    Raises:
        UserInputError: not a run directory, an unfinished run, an untrusted ``_target_``, or its latent space is
            not in the cache.
    """
    from neuralcol.nn.detector import load_detector

    run_dir = Path(run_dir)
    cfg, metrics = check_run_dir(run_dir)
    rd = RunDir(run_dir)
    _check_targets(cfg, rd.config, trust_config)
    cache_dir, temperature = _run_settings(cfg, rd.config)
    key = metrics["autoencoder"].get("cache_key")
    if rd.package.is_file():  # a packed run (pretrained/<name>): its own latent space, every file checked
        check_package(run_dir)
    space_path = rd.latent_space if rd.latent_space.is_file() else CacheDir(cache_dir).latent_space(str(key))
    if key is None or not space_path.is_file():
        raise UserInputError(f"{space_path}: the run's latent space is not in the cache (paths.cache_dir="
                             f"{cache_dir}); run the same command again to rebuild it")
    retrain = "restore it from a copy of the run, or run the run's command again in a new directory"
    net, blob = _read_model_file(rd.detector, load_detector, retrain)
    pd_unit = _pd_unit(blob, metrics, rd.detector, rd.metrics)
    # (a mesh_detector.pt of an older run, the separate mesh detector, is not read)
    space = _read_model_file(space_path, LatentSpace.load, f"delete {space_path.parent} and run the same command "
                             "again to rebuild it")
    if net.latent_dim != space.dim:
        raise UserInputError(f"{rd.detector}: reads latent codes of size {net.latent_dim}, the run's latent space "
                             f"{space_path} has {space.dim}; the files belong to different runs: {retrain}")
    return TrainedRun(run_dir, cfg, metrics, space, net, pd_unit, temperature,
                      device=device, workers=workers, progress=progress)


def pretrained_root() -> Path:
    """The shipped models' folder: ``pretrained/`` of a clone, or the copy an installed wheel carries
    (:mod:`neuralcol.resources`)."""
    from neuralcol.resources import pretrained_dir

    return pretrained_dir()


def pretrained(name: str = "scape", **load_kw):
    """Load a package shipped in the repository's ``pretrained/`` folder, e.g. ``pretrained("scape")``
    (keywords go to :func:`~neuralcol.load_run`).

    Raises:
        UserInputError: no such package (the message lists the shipped ones).
    """
    root = pretrained_root()
    path = root / name
    if not RunDir(path).package.is_file():
        have = sorted(p.name for p in root.glob("*") if RunDir(p).package.is_file()) if root.is_dir() else []
        raise UserInputError(f"{path}: no shipped model named {name!r} "
                             + (f"(shipped: {', '.join(have)})" if have else
                                "(no pretrained/ folder here: this install carries none; reinstall neuralcol, or "
                                "give load_run a packed folder)"))
    return load_run(path, **load_kw)


class TrainedRun(CascadeMixin, ResolveMixin):
    """A finished run: latent space, detector, exact labeler (a resource owner: its label pool opens on the
    first :meth:`label` and closes in :meth:`close`). Built by :func:`load_run`.

    Args:
        run_dir: the run directory. cfg: its config. metrics: its ``metrics.json``.
        space: the latent space. detector: the final detector.
        pd_unit: the length the detector's PD targets were divided by (the labeler's clearance cap).
        temperature: the smooth-max temperature of the detector's aggregated PD.
        device: device of the networks. workers: label worker processes (None: the run's setting).
        progress: progress bars while labeling.
    """

    def __init__(self, run_dir: Path, cfg: DictConfig, metrics: dict, space: LatentSpace,
                 detector: CollisionDetector, pd_unit: float, temperature: float, device="cpu",
                 workers: int | None = None, progress: bool = False):
        self.run_dir, self.cfg, self.metrics = Path(run_dir), cfg, metrics
        self.device = torch.device(device)
        self.space = space.to(self.device).eval()
        self.detector = detector.to(self.device).eval()
        self.pd_unit, self.temperature = float(pd_unit), float(temperature)
        # the label pool's settings that differ from the run's labeling.pool
        self._pool_cfg = {"progress": bool(progress), **({} if workers is None else {"workers": int(workers)})}
        self._pool = None
        self._fast: dict = {}  # compiled copies of the detector by dtype (detect(..., fast=...))
        self._exact = None
        self._calibration: tuple[np.ndarray, np.ndarray] | None = None  # cascade.npz (detect(..., certify=...))

    # ------------------------------------------------------------------ facts
    @property
    def on_codes(self) -> DetectorOnCodes:
        """The detector as a function of codes (one over code and mesh decodes the vertices its features read)."""
        return DetectorOnCodes(self.detector, self.space)

    @property
    def dim(self) -> int:
        """D, the latent code size."""
        return self.space.dim

    @property
    def faces(self) -> np.ndarray:
        """(F, 3) int64 triangles shared by every mesh of the run."""
        return self.space.faces.cpu().numpy()

    @property
    def n_vertices(self) -> int:
        return self.space.acap.n_vertices

    @property
    def diagonal(self) -> float:
        """Bounding-box diagonal of the rest mesh (the unit of the fractions the run reports)."""
        rest = self.space.rest_vertices.cpu().numpy()
        return float(np.linalg.norm(rest.max(0) - rest.min(0)))

    def __repr__(self) -> str:
        return (f"TrainedRun({self.run_dir}, dataset={self.cfg.dataset.name}, V={self.n_vertices}, D={self.dim}, "
                f"K={self.space.n_parts}, device={self.device})")

    # ------------------------------------------------------------------ inputs
    def _vertices(self, x, name: str = "vertices", check_finite: bool = True) -> torch.Tensor:
        """(B, V, 3) or (V, 3) meshes -> (B, V, 3) float64 CPU tensor (``check_finite=False``: the caller checks
        what it derives from them instead, saving a pass over the meshes)."""
        v = torch.as_tensor(np.asarray(x) if not torch.is_tensor(x) else x).detach()
        v = v[None] if v.ndim == 2 else v
        if v.ndim != 3 or v.shape[1:] != (self.n_vertices, 3):
            raise UserInputError(f"{name} have shape {tuple(v.shape)}; this run's meshes are ({self.n_vertices}, 3) "
                                 f"(give (B, {self.n_vertices}, 3) or one ({self.n_vertices}, 3) mesh)")
        if check_finite and not bool(torch.isfinite(v.sum())) and not bool(torch.isfinite(v).all()):
            raise UserInputError(f"{name}: non-finite coordinates")
        return v.to("cpu", torch.float64)

    def _is_vertices(self, x) -> bool:
        shape = tuple(x.shape)
        return len(shape) >= 2 and shape[-2:] == (self.n_vertices, 3)

    def _codes(self, x) -> torch.Tensor:
        """(B, D) or (D,) codes -> (B, D) float32 tensor on the run's device."""
        z = torch.as_tensor(np.asarray(x) if not torch.is_tensor(x) else x).detach()
        z = z[None] if z.ndim == 1 else z
        if z.ndim != 2 or z.shape[1] != self.dim:
            raise UserInputError(f"codes have shape {tuple(z.shape)}; this run's latent codes are ({self.dim},) "
                                 f"(give (B, {self.dim}) codes or (B, {self.n_vertices}, 3) meshes)")
        if not bool(torch.isfinite(z).all()):
            raise UserInputError("codes: non-finite values")
        return z.to(self.device, torch.float32)

    # ------------------------------------------------------------------ maps
    def encode(self, vertices) -> torch.Tensor:
        """Meshes (B, V, 3) or (V, 3), numpy or torch -> latent codes (B, D) float32 on the run's device."""
        return self.space.encode(self._vertices(vertices))

    def decode(self, codes) -> torch.Tensor:
        """Codes (B, D) or (D,) -> meshes (B, V, 3) float32 on the run's device (no gradient)."""
        with torch.no_grad():
            return self.space.decode(self._codes(codes))

    def detect(self, vertices_or_codes, batch_size: int = 4096, fast: str | None = None,
               certify: float | None = None, *, inputs: str | None = None) -> Detection:
        """The run's detector (``detector.pt``) on meshes (B, V, 3) or codes (B, D), in batches of ``batch_size``.

        A run whose detector reads code and mesh (``detector.inputs=code_and_mesh``, the default)
        judges a given mesh by its own contact-pair features beside its code, and a code by its decoded mesh's; the
        paper's detector (``detector.inputs=latent``) reads the code only, so on a mesh it judges the autoencoder's
        round trip, not the mesh. ``inputs`` is gone with the separate mesh detector (folded into the run's
        detector): ``inputs="mesh"`` or ``"auto"`` raises a UserInputError saying so (``"latent"``, the
        run's detector, is accepted from old callers).

        ``fast``: None (the eager float32 network, as in training and in the reported metrics), ``"float32"``
        (compiled with torch.compile: the same outputs to round-off, ~1.4x faster at batch 4096 on 2 CPU cores),
        ``"bfloat16"`` (compiled, bfloat16 weights: ~2.3x faster where bfloat16 is native; about 0.1 % of labels
        flip) or ``"bfloat16_checked"`` (bfloat16, with the rows whose logit lies near 0 recomputed in float32:
        ~1.9x, no label flipped on SCAPE's test sets). The first call with a ``fast`` form compiles it (seconds);
        :class:`~neuralcol.nn.fast_inference.FastDetector` and docs/studies/detector_inference_speed.md have the
        measurements. Meshes given to a detector over code and mesh run the compiled mesh path
        (``FastDetector.on_meshes``): on SCAPE meshes 59 µs per mesh against 104 eager, 110x the exact full label
        (``python -m research.mesh_speed``).

        ``certify``: None, or a target FNR in [0, 1): the certified cascade (docs/cascade.md). The band ``[lo, hi)``
        of that target (:meth:`band`, from the run's calibration set) decides which rows the exact labeler judges:
        logit below ``lo``: free, at or above ``hi``: colliding (the network), inside: the exact label of the
        **mesh** (a mesh given here is labeled itself, not its round trip; a code is decoded first), through the
        run's label pool (:meth:`label_pool`). The verdict is then ``collides``, not ``prob > 0.5``; ``exact`` marks
        the rows labeled, whose ``prob`` becomes 1.0 or 0.0. A row the exact labeler fails on is called colliding
        (never certified free) and not marked ``exact``."""
        check_removed_choice("inputs", inputs, ("mesh", "auto"))
        x = vertices_or_codes
        is_mesh = self._is_vertices(x)
        band = None if certify is None else self.band(certify)
        mesh = self._vertices(x, check_finite=False) if is_mesh else None
        try:
            z = self.space.encode(mesh) if is_mesh else self._codes(x)
        except (ValueError, RuntimeError, np.linalg.LinAlgError):
            if is_mesh:
                self._vertices(x)  # a non-finite coordinate: the one clear line
            raise
        if is_mesh and not bool(torch.isfinite(z).all()):  # a non-finite coordinate reaches every code it enters
            self._vertices(x)  # (raises, naming it)
        # a detector over code and mesh judges a mesh by its own geometry, not by its round trip's: the
        # vertices its pair features read, float32, in blocks small enough to stay in cache
        geometry = self.detector.geometry if is_mesh else None
        v = None if geometry is None else mesh[:, geometry.vertex_index.cpu()].to(self.device, torch.float32)
        net = self.on_codes if fast is None else self._fast_detector(fast)
        step = batch_size if v is None or fast is not None else max(1, min(batch_size, DetectorOnCodes.inference_block))
        parts = []
        with torch.no_grad():
            for start in range(0, len(z), step):
                zb = z[start:start + step]
                if v is None:
                    out = net(zb)
                elif fast is not None:
                    out = net.on_meshes(zb, v[start:start + len(zb)])
                else:
                    vb = v[start:start + len(zb)].permute(1, 2, 0).contiguous()
                    out = self.detector(zb, embedding=self.detector.embed_vertices_batch_last(vb))
                parts.append(Detection(out.prob, out.logit, smooth_max(out.s, self.temperature) * self.pd_unit,
                                       out.s * self.pd_unit))
        if not parts:
            empty = z.new_zeros(0)
            no = z.new_zeros(0, dtype=bool)
            return Detection(empty, empty, empty, z.new_zeros(0, self.space.n_parts), no, no,
                             None if band is None else no)
        det = Detection(*(torch.cat(t) for t in zip(*(p[:4] for p in parts))), self.space.outside_box(z))
        if band is None:
            return det._replace(collides=det.logit > 0)
        return self._certified(det, band, x if is_mesh else None, z)

    def _fast_detector(self, form: str):
        """The compiled copy of the detector for ``form`` (built on first use, then kept)."""
        from neuralcol.nn.fast_inference import FORMS, FastDetector

        if form not in FORMS:
            raise UserInputError(f"fast={form!r}; use None or one of {sorted(FORMS)}")
        if form not in self._fast:
            self._fast[form] = FastDetector.from_form(self.on_codes, form)
        return self._fast[form]

    # ------------------------------------------------------------------ exact labels
    def label_pool(self):
        """The run's label pool (its exact labeler on worker processes; opened on first use, closed by
        :meth:`close`)."""
        if self._pool is None:
            ctx = self.context()
            self._exact = ctx.sample_labeler()
            self._pool = ctx.pool(self._exact, **self._pool_cfg, desc="labeling").__enter__()
        return self._pool

    @property
    def labeler(self):
        """The run's exact labeler (``labeling``; the one :meth:`label_pool` runs)."""
        self.label_pool()
        return self._exact

    def context(self):
        """A :class:`~neuralcol.pipeline.RunContext` of this run's config, with this run's latent space (its data
        set and features are loaded on first use)."""
        from neuralcol.pipeline import RunContext

        ctx = RunContext(self.cfg, self.run_dir)
        ctx.use_latent_space(self.space, {**self.space.meta, "cache_key": self.metrics["autoencoder"]["cache_key"]})
        return ctx

    def label(self, vertices):
        """Exact labels of meshes (B, V, 3) or (V, 3) through the run's label pool.

        Returns:
            ``neuralcol.collision.pool.Labels``: collides (B,) bool, n_pairs (B,) int64, pd (B,) float64 (mesh
            units), pd_sub (B, K) float64.

        Raises:
            LabelingError: some meshes could not be labelled (it lists them).
        """
        return self.label_pool().label(self._vertices(vertices).numpy())

    def _pd(self, vertices: torch.Tensor) -> np.ndarray:
        """Exact PD (B,) of meshes; NaN where the labeler failed (never raises for a mesh)."""
        if len(vertices) == 0:
            return np.zeros(0)
        v = vertices.detach().to("cpu", torch.float64).numpy() if torch.is_tensor(vertices) else \
            np.asarray(vertices, np.float64)
        report = self.label_pool().label_report(v)
        return np.where(report.ok, report.labels.pd, np.nan)

    def close(self) -> None:
        """Stop the label workers (if any were started)."""
        if self._pool is not None:
            pool, self._pool = self._pool, None
            pool.__exit__(None, None, None)

    def __enter__(self) -> TrainedRun:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
