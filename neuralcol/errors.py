"""Exception types for errors caused by user input (files, settings).

Entry points catch :class:`UserInputError` and print its message as a single line (no traceback);
set ``HYDRA_FULL_ERROR=1`` or pass ``--debug`` to see the traceback.
"""

from __future__ import annotations


class UserInputError(ValueError):
    """Bad input from the user: the message names the file or setting and how to fix it."""


class MeshFileError(UserInputError):
    """A mesh file cannot be read or breaks a rule of the data set (topology, finiteness, ...)."""


class DatasetNotFoundError(UserInputError, FileNotFoundError):
    """A configured data set path does not exist or holds no meshes."""


class UnsafeFileError(UserInputError):
    """A saved file (checkpoint, cache entry) holds pickled Python objects, which neuralcol refuses to unpickle
    (unpickling runs the file's code), or cannot be read at all."""
