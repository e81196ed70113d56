"""Bad input, as a careless user or an adversary gives it, through the CLI: each case ends
with exit code 2, a message that names the problem, no traceback, and no output folder."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import pytest

from monoavatar.cli import main
from tests.io.media_helpers import write_video


def _missing(tmp: Path) -> Path:
    return tmp / "missing.mp4"


def _empty(tmp: Path) -> Path:
    path = tmp / "empty.mp4"
    path.write_bytes(b"")
    return path


def _text(tmp: Path) -> Path:
    path = tmp / "notes.mp4"
    path.write_text("this is not a video\n" * 50)
    return path


def _moov_lost(tmp: Path) -> Path:
    data = write_video(tmp / "whole.mp4", n=12).read_bytes()
    path = tmp / "cut.mp4"
    path.write_bytes(data[: len(data) // 2])
    return path


def _faststart_cut(tmp: Path) -> Path:
    data = write_video(tmp / "whole.mp4", n=24, faststart=True).read_bytes()
    start = data.find(b"mdat")
    path = tmp / "cut.mp4"
    path.write_bytes(data[: start + (len(data) - start) * 4 // 10])
    return path


def _avi_cut(tmp: Path) -> Path:
    data = write_video(tmp / "whole.avi", n=30, codec="mpeg4").read_bytes()
    path = tmp / "cut.avi"
    path.write_bytes(data[: len(data) // 2])
    return path


def _video(tmp: Path) -> Path:
    return write_video(tmp / "clip.mp4", n=6)


CASES: dict[str, tuple[Callable[[Path], Path], list[str], str]] = {
    "missing file": (_missing, [], r"missing\.mp4: no such file"),
    "empty file": (_empty, [], r"empty \(0 bytes\)"),
    "text file": (_text, [], r"not a video"),
    "mp4 cut short (index lost)": (_moov_lost, [], r"cut short.*copy it again"),
    "mp4 cut short (index first)": (_faststart_cut, [], r"'mdat' box .* 40 % of it"),
    "avi cut short": (_avi_cut, [], r"cut short: it declares"),
    "height in centimetres": (_video, ["--height", "175"], r"metres"),
    "frames below two": (_video, ["--frames", "1"], r"at least 2"),
    "frames beyond any use": (_video, ["--frames", "100000"], r"at most 600 key-frames"),
    "texture too large": (_video, ["--texture-size", "100000"], r"\[16, 8192\] texels"),
    "max side too small": (_video, ["--max-side", "100"], r"\[256, 4096\] pixels"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_reconstruct_refuses_bad_input(case: str, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    make, extra, message = CASES[case]
    source = make(tmp_path)
    out = tmp_path / "out"
    code = main(["reconstruct", str(source), "-o", str(out), "--quiet", *extra])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    assert re.search(message, err), err
    assert not out.exists()


@pytest.mark.parametrize("verb", ["fit-poses", "fit-shape", "track"])
def test_other_verbs_leave_no_folder_for_a_missing_input(
    verb: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    assert main([verb, str(tmp_path / "missing.mp4"), "-o", str(out)]) == 2
    assert "missing.mp4: no such file" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(("args", "message"), [
    (["--size", "100000", "100000"], r"at most 4096 pixels"),
    (["--frames", "1000000"], r"at most 10000"),
    (["--texture-size", "100000"], r"\[16, 8192\]"),
])  # fmt: skip
def test_synth_refuses_sizes_beyond_any_use(
    args: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "scene"
    assert main(["synth", "turnaround", "-o", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert re.search(message, err) and "Traceback" not in err, err
    assert not out.exists()


def test_warnings_are_one_line_without_source(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # a frame that cannot be decoded is skipped with a warning; the run then fails for want of
    # a person, but the warning must read as one line from us, not as Python source
    from tests.io.test_video import _corrupt_packet

    video = _corrupt_packet(write_video(tmp_path / "c.mp4", n=12), 5)
    main(["reconstruct", str(video), "-o", str(tmp_path / "o"), "--quiet", "--frames", "12"])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "skipped 1 frame" in line]
    assert lines and lines[0].startswith("monoavatar reconstruct: warning: "), err
    assert "warnings.warn(" not in err and "stacklevel" not in err
