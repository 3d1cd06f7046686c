"""The files of a finished run directory, read and checked: its config (sections, trusted ``_target_`` entries),
``metrics.json``, model files (damaged or non-finite ones named with the fix) and :func:`check_run_dir`."""

from __future__ import annotations

import json
import math
import pickle
from collections.abc import Callable
from pathlib import Path

import torch
import yaml
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from neuralcol.errors import UserInputError
from neuralcol.rundir import RunDir

RUN_SECTIONS = ("dataset", "labeling", "detector", "handler", "paths")
# what reading a damaged or foreign model file raises past the loaders' own UserInputError: a broken zip archive,
# pickle or tensor record (RuntimeError, OSError, EOFError, UnpicklingError, UnicodeDecodeError, IndexError), or a
# blob without the expected keys, types or shapes (KeyError, TypeError, AttributeError, ValueError, RuntimeError
# of load_state_dict, IndexError)
DAMAGED_FILE_ERRORS = (RuntimeError, OSError, EOFError, pickle.UnpicklingError, ValueError, KeyError, IndexError,
                       TypeError, AttributeError)


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

