"""On-disk cache of perception results.

Entries are keyed by a hash of the input's *content* (the decoded frames and their source
indices, not the file name) and of everything that changes the result (settings, detector
names and versions, precomputed inputs), so a second run on the same input skips perception and
a change of any setting recomputes. Files are written atomically (temporary name, then rename):
a crash leaves either no entry or a whole one; an unreadable entry is ignored and recomputed.

Location: ``$MONOAVATAR_CACHE`` if set, else ``~/.cache/monoavatar``; perception entries live in
its ``perception/`` folder. Deleting the folder is always safe.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from monoavatar.core.files import atomic_write_bytes

CACHE_ENV = "MONOAVATAR_CACHE"
_CACHE_VERSION = "perception-v1"


def cache_root() -> Path:
    """The cache folder: ``$MONOAVATAR_CACHE`` or ``~/.cache/monoavatar``."""
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "monoavatar"


def perception_cache_dir(root: str | Path | None = None) -> Path:
    """Folder of perception entries under ``root`` (default :func:`cache_root`)."""
    return (Path(root) if root is not None else cache_root()) / "perception"


def make_key(*parts: Any) -> str:
    """A hex key from JSON-serialisable parts (dicts are key-sorted), this package's version and
    the cache format version (bump ``_CACHE_VERSION`` when perception's results change)."""
    from monoavatar import __version__

    text = json.dumps([_CACHE_VERSION, __version__, *parts], sort_keys=True, default=str)
    return hashlib.blake2b(text.encode(), digest_size=20).hexdigest()


def load_arrays(path: Path) -> dict[str, np.ndarray] | None:
    """The arrays of a cache entry, or None when absent or unreadable (with a warning)."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            return {name: data[name] for name in data.files}
    except Exception as exc:  # any damage: recompute rather than fail
        warnings.warn(f"ignoring unreadable cache entry {path} ({exc})", stacklevel=2)
        return None


def save_arrays(path: Path, arrays: dict[str, np.ndarray], compress: bool = True) -> None:
    """Write arrays to an ``.npz`` cache entry atomically."""
    buffer = io.BytesIO()
    if compress:
        np.savez_compressed(buffer, **arrays)
    else:
        np.savez(buffer, **arrays)
    atomic_write_bytes(path, buffer.getvalue())
