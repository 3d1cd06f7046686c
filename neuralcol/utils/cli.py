"""Helpers shared by the command-line entry points."""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable

from neuralcol.errors import UserInputError


def debug_requested() -> bool:
    """True when tracebacks should be shown for user errors (``HYDRA_FULL_ERROR=1`` or ``NEURALCOL_DEBUG=1``)."""
    return os.environ.get("HYDRA_FULL_ERROR") == "1" or os.environ.get("NEURALCOL_DEBUG") == "1"


def find_user_error(exc: BaseException) -> UserInputError | None:
    """The first :class:`UserInputError` in the chain of ``exc`` (wrappers such as Hydra's
    ``InstantiationException`` keep the original as ``__cause__``), or None."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, UserInputError):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def report_user_errors(func: Callable) -> Callable:
    """Decorator: a :class:`UserInputError` becomes one line on stderr and exit code 2 (no traceback).

    Developers get the traceback with ``HYDRA_FULL_ERROR=1`` or ``NEURALCOL_DEBUG=1``.
    """

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except Exception as exc:
            user_error = find_user_error(exc)
            if user_error is None or debug_requested():
                raise
            print(f"error: {user_error}", file=sys.stderr)
            sys.exit(2)

    return wrapper
