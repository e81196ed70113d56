"""Atomic file writes: a reader sees either the old file or the whole new one, never half of it,
and a failure leaves nothing behind."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same folder and suffix, the usual permissions of a
    new file); rename it onto ``path`` if the block succeeds, delete it otherwise. An
    ``OSError`` of the block (a full disk) is raised naming ``path``."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        if exc.filename is None or exc.filename == tmp:  # name the file the user asked for
            raise OSError(exc.errno, exc.strerror, str(path)) from exc
        raise
    finally:
        Path(tmp).unlink(missing_ok=True)


def atomic_write_bytes(path: str | Path, payload: bytes, *, fsync: bool = True) -> None:
    """Write ``payload`` to ``path`` atomically (creating its folder); with ``fsync`` the data is
    flushed to disk before the rename (cache entries that must survive a crash)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(payload)
        if fsync:
            fh.flush()
            os.fsync(fh.fileno())


def atomic_write_npz(path: str | Path, **arrays: object) -> None:
    """``np.savez`` to ``path`` atomically. The archive is built in memory first, so a full
    disk fails in one clean ``OSError`` (a ``ZipFile`` half-written to a file that failed leaves
    a second error behind when it is collected)."""
    import io

    import numpy as np

    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # type: ignore[arg-type]
    atomic_write_bytes(path, buffer.getvalue(), fsync=False)


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"), fsync=False)


@contextmanager
def staged_folder(folder: str | Path) -> Iterator[Path]:
    """A new folder assembled under a temporary name beside ``folder`` (which must not exist, or
    be empty) and renamed to it when the block ends without an error; on an error the staging
    folder is removed and ``folder`` is left as it was.

    Raises:
        OSError: the parent cannot be written.
    """
    import shutil

    folder = Path(folder)
    parent = folder.resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=parent, prefix=f".{folder.name}.staging-"))
    try:
        yield staging
        if folder.exists():
            folder.rmdir()
        os.replace(staging, folder)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
