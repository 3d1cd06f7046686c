"""Cache keys: a short SHA-1 of settings (and of the bytes they belong to).

Every cache of the project (data sets, ACAP features, autoencoders, labeled samples, realistic sets, the box fit)
names its files by such a key. The keys must stay byte for byte what they are, or every user's cache is
invalidated: :func:`settings_key` is ``sha1(<bytes...> + json.dumps(settings, sort_keys=True)).hexdigest()[:length]``
exactly as each cache computed it by hand before (``tests/test_hashing.py`` pins known keys).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterable


def content_key(parts: Iterable[bytes], length: int = 16) -> str:
    """The first ``length`` hex digits of the SHA-1 of ``parts`` concatenated, in order."""
    h = hashlib.sha1()
    for part in parts:
        h.update(part)
    return h.hexdigest()[:length]


def settings_key(settings, length: int = 16, data: Iterable[bytes] = (), default: Callable | None = None) -> str:
    """The cache key of ``settings`` (anything ``json.dumps`` takes): the first ``length`` hex digits of the SHA-1 of
    ``data`` (bytes the settings apply to, e.g. the meshes' vertices, in order; none by default) followed by
    ``json.dumps(settings, sort_keys=True, default=default)``. The same settings give the same key in any order of
    their dict entries."""
    return content_key([*data, json.dumps(settings, sort_keys=True, default=default).encode()], length)
