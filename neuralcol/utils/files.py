"""Atomic file writes: a reader never sees a partial file, and several processes may write one cache entry at once."""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``, unique to this writer, and move it onto ``path`` on success.

    Two processes (or threads) that write the same cache entry each write their own temporary file, and the
    last ``os.replace`` wins with a complete file; a reader never sees a partial one. A shared temporary name
    (``<name>.tmp``) let one writer move the other's file away mid-write (two runs of one new data
    set started together failed with FileNotFoundError). The temporary name keeps ``path``'s suffix, since
    ``np.savez`` appends ``.npz`` to names without it. On an exception the temporary file is removed.
    """
    path = Path(path)
    tmp = path.with_name(f"{path.stem}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_json_atomic(path: str | os.PathLike, obj) -> None:
    """Write ``obj`` as indented JSON to ``path`` atomically (:func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2))
