"""A restricted unpickler for data files users already have (People-Snapshot ``camera.pkl``).

``pickle.load`` on a file from elsewhere can run arbitrary code: a pickle names callables that
the loader imports and calls. :func:`safe_load` allows only what a pickled dict of numbers,
strings and numpy arrays needs (numpy's array and scalar reconstruction, ``dtype``) and refuses
everything else with :class:`UnsafePickleError` before anything is called. Files written by
Python 2 (as the original research code did) are read with ``encoding="latin1"``, which numpy
needs for their array buffers.
"""

from __future__ import annotations

import pickle
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from monoavatar.core.errors import InputFormatError, InputNotFoundError, UnsafePickleError


def _allowed_globals() -> dict[tuple[str, str], Any]:
    import builtins
    import codecs
    import importlib

    multiarray: Any = importlib.import_module("numpy.core.multiarray")

    allowed: dict[tuple[str, str], Any] = {
        ("numpy", "ndarray"): np.ndarray,
        ("numpy", "dtype"): np.dtype,
        # Python 3 pickles of protocol < 3 store bytes as latin-1 text re-encoded by this.
        ("_codecs", "encode"): codecs.encode,
    }
    numeric: Any = importlib.import_module("numpy.core.numeric")
    for prefix in ("numpy.core", "numpy._core"):  # numpy 1.x and 2.x
        allowed[(f"{prefix}.multiarray", "_reconstruct")] = multiarray._reconstruct
        allowed[(f"{prefix}.multiarray", "scalar")] = multiarray.scalar
        allowed[(f"{prefix}.numeric", "_frombuffer")] = numeric._frombuffer  # protocol 5
    for name in ("set", "frozenset", "complex", "slice"):
        for module in ("builtins", "__builtin__"):  # Python 3 and Python 2 names
            allowed[(module, name)] = getattr(builtins, name)
    return allowed


_ALLOWED = _allowed_globals()


#: Maps a (module, name) a pickle asks for to the object to use, or None to refuse it.
Resolver = Callable[[str, str], Any]


class _RestrictedUnpickler(pickle.Unpickler):
    def __init__(self, file: BinaryIO, path: Path, resolve: Resolver | None) -> None:
        super().__init__(file, encoding="latin1")
        self._path = path
        self._resolve = resolve

    def find_class(self, module: str, name: str) -> Any:
        allowed = _ALLOWED.get((module, name))
        if allowed is None and self._resolve is not None:
            allowed = self._resolve(module, name)
        if allowed is None:
            raise UnsafePickleError(
                self._path,
                f"refusing to load '{module}.{name}': only numbers, strings, lists, dicts and "
                "numpy arrays are allowed in this file",
            )
        return allowed


def safe_load(path: str | Path, resolve: Resolver | None = None) -> Any:
    """Unpickle ``path`` allowing only builtin containers/numbers and numpy arrays, plus what
    ``resolve(module, name)`` returns for the names it admits (None for the rest).

    Raises:
        InputNotFoundError: no such file.
        UnsafePickleError: the pickle names any other class or function.
        InputFormatError: the file is not a valid pickle, including one whose length fields ask
            for more memory than exists (a corrupt ``BINBYTES8`` makes the unpickler try to
            allocate exabytes before it reads a byte).
    """
    path = Path(path)
    if not path.is_file():
        raise InputNotFoundError(path, "no such file")
    with path.open("rb") as fh:
        try:
            return _RestrictedUnpickler(fh, path, resolve).load()
        except UnsafePickleError:
            raise
        except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError,
                IndexError, KeyError, UnicodeDecodeError, OverflowError) as exc:
            raise InputFormatError(path, f"not a valid pickle file ({exc})") from exc
        except MemoryError as exc:
            raise InputFormatError(
                path, "not a valid pickle file (a length in it asks for more memory than this "
                f"machine has; the file is {path.stat().st_size} bytes)") from exc
