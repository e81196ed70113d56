"""Atomic writes: a reader sees the old file or the whole new one; a full disk fails in one
clean OSError and leaves neither a half-written file nor a temporary one behind."""

from __future__ import annotations

import errno
import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from monoavatar.core import files
from monoavatar.core.files import atomic_write_npz


class _FullDisk(io.RawIOBase):
    """A writable file on a disk with ``room`` bytes left."""

    def __init__(self, path: str | Path, room: int) -> None:
        self._fh = open(path, "wb")  # noqa: SIM115 - closed in close()
        self._room = room

    def writable(self) -> bool:
        return True

    def write(self, data: Any) -> int:
        if len(data) > self._room:
            raise OSError(errno.ENOSPC, "No space left on device")
        self._room -= len(data)
        return self._fh.write(data)

    def close(self) -> None:
        self._fh.close()
        super().close()


def _full_disk(monkeypatch: pytest.MonkeyPatch, room: int = 10) -> None:
    monkeypatch.setattr(files, "open", lambda path, mode="r": _FullDisk(path, room), raising=False)


def test_npz_round_trip(tmp_path: Path) -> None:
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    atomic_write_npz(tmp_path / "x.npz", a=a, name=np.array("body"))
    with np.load(tmp_path / "x.npz") as data:
        np.testing.assert_array_equal(data["a"], a)
        assert str(data["name"]) == "body"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.npz"]


def test_full_disk_keeps_the_old_file_and_leaves_no_temporary(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        recwarn: pytest.WarningsRecorder) -> None:  # fmt: skip
    path = tmp_path / "x.npz"
    atomic_write_npz(path, a=np.zeros(3))
    before = path.read_bytes()
    _full_disk(monkeypatch)
    with pytest.raises(OSError) as info:
        atomic_write_npz(path, a=np.ones(1000))
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.npz"]
    unraisable = pytest.PytestUnraisableExceptionWarning
    assert not [w for w in recwarn if issubclass(w.category, unraisable)]


def test_cli_says_the_disk_is_full(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                   capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    from monoavatar.cli import main
    from monoavatar.io import export_mesh

    def write_obj(path: Path, *args: object, **kwargs: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(export_mesh, "write_obj", write_obj)
    assert main(["body", "-o", str(tmp_path / "out"), "--pose", "rest"]) == 2
    err = capsys.readouterr().err
    assert "No space left on device" in err and "body.obj" in err
    assert "the disk is full: free some space or write the output elsewhere" in err
    assert "Traceback" not in err


def _write_entry_many_times(path: str, value: int) -> None:
    from monoavatar.perception.cache import save_arrays

    for k in range(40):
        save_arrays(Path(path), {"value": np.full(2000 + 37 * value + k, value, np.int64)})


def test_processes_sharing_a_cache_entry_never_see_a_partial_file(tmp_path: Path) -> None:
    """Batch workers share one cache folder: four processes write the same entry over and over
    while this one reads it; every read is one writer's whole array, and no temporary file
    is left behind."""
    import multiprocessing
    import warnings

    from monoavatar.perception.cache import load_arrays

    entry = tmp_path / "cache" / "perception" / "entry.npz"
    entry.parent.mkdir(parents=True)
    context = multiprocessing.get_context("spawn")
    writers = [context.Process(target=_write_entry_many_times, args=(str(entry), v))
               for v in range(1, 5)]  # fmt: skip
    for w in writers:
        w.start()
    reads = 0
    while any(w.is_alive() for w in writers) or reads == 0:
        if entry.exists():
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # "ignoring unreadable cache entry" fails
                data = load_arrays(entry)
            assert data is not None
            value = int(data["value"][0])
            assert 1 <= value <= 4 and (data["value"] == value).all()
            assert (len(data["value"]) - 2000 - 37 * value) in range(40)
            reads += 1
    for w in writers:
        w.join()
        assert w.exitcode == 0
    assert [p.name for p in entry.parent.iterdir()] == ["entry.npz"]
