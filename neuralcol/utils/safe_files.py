"""Reading and writing torch files without unpickling code.

``torch.load`` with ``weights_only`` off unpickles, and unpickling runs whatever code the file names: a shared
run directory or cache entry could do anything to the machine that loads it. neuralcol therefore reads every
checkpoint and cache file with :func:`read_torch_file` (``weights_only=True``: tensors, Python scalars,
strings, lists, tuples and dicts, plus numpy arrays and scalars of numeric dtypes for files written before
:func:`plain_values`), and writes them through :func:`plain_values`, so new files hold nothing else. A file
that holds anything else raises :class:`~neuralcol.errors.UnsafeFileError` naming the file; it is never run.
"""

from __future__ import annotations

import enum
import pickle
import re
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path, PurePath
from typing import Any

import numpy as np
import torch

from neuralcol.errors import UnsafeFileError

REMAKE = "re-create it with this version of neuralcol"
_NUMERIC_DTYPE_CODES = "?bhilqpBHILQPefdgFDG"  # bool, signed/unsigned ints, floats, complex


def _numpy_globals() -> list:
    """The numpy functions and classes a pickled numeric numpy array or scalar names (numpy 2 spells the
    module ``numpy._core``, files written under numpy 1 ``numpy.core``): rebuilding an array or a scalar
    from raw bytes and a dtype, nothing that calls other code. Object arrays still unpickle their elements
    with the restricted unpickler, so they stay refused unless the elements are plain values."""
    core = np._core.multiarray
    rebuilders = []
    for fn in (core._reconstruct, core.scalar):
        rebuilders += [fn, (fn, f"numpy.core.multiarray.{fn.__name__}")]
    dtype_classes = {type(np.dtype(c)) for c in _NUMERIC_DTYPE_CODES}
    return rebuilders + [np.ndarray, np.dtype, *sorted(dtype_classes, key=lambda t: t.__name__)]


ALLOWED_NUMPY_GLOBALS = _numpy_globals()


@contextmanager
def numpy_values_allowed() -> Iterator[None]:
    """Within this block ``torch.load(..., weights_only=True)`` also accepts numeric numpy arrays and scalars
    (:data:`ALLOWED_NUMPY_GLOBALS`); everything else stays refused."""
    with torch.serialization.safe_globals(ALLOWED_NUMPY_GLOBALS):
        yield


def _unsafe_names(path: Path, exc: BaseException) -> list[str]:
    """Names of the Python objects ``path`` would need unpickled and :func:`read_torch_file` refuses: read from
    the file's pickle opcodes without running them, else from torch's message; [] when neither tells."""
    allowed = {g[1] if isinstance(g, tuple) else f"{g.__module__}.{g.__qualname__}"
               for g in ALLOWED_NUMPY_GLOBALS}
    try:
        names = torch.serialization.get_unsafe_globals_in_checkpoint(path)
    except Exception:  # a legacy (not zip) file or a damaged one: only torch's message can tell
        names = re.findall(r"GLOBAL ([\w.]+)", str(exc))
    return [n for n in dict.fromkeys(names) if n not in allowed]


def _reason(exc: BaseException) -> str:
    """The line of torch's long weights_only message that says what was refused."""
    text = str(exc)
    detail = text.split("WeightsUnpickler error:", 1)[-1].strip()
    return (detail.splitlines() or [type(exc).__name__])[0].strip()[:200]


def read_torch_file(path: str | Path, map_location: Any = "cpu", fix: str = REMAKE) -> Any:
    """``torch.load`` that never unpickles code: ``weights_only=True`` with numeric numpy values allowed.

    Args:
        path: a file written by ``torch.save`` (checkpoint, cache entry).
        map_location: as ``torch.load``.
        fix: what the user should do about a refused file (ends the error message).

    Returns:
        The saved object (dicts, lists, tuples, tensors, Python scalars, strings, numeric numpy values).

    Raises:
        UnsafeFileError: the file holds pickled Python objects (named in the message), which are not run, or it
            is damaged / not a torch file.
    """
    path = Path(path)
    try:
        with numpy_values_allowed():
            return torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as exc:
        names = _unsafe_names(path, exc)
        if names:
            what = ", ".join(names[:4]) + (", ..." if len(names) > 4 else "")
            raise UnsafeFileError(f"{path}: holds pickled Python objects ({what}); neuralcol does not unpickle "
                                  f"files, since that runs their code; {fix}") from exc
        raise _unreadable(path, _reason(exc), fix) from exc
    except (RuntimeError, EOFError, KeyError) as exc:
        if isinstance(exc, RuntimeError) and "PytorchStreamReader" not in str(exc):
            raise  # not the file's bytes (e.g. a map_location this machine lacks)
        first = (str(exc).splitlines() or [""])[0].split(". ")[0][:160]  # torch's first sentence
        raise _unreadable(path, f"{type(exc).__name__}: {first}", fix) from exc


def _unreadable(path: Path, reason: str, fix: str) -> UnsafeFileError:
    """The error for a file that is neither plain values nor names the objects it would unpickle."""
    return UnsafeFileError(f"{path}: cannot be read as a torch file of tensors and plain values ({reason}); it is "
                           "damaged, not a file neuralcol wrote, or holds pickled objects, which neuralcol does not "
                           f"unpickle; {fix}")


def plain_values(obj: Any, where: str = "value") -> Any:
    """``obj`` as values that load with ``weights_only=True``: dicts, lists, tuples, tensors, Python scalars,
    strings and None.

    numpy scalars become Python scalars and numpy arrays lists; OmegaConf containers become dicts and lists,
    named tuples dicts, paths strings, enums their value; subclasses of int, float and str become the base type.

    Args:
        obj: the value to save (tensors are kept as they are).
        where: its name in error messages (nested keys are appended).

    Raises:
        TypeError: a value of another type (naming ``where`` and the type).
    """
    if obj is None or type(obj) in (bool, int, float, str) or isinstance(obj, torch.Tensor):
        return obj
    if isinstance(obj, enum.Enum):
        return plain_values(obj.value, where)
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj)
    if isinstance(obj, str):
        return str(obj)
    if isinstance(obj, PurePath):
        return str(obj)
    if isinstance(obj, np.ndarray):
        return plain_values(obj.tolist(), where)
    if _is_omegaconf(obj):
        from omegaconf import OmegaConf

        return plain_values(OmegaConf.to_container(obj, resolve=True), where)
    if isinstance(obj, tuple) and hasattr(obj, "_asdict"):  # a NamedTuple
        return plain_values(obj._asdict(), where)
    if isinstance(obj, Mapping):
        return {plain_values(k, f"{where} key"): plain_values(v, f"{where}[{k!r}]") for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        items = [plain_values(v, f"{where}[{i}]") for i, v in enumerate(obj)]
        return tuple(items) if isinstance(obj, tuple) else items
    raise TypeError(f"{where}: a {type(obj).__module__}.{type(obj).__qualname__} cannot be saved so that it loads "
                    "without unpickling; store tensors, numbers, strings, lists or dicts instead")


def _is_omegaconf(obj: Any) -> bool:
    """True for an OmegaConf DictConfig/ListConfig (without importing omegaconf for other values)."""
    return type(obj).__module__.startswith("omegaconf")
