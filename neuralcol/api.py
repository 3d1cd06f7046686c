"""A finished run as one object: ``run = neuralcol.load_run(RUN_DIR)``.

``RUN_DIR`` is the directory of a finished ``python -m experiments.run`` (it holds ``.hydra/config.yaml``,
``detector.pt`` and ``metrics.json``; the latent space comes from the run's autoencoder cache). The
:class:`TrainedRun` it returns maps meshes to latent codes and back, asks the detector, labels exactly and
resolves self-collisions::

    run = neuralcol.load_run("outputs/2024-01-01/12-00-00")
    det = run.detect(vertices)          # (B, V, 3) meshes or (B, D) codes -> Detection (prob, logit, pd, pd_sub)
    det = run.detect(vertices, certify=0.01)  # the certified cascade: exact labels where the detector is in doubt
    out = run.resolve(vertices)         # Resolved: vertices, codes, exact PD before and after
    run.close()                         # (or `with neuralcol.load_run(...) as run:`) stops the label workers

Symbols: B batch, V vertices, D = |Z_all| latent size, K sub-domains. PD is the exact penetration depth in
the units of the mesh (> 0: self-penetrating; docs/labels.md).
"""

from __future__ import annotations

import json
import math
import pickle
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
import yaml
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from neuralcol.errors import UserInputError
from neuralcol.nn.detector import CollisionDetector, smooth_max
from neuralcol.nn.latent_space import LatentSpace
from neuralcol.nn.part_geometry import DetectorOnCodes
from neuralcol.rundir import CacheDir, RunDir

OBJECTIVES = ("latent", "cartesian")
RUN_SECTIONS = ("dataset", "labeling", "detector", "handler", "paths")
# what reading a damaged or foreign model file raises past the loaders' own UserInputError: a broken zip archive,
# pickle or tensor record (RuntimeError, OSError, EOFError, UnpicklingError, UnicodeDecodeError, IndexError), or a
# blob without the expected keys, types or shapes (KeyError, TypeError, AttributeError, ValueError, RuntimeError
# of load_state_dict, IndexError)
DAMAGED_FILE_ERRORS = (RuntimeError, OSError, EOFError, pickle.UnpicklingError, ValueError, KeyError, IndexError,
                       TypeError, AttributeError)


class Detection(NamedTuple):
    """The detector's answer for B codes (tensors on the run's device, float32).

    prob (B,): collision probability. logit (B,): its logit (the handler's constraint is ``logit <= -margin``).
    pd (B,): the detector's PD estimate in mesh units, ``pd_unit * smooth_max(S, temperature)`` (the quantity
    its loss fits to the exact PD; trained on targets clipped to ``detector.loss.pd_clip`` units, so deep
    penetrations saturate). pd_sub (B, K): the per-sub-domain estimates ``pd_unit * S_i``. outside_box (B,) bool:
    the code (of a mesh: its encoding) lies outside the box Z the latent detector was trained in, so its answer is
    an extrapolation (``run.detect(mesh, inputs="mesh")`` reads the mesh instead); None where not computed.
    collides (B,) bool: the verdict: ``logit > 0``, or with ``certify`` the certified cascade's (the network below
    and above the band, the exact label inside it; docs/cascade.md). exact (B,) bool: with ``certify``, the rows
    the exact labeler decided (their ``prob`` is then 1.0 or 0.0, the exact answer); None without ``certify``.
    """

    prob: torch.Tensor
    logit: torch.Tensor
    pd: torch.Tensor
    pd_sub: torch.Tensor
    outside_box: torch.Tensor | None = None
    collides: torch.Tensor | None = None
    exact: torch.Tensor | None = None


class Resolved(NamedTuple):
    """Result of :meth:`TrainedRun.resolve` for N inputs.

    vertices (N, V, 3): the resolved meshes. For mesh inputs (float64, the precision they were labeled in), the
    input mesh plus the correction the handled code implies (in the input's frame, keeping its detail); for
    code inputs (float32), the decoded ``codes``.
    codes (N, D) float32: the handled latent codes. codes_before (N, D): the inputs' codes. pd_input (N,)
    float64: exact PD of the input meshes (NaN for code inputs). pd_before (N,): exact PD of the decoded input
    codes (the autoencoder's round trip). pd_after (N,): exact PD of the returned ``vertices`` (NaN: the
    handler or the labeler failed). margin (N,): the detector-logit margin of the kept result (NaN where the
    contact repair's mesh was kept). repaired (N,) bool: the contact repair (``handler.repair``, mesh inputs
    with ``verify``) produced the returned mesh.
    displacement_mean, displacement_max, displacement_median (N,): how far the returned vertices lie from the
    input's (code inputs: from the decoded input code), in mesh units; divide by ``diagonal`` (the rest mesh's
    bounding-box diagonal) for a fraction. decoded (N, V, 3) float32: the handled codes decoded (the latent
    result, in the decoder's frame).
    With ``certify`` (else None): exact (N,) bool: the verdict on the returned result is the exact labeler's
    (``pd_after`` is NaN where the detector was trusted instead); free (N,) bool: the certified cascade calls the
    returned result collision-free (exact PD <= 0, or the detector's logit below the band); exact_share: exact labels
    per verification decision (the full verification labels every result: 1.0).
    """

    vertices: torch.Tensor
    codes: torch.Tensor
    codes_before: torch.Tensor
    pd_input: np.ndarray
    pd_before: np.ndarray
    pd_after: np.ndarray
    margin: np.ndarray
    displacement_mean: np.ndarray
    displacement_max: np.ndarray
    displacement_median: np.ndarray
    diagonal: float
    decoded: torch.Tensor
    repaired: np.ndarray | None = None
    exact: np.ndarray | None = None
    free: np.ndarray | None = None
    exact_share: float | None = None


def _finish_hint(run_dir: Path) -> str:
    return (f"finish it by running its command again with hydra.run.dir={run_dir} (it resumes after its last "
            "finished round), or pass the directory of a finished run")


def _one_line(exc: BaseException, limit: int = 160) -> str:
    """``Type: message`` of an exception on one line, its message cut to ``limit`` characters."""
    msg = " ".join(str(exc).split())
    msg = msg if len(msg) <= limit else msg[:limit - 3] + "..."
    return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__


def _read_model_file(path: Path, read: Callable, fix: str):
    """``read(path)`` (a model file's loader) with its float tensors checked finite; a damaged file raises
    :class:`UserInputError` naming it and ``fix`` (the loader's own UserInputError passes as it is)."""
    try:
        model = read(path)
    except UserInputError:
        raise
    except DAMAGED_FILE_ERRORS as exc:
        raise UserInputError(f"{path}: damaged or not a file neuralcol wrote ({_one_line(exc)}); {fix}") from exc
    module = model[0] if isinstance(model, tuple) else model
    tensors = [*module.named_parameters(), *module.named_buffers()]
    bad = [name for name, t in tensors if t.is_floating_point() and not bool(torch.isfinite(t).all())]
    if bad:
        raise UserInputError(f"{path}: '{bad[0]}' holds NaN or inf ({len(bad)} such tensors), the file is damaged; "
                             f"{fix}")
    return model


def _read_json(path: Path) -> object:
    """The JSON value in ``path``; :class:`UserInputError` naming it when it is not UTF-8 JSON."""
    try:
        return json.loads(path.read_bytes().decode())
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
        raise UserInputError(f"{path}: not readable JSON ({_one_line(exc)}); the run's files are damaged: restore "
                             "them from a copy, or run its command again") from exc


def _read_config(path: Path) -> DictConfig:
    """The run configuration in ``path`` with its sections checked; :class:`UserInputError` naming it."""
    try:
        cfg = OmegaConf.load(path)
        missing = [k for k in RUN_SECTIONS if not isinstance(cfg, DictConfig) or not isinstance(cfg.get(k), DictConfig)]
    except (yaml.YAMLError, OmegaConfBaseException, ValueError) as exc:  # ValueError: UnicodeDecodeError
        raise UserInputError(f"{path}: not a readable YAML run configuration ({_one_line(exc)}); restore it from a "
                             "copy of the run") from exc
    if missing:
        raise UserInputError(f"{path}: has no {', '.join(missing)} section; not a neuralcol run configuration")
    return cfg


# modules whose callables a shared run's config may name (Hydra instantiates ``_target_`` entries when the run
# labels or resolves): neuralcol's own and the optimizers / trainer its configs use
TRUSTED_TARGETS = ("neuralcol.", "torch.optim.", "lightning.")


def untrusted_targets(cfg) -> list[str]:
    """``key=value`` of every ``_target_`` in ``cfg`` (nested; interpolations unresolved, so an interpolated
    target counts as untrusted) outside :data:`TRUSTED_TARGETS`."""
    found: list[str] = []

    def walk(node, where: str) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                if k == "_target_" and not (isinstance(v, str) and v.startswith(TRUSTED_TARGETS)):
                    found.append(f"{where}{k}={v!r}")
                walk(v, f"{where}{k}.")
        elif isinstance(node, list):
            for i, v in enumerate(node):
                walk(v, f"{where}{i}.")

    walk(OmegaConf.to_container(cfg, resolve=False) if isinstance(cfg, DictConfig) else cfg, "")
    return found


def _check_targets(cfg: DictConfig, path: Path, trust_config: bool) -> None:
    """Refuse a run config that names callables outside neuralcol / torch.optim / lightning (unless trusted)."""
    if trust_config:
        return
    bad = untrusted_targets(cfg)
    if bad:
        raise UserInputError(f"{path}: names callables outside {', '.join(TRUSTED_TARGETS)} ({'; '.join(bad[:3])}); "
                             "a shared run's config could name any function, which would run when the run labels "
                             "or resolves. If you trust this run, load it with load_run(..., trust_config=True)")


def _run_settings(cfg: DictConfig, cfg_path: Path) -> tuple[str, float]:
    """``paths.cache_dir`` and the detector's smooth-max temperature (> 0) of a run's config."""
    try:
        cache_dir = str(cfg.paths.cache_dir)
        temperature = float(OmegaConf.select(cfg, "detector.loss.temperature", default=0.1))
    except (OmegaConfBaseException, ValueError, TypeError) as exc:
        raise UserInputError(f"{cfg_path}: paths.cache_dir or detector.loss.temperature cannot be read "
                             f"({_one_line(exc)}); restore the run's config") from exc
    if not (math.isfinite(temperature) and temperature > 0):
        raise UserInputError(f"{cfg_path}: detector.loss.temperature={temperature}; it must be a number > 0")
    return cache_dir, temperature


def _pd_unit(blob: dict, metrics: dict, det_path: Path, metrics_path: Path) -> float:
    """The detector's PD unit (> 0): from ``detector.pt``, else from ``metrics.json``."""
    value = blob.get("pd_unit") or metrics["detector"].get("pd_unit")
    try:
        pd_unit = float(value)
    except (TypeError, ValueError):
        pd_unit = math.nan
    if not (math.isfinite(pd_unit) and pd_unit > 0):
        raise UserInputError(f"{det_path}: pd_unit={value!r} (also read from {metrics_path.name}); it must be a "
                             "number > 0, the files are damaged: restore them from a copy of the run")
    return pd_unit


def check_run_dir(run_dir: Path) -> tuple[DictConfig, dict]:
    """The config and metrics of a finished run directory; :class:`UserInputError` naming what is missing."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise UserInputError(f"{run_dir}: no such directory; give the output directory of a finished "
                             "`python -m experiments.run`")
    rd = RunDir(run_dir)
    cfg_path = rd.config
    if not cfg_path.is_file():
        raise UserInputError(f"{cfg_path}: missing; {run_dir} is not the output directory of "
                             "`python -m experiments.run` (such a directory holds .hydra/, detector.pt and "
                             "metrics.json)")
    det_path, metrics_path = rd.detector, rd.metrics
    if not metrics_path.is_file() and rd.resumed_in.is_file():
        raise UserInputError(f"{run_dir}: this run was resumed in {rd.resumed_in.read_text().strip()}"
                             "; load that directory")
    for p, when in ((det_path, "when the detector's training ends"), (metrics_path, "when the run ends")):
        if not p.is_file():
            raise UserInputError(f"{p}: missing (written {when}); {run_dir} is not a finished run, whose directory "
                                 f"holds .hydra/, detector.pt and metrics.json: {_finish_hint(run_dir)}")
    cfg = _read_config(cfg_path)
    metrics = _read_json(metrics_path)
    if not isinstance(metrics, dict) or not isinstance(metrics.get("autoencoder"), dict) \
            or not isinstance(metrics.get("detector"), dict):
        raise UserInputError(f"{metrics_path}: has no autoencoder/detector results; not the metrics of a "
                             "finished neuralcol run")
    return cfg, metrics


def load_run(run_dir: str | Path, device: str | torch.device = "cpu", workers: int | None = 0,
             progress: bool = False, trust_config: bool = False) -> TrainedRun:
    """Load a finished run: its config, latent space and final detector.

    Args:
        run_dir: output directory of a finished ``python -m experiments.run``.
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
    space_path = CacheDir(cache_dir).latent_space(str(key))
    if key is None or not space_path.is_file():
        raise UserInputError(f"{space_path}: the run's latent space is not in the cache (paths.cache_dir="
                             f"{cache_dir}); run the same command again to rebuild it")
    retrain = "restore it from a copy of the run, or run the run's command again in a new directory"
    net, blob = _read_model_file(rd.detector, load_detector, retrain)
    pd_unit = _pd_unit(blob, metrics, rd.detector, rd.metrics)
    mesh_net = None
    if rd.mesh_detector.is_file():  # the detector that reads the mesh (issue 27)
        from neuralcol.nn.mesh_detector import load_mesh_detector

        mesh_net = _read_model_file(rd.mesh_detector, load_mesh_detector, retrain)
    space = _read_model_file(space_path, LatentSpace.load, f"delete {space_path.parent} and run the same command "
                             "again to rebuild it")
    if net.latent_dim != space.dim:
        raise UserInputError(f"{rd.detector}: reads latent codes of size {net.latent_dim}, the run's latent space "
                             f"{space_path} has {space.dim}; the files belong to different runs: {retrain}")
    return TrainedRun(run_dir, cfg, metrics, space, net, pd_unit, temperature,
                      device=device, workers=workers, progress=progress, mesh_detector=mesh_net)


class TrainedRun:
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
                 workers: int | None = None, progress: bool = False, mesh_detector=None):
        self.run_dir, self.cfg, self.metrics = Path(run_dir), cfg, metrics
        self.device = torch.device(device)
        self.space = space.to(self.device).eval()
        self.detector = detector.to(self.device).eval()
        # the detector as a function of codes (one over code and mesh decodes the vertices its features read)
        self.on_codes = DetectorOnCodes(self.detector, self.space)
        self.mesh_detector = None if mesh_detector is None else mesh_detector.to(self.device).eval()
        self.pd_unit, self.temperature = float(pd_unit), float(temperature)
        # the label pool's settings that differ from the run's labeling.pool
        self._pool_cfg = {"progress": bool(progress), **({} if workers is None else {"workers": int(workers)})}
        self._pool = None
        self._fast: dict = {}  # compiled copies of the detector by dtype (detect(..., fast=...))
        self._exact = None
        self._calibration: tuple[np.ndarray, np.ndarray] | None = None  # cascade.npz (detect(..., certify=...))

    # ------------------------------------------------------------------ facts
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
    def _vertices(self, x, name: str = "vertices") -> torch.Tensor:
        """(B, V, 3) or (V, 3) meshes -> (B, V, 3) float64 CPU tensor."""
        v = torch.as_tensor(np.asarray(x) if not torch.is_tensor(x) else x).detach()
        v = v[None] if v.ndim == 2 else v
        if v.ndim != 3 or v.shape[1:] != (self.n_vertices, 3):
            raise UserInputError(f"{name} have shape {tuple(v.shape)}; this run's meshes are ({self.n_vertices}, 3) "
                                 f"(give (B, {self.n_vertices}, 3) or one ({self.n_vertices}, 3) mesh)")
        if not bool(torch.isfinite(v).all()):
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
               inputs: str = "latent", certify: float | None = None) -> Detection:
        """The detector on meshes (B, V, 3) or codes (B, D), in batches of ``batch_size``.

        ``inputs``: which detector judges. ``"latent"`` (default): the paper's detector on the code (a mesh is
        encoded first: it then judges the autoencoder's round trip, not the mesh). ``"mesh"``: the detector that
        reads the mesh (``mesh_detector.pt``, issue 27; codes are decoded first): on meshes nobody trained on it
        is far more accurate (proc_hand 0.891 against 0.634, SCAPE 0.815 against 0.637), but on SCAPE's U(Z) it
        is 1.7 points below the latent detector, so by the rule registered before the deciding runs it is not the
        default (docs/real_meshes.md). ``"auto"``: the mesh detector for meshes when the run has one, the latent
        detector otherwise. ``pd`` and ``pd_sub`` always come from the latent detector (the mesh detector
        estimates no depth).

        ``fast`` (latent detector only): None (the eager float32 network, as in training and in the reported
        metrics), ``"float32"`` (compiled with torch.compile: the same outputs to round-off, ~1.4x faster at batch
        4096 on 2 CPU cores), ``"bfloat16"`` (compiled, bfloat16 weights: ~2.3x faster where bfloat16 is native;
        about 0.1 % of labels flip) or ``"bfloat16_checked"`` (bfloat16, with the rows whose logit lies near 0
        recomputed in float32: ~1.9x, no label flipped on SCAPE's test sets). The first call with a ``fast``
        form compiles it (seconds); :class:`~neuralcol.nn.fast_inference.FastDetector` and docs/model_size.md
        have the measurements.

        ``certify`` (latent detector only): None, or a target FNR in [0, 1): the certified cascade (docs/cascade.md).
        The band ``[lo, hi)`` of that target (:meth:`band`, from the run's calibration set) decides which rows the
        exact labeler judges: logit below ``lo``: free, at or above ``hi``: colliding (the network), inside: the
        exact label of the **mesh** (a mesh given here is labeled itself, not its round trip; a code is decoded
        first), through the run's label pool (:meth:`label_pool`). The verdict is then ``collides``, not
        ``prob > 0.5``; ``exact`` marks the rows labeled, whose ``prob`` becomes 1.0 or 0.0. A row the exact
        labeler fails on is called colliding (never certified free) and not marked ``exact``."""
        if inputs not in ("auto", "mesh", "latent"):
            raise UserInputError(f"inputs={inputs!r}; use 'auto', 'mesh' or 'latent'")
        x = vertices_or_codes
        is_mesh = self._is_vertices(x)
        if inputs == "mesh" and self.mesh_detector is None:
            raise UserInputError(f"{self.run_dir}: this run has no mesh_detector.pt (it ran with "
                                 "mesh_detector.enabled=false or before issue 27); use inputs='latent'")
        use_mesh = inputs == "mesh" or (inputs == "auto" and is_mesh and self.mesh_detector is not None)
        band = None
        if certify is not None:
            if use_mesh:
                raise UserInputError("certify: the cascade's bands are calibrated on the latent detector's logits; "
                                     "use inputs='latent' with certify")
            band = self.band(certify)
        z = self.encode(x) if is_mesh else self._codes(x)
        # issue 41: a detector over code and mesh judges a mesh by its own geometry, not by its round trip's
        v = self._vertices(x).to(self.device) if is_mesh and self.detector.geometry is not None else None
        net = self.on_codes if fast is None or v is not None else self._fast_detector(fast)
        parts = []
        with torch.no_grad():
            for start in range(0, len(z), batch_size):
                zb = z[start:start + batch_size]
                out = net(zb) if v is None else \
                    self.detector(zb, self.detector.geometry_of_meshes(v[start:start + len(zb)]))
                parts.append(Detection(out.prob, out.logit, smooth_max(out.s, self.temperature) * self.pd_unit,
                                       out.s * self.pd_unit))
        if not parts:
            empty = z.new_zeros(0)
            no = z.new_zeros(0, dtype=bool)
            return Detection(empty, empty, empty, z.new_zeros(0, self.space.n_parts), no, no,
                             None if band is None else no)
        det = Detection(*(torch.cat(t) for t in zip(*(p[:4] for p in parts))), self.space.outside_box(z))
        if use_mesh:
            from neuralcol.nn.mesh_detector import mesh_logits

            meshes = self._vertices(x).numpy() if is_mesh else self.decode(z).cpu().numpy()
            logit = torch.as_tensor(mesh_logits(self.mesh_detector, meshes), dtype=torch.float32,
                                    device=det.logit.device)
            det = det._replace(prob=torch.sigmoid(logit), logit=logit)
        if band is None:
            return det._replace(collides=det.logit > 0)
        return self._certified(det, band, x if is_mesh else None, z)

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

    # ------------------------------------------------------------------ the certified cascade
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
                    f"{path}: missing; this run has no calibration set for the certified cascade (it predates issue "
                    "29 or ran with detector.cascade.enabled=false). Fix: run.calibrate() labels one and writes it "
                    "into the run directory (once), or run the run's command again with detector.cascade.enabled=true")
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
        from neuralcol.stages.cascade import calibration_set, save_calibration
        from neuralcol.stages.realistic import detector_logits

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

    def _fast_detector(self, form: str):
        """The compiled copy of the detector for ``form`` (built on first use, then kept)."""
        from neuralcol.nn.fast_inference import FORMS, FastDetector

        if form not in FORMS:
            raise UserInputError(f"fast={form!r}; use None or one of {sorted(FORMS)}")
        if form not in self._fast:
            self._fast[form] = FastDetector.from_form(self.on_codes, form)
        return self._fast[form]

    def repair_settings(self, repair: bool | None = None):
        """The run's ``handler.repair`` (off for runs older than it) with ``repair`` forcing it on or off."""
        from neuralcol.handler.contact_repair import repair_from_config

        try:
            return repair_from_config(self.cfg, enabled=repair)
        except ValueError as e:
            raise UserInputError(f"{self.run_dir}/.hydra/config.yaml: {e}") from e

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

    # ------------------------------------------------------------------ handling
    def resolve(self, vertices_or_codes, objective: str = "latent", verify: bool = True, margins=None,
                subset=None, anchor: str = "median", constraint: str = "latent",
                repair: bool | None = None, certify: float | None = None) -> Resolved:
        """Resolve self-collisions: meshes come back as the user's meshes, corrected; codes as decoded codes.

        The augmented-Lagrangian handler (docs/handler.md) moves each input's latent code to the nearest code
        the detector calls collision-free (the run's ``handler`` settings). For a **mesh**, the correction that
        move implies (the handled code decoded minus the input's own round trip) is added to the input mesh
        (:func:`~neuralcol.stages.handler.transfer_displacement`): the result is in the input's frame and
        keeps its detail, and the exact labeler judges that returned mesh. For a **code**, the result is the
        handled code decoded. With ``verify`` the results the exact labeler still finds self-penetrating are
        handled again with the larger margins (``margins``, default the run's ``handler.verify_margins``) and
        the lowest-PD result is kept; ``verify=False`` trusts the detector (PD after is still measured).

        Args:
            vertices_or_codes: meshes (N, V, 3) / (V, 3) or codes (N, D) / (D,), numpy or torch.
            objective: ``"latent"`` (stay close to the input's code) or ``"cartesian"`` (stay close to the input
                mesh's vertices; mesh inputs only).
            verify: exact verification with margin escalation.
            margins: verification margins, each above ``handler.alm.margin`` (None: the run's).
            subset: ``objective="cartesian"``: (S,) vertex indices whose positions count (None: all).
            anchor: mesh inputs: ``"median"`` (default) removes the translation the decoder's centroid pinning
                adds to the correction; ``"none"`` keeps the raw difference of the decoded meshes.
            constraint: mesh inputs: ``"latent"`` (default: the latent detector's logit on the code) or ``"mesh"``
                (the detector that reads the mesh, on the mesh that would be returned, differentiated through
                the decoder; slower, docs/real_meshes.md).
            repair: mesh inputs with ``verify``: a returned mesh the exact labeler still finds self-penetrating
                after the margins gets the contact repair (its intersecting triangles pushed apart, our addition;
                docs/real_meshes.md); None: the run's ``handler.repair.enabled``.
            certify: None, or a target FNR: verification through the certified cascade (needs ``verify``;
                docs/cascade.md): a handled result is labeled exactly only where the latent detector's logit on its
                code lies in the run's band for that target (:meth:`band`); below it the detector is trusted (free,
                kept, ``pd_after`` NaN), at or above it the result counts as still colliding (handled again with the
                next margin, then, for meshes, the contact repair). ``exact``, ``free`` and ``exact_share`` of the
                result say which verdicts were exact. The inputs' ``pd_input`` / ``pd_before`` are measured as
                without it.

        Returns:
            :class:`Resolved`.
        """
        from neuralcol.handler.objectives import CartesianObjective, LatentObjective
        from neuralcol.handler.resolve import (
            ANCHORS,
            CertifiedLabel,
            alm_settings,
            certified_outcome,
            detector_logits,
            displacement_stats,
            handle_codes,
            resolve_meshes,
            verified_escalation,
        )

        if objective not in OBJECTIVES:
            raise UserInputError(f"objective={objective!r}; use one of {OBJECTIVES}")
        if anchor not in ANCHORS:
            raise UserInputError(f"anchor={anchor!r}; use one of {ANCHORS}")
        if constraint not in ("latent", "mesh"):
            raise UserInputError(f"constraint={constraint!r}; use 'latent' or 'mesh'")
        if constraint == "mesh" and self.mesh_detector is None:
            raise UserInputError(f"{self.run_dir}: constraint='mesh' needs the run's mesh_detector.pt")
        band = None
        if certify is not None:
            if not verify:
                raise UserInputError("certify decides which handled results the exact labeler verifies; it needs "
                                     "verify=True")
            if constraint == "mesh":
                raise UserInputError("certify: the cascade's bands are calibrated on the latent detector's logits; "
                                     "use constraint='latent' with certify")
            band = self.band(certify)
        x = vertices_or_codes
        v_user = self._vertices(x) if self._is_vertices(x) else None
        z_user = (self.encode(v_user) if v_user is not None else self._codes(x)).float().cpu()
        if objective == "cartesian":
            if v_user is None:
                raise UserInputError("objective='cartesian' needs meshes (B, V, 3): their vertices are the targets")
            if subset is not None:
                subset = torch.as_tensor(np.asarray(subset), dtype=torch.long).reshape(-1)
                if len(subset) == 0 or subset.min() < 0 or subset.max() >= self.n_vertices:
                    raise UserInputError(f"subset: vertex indices must lie in [0, {self.n_vertices})")
            target = CartesianObjective(self.space, v_user.float().to(self.device), vertices=subset)
        else:
            target = LatentObjective(z_user.to(self.device))
        settings = alm_settings(self.cfg.handler.alm)
        margins = [] if not verify else \
            [float(m) for m in (margins if margins is not None else
                                OmegaConf.select(self.cfg, "handler.verify_margins", default=[]))]
        bad = [m for m in margins if m <= settings.margin]
        if bad:
            raise UserInputError(f"margins {bad} must exceed handler.alm.margin = {settings.margin}")
        batch = int(self.cfg.handler.batch_size)
        used_margins = np.array([settings.margin, *margins])
        diag = self.diagonal
        if v_user is not None:
            rep = self.repair_settings(repair) if verify else None
            if rep is not None:
                self.label_pool()  # the repair asks the run's labeler in this process
            res = resolve_meshes(self.on_codes, self.space, v_user, self._pd, settings, margins, batch,
                                 objective=target, anchor=anchor, z_user=z_user,
                                 mesh_net=self.mesh_detector if constraint == "mesh" else None,
                                 repair=rep, labeler=self._exact if rep is not None else None, certify=band)
            used_margins = np.append(used_margins, np.nan)
            moved = displacement_stats(v_user.numpy(), res.vertices, diag)
            return Resolved(vertices=torch.as_tensor(res.vertices, dtype=torch.float64, device=self.device),
                            codes=res.codes.to(self.device), codes_before=z_user.to(self.device),
                            pd_input=res.pd_input, pd_before=self._pd(self.decode(z_user)), pd_after=res.pd_after,
                            margin=used_margins[res.stage], displacement_mean=moved["mean"],
                            displacement_max=moved["max"], displacement_median=moved["median"], diagonal=diag,
                            decoded=torch.as_tensor(res.decoded, dtype=torch.float32, device=self.device),
                            repaired=res.repaired, exact=res.exact, free=res.free, exact_share=res.exact_share)

        def handle(rows: np.ndarray, margin: float):
            idx_map = torch.as_tensor(rows, device=self.device)
            return handle_codes(self.on_codes, z_user[torch.as_tensor(rows)], self.space.box_lo, self.space.box_hi,
                                replace(settings, margin=margin), batch_size=batch,
                                objective=lambda z, idx: target(z, idx_map[idx]))

        def label(z: torch.Tensor, rows=None) -> np.ndarray:
            return self._pd(self.decode(z))

        decide = label if band is None else \
            CertifiedLabel(band, lambda z: detector_logits(self.on_codes, z), label)
        res = handle(np.arange(len(z_user)), settings.margin)
        pd_after = np.full(len(z_user), np.nan)
        pd_after[res.finite.numpy()] = decide(res.z[res.finite])
        z, stage = res.z.float(), np.zeros(len(z_user), dtype=np.int64)
        if margins:
            z, pd_after, stage, _ = verified_escalation(handle, decide, z_user, z, pd_after, margins)
        exact = free = share = None
        if band is not None:
            pd_after, exact, free = certified_outcome(pd_after)
            share = decide.exact_share
        with torch.no_grad():  # (a failed result's code may be non-finite: no input check here)
            verts = self.space.decode(z.to(self.device))
            before = self.space.decode(z_user.to(self.device))
        moved = displacement_stats(before.cpu().numpy(), verts.cpu().numpy(), diag)
        nan = np.full(len(z_user), np.nan)
        return Resolved(vertices=verts, codes=z.to(self.device), codes_before=z_user.to(self.device),
                        pd_input=nan, pd_before=label(z_user), pd_after=pd_after, margin=used_margins[stage],
                        displacement_mean=moved["mean"], displacement_max=moved["max"],
                        displacement_median=moved["median"], diagonal=diag, decoded=verts, exact=exact, free=free,
                        exact_share=share)
