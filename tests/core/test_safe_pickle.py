from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np
import pytest

from monoavatar.core.safe_pickle import safe_load
from monoavatar.io import InputFormatError, InputNotFoundError, UnsafePickleError


@pytest.mark.parametrize("protocol", [0, 2, 4, 5])
def test_loads_numbers_strings_and_arrays(tmp_path: Path, protocol: int) -> None:
    data = {
        "camera_f": np.array([1000.0, 1001.0]),
        "camera_k": np.zeros(5, dtype=np.float32),
        "width": 1080,
        "name": "seq",
        "scalar": np.float64(2.5),
        "nested": [(1, 2.0), {"a": None}],
        "labels": {1, 2},
    }
    path = tmp_path / "camera.pkl"
    path.write_bytes(pickle.dumps(data, protocol=protocol))
    loaded = safe_load(path)
    np.testing.assert_array_equal(loaded["camera_f"], data["camera_f"])
    assert loaded["camera_k"].dtype == np.float32
    assert loaded["width"] == 1080 and loaded["name"] == "seq" and loaded["scalar"] == 2.5
    assert loaded["nested"] == [(1, 2.0), {"a": None}] and loaded["labels"] == {1, 2}


class _Exploit:
    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[object, tuple[str]]:
        return (os.system, (f"touch {self.marker}",))


def test_refuses_code_execution(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    path = tmp_path / "camera.pkl"
    path.write_bytes(pickle.dumps({"camera_f": _Exploit(str(marker))}, protocol=2))
    message = r"camera\.pkl: refusing to load '(posix|os|nt)\.system'"
    with pytest.raises(UnsafePickleError, match=message):
        safe_load(path)
    assert not marker.exists()


def test_refuses_arbitrary_classes(tmp_path: Path) -> None:
    path = tmp_path / "obj.pkl"
    path.write_bytes(pickle.dumps(Path("x")))
    with pytest.raises(UnsafePickleError, match="pathlib"):
        safe_load(path)


def test_bad_files(tmp_path: Path) -> None:
    with pytest.raises(InputNotFoundError):
        safe_load(tmp_path / "missing.pkl")
    path = tmp_path / "bad.pkl"
    path.write_bytes(b"not a pickle at all")
    with pytest.raises(InputFormatError, match=r"bad\.pkl: not a valid pickle"):
        safe_load(path)
    path.write_bytes(pickle.dumps({"a": 1})[:-3])
    with pytest.raises(InputFormatError, match="not a valid pickle"):
        safe_load(path)


def test_corrupt_length_fields_are_format_errors(tmp_path: Path) -> None:
    path = tmp_path / "huge.pkl"
    # Protocol 4, BINBYTES8 claiming 2**62 bytes: the unpickler allocates before it reads.
    path.write_bytes(b"\x80\x04\x8e" + (2**62).to_bytes(8, "little") + b"xx")
    with pytest.raises(InputFormatError, match="more memory than this machine has"):
        safe_load(path)


def test_random_bytes_only_ever_raise_the_documented_errors(tmp_path: Path) -> None:
    """Seeded fuzz: about 1 % of random 200-byte files hit MemoryError or OverflowError inside
    the unpickler; all must come out as the documented InputFormatError/UnsafePickleError."""
    rng = np.random.default_rng(2026)
    path = tmp_path / "fuzz.pkl"
    for _ in range(2000):
        path.write_bytes(rng.bytes(200))
        with pytest.raises((InputFormatError, UnsafePickleError)):
            safe_load(path)
