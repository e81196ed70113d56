"""Reading video files (mp4, mov, avi, webm, anything FFmpeg decodes) through PyAV.

Frames are returned in display orientation: the rotation stored in the container's display
matrix (phones record portrait video as landscape frames plus a 90° rotation) is applied, so
``Frames.images`` look as a player shows them and a user's ``camera.json`` refers to them.

Frame indices are presentation-order positions among all packets of the video stream; times are
seconds from the first frame. The file is read twice: once without decoding to list the frames
(cheap), then decoding only as far as the last selected frame.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Literal

import av
import numpy as np

from monoavatar.core.errors import (
    CorruptFrameError,
    CorruptFrameWarning,
    EmptyVideoError,
    InputFormatError,
    InputNotFoundError,
    NotAVideoError,
    TruncatedVideoError,
    format_indices,
)
from monoavatar.io.frames import Frames, FrameSelection, resize_max_side

VIDEO_EXTENSIONS = (".mp4", ".mov", ".m4v", ".avi", ".webm", ".mkv", ".mpg", ".mpeg", ".wmv")

OnCorrupt = Literal["skip", "raise"]

TRUNCATED_SHARE = 0.9
"""A video holding fewer than this share of the frames its header announces is refused as
truncated (a partial turn would make a wrong avatar, silently)."""


_ISO_BOXES = (b"ftyp", b"moov", b"mdat", b"free", b"skip", b"wide", b"uuid", b"meta", b"moof",
              b"mfra", b"pdin", b"styp", b"sidx")  # fmt: skip


def _megabytes(n: int) -> str:
    return f"{n / 1e6:.1f} MB" if n >= 100_000 else f"{n / 1e3:.1f} kB"


def _mp4_truncation(path: Path) -> str | None:
    """What says a file is cut short, else None. An MP4 / MOV file (ISO base media): a
    top-level box that runs past the end of the file, or media data without its index (the
    ``moov`` box, written last by most recorders). An AVI (RIFF) file: a declared size beyond
    the end. Other files: None."""
    size = path.stat().st_size
    boxes: list[bytes] = []
    with path.open("rb") as fh:
        head = fh.read(12)
        if head[:4] == b"RIFF" and head[8:12] == b"AVI ":
            declared = int.from_bytes(head[4:8], "little") + 8
            if declared > size:
                return (f"the file is cut short: it declares {_megabytes(declared)} but only "
                        f"{100.0 * size / declared:.0f} % of it is there (an interrupted copy, "
                        "download or recording); copy it again from the source")  # fmt: skip
            return None
        offset = 0
        while offset + 8 <= size:
            fh.seek(offset)
            head = fh.read(16)
            length, kind = int.from_bytes(head[:4], "big"), head[4:8]
            if not boxes and kind != b"ftyp":
                return None  # not an ISO media file
            if length == 1 and len(head) == 16:
                length = int.from_bytes(head[8:16], "big")
            elif length == 0:
                length = size - offset
            if length < 8 or kind not in _ISO_BOXES:
                return None  # not a box structure we know: leave it to FFmpeg
            boxes.append(kind)
            if offset + length > size:
                have = 100.0 * (size - offset) / length
                return (f"the file is cut short: its {kind.decode()!r} box needs "
                        f"{_megabytes(length)} but only {have:.0f} % of it is there "
                        "(an interrupted copy, download or recording); copy it again "
                        "from the source")  # fmt: skip
            offset += length
    if boxes and b"mdat" in boxes and b"moov" not in boxes and b"moof" not in boxes:
        return ("the file has video data but no index (its 'moov' box is missing): the "
                "recording or copy was cut short; copy it again from the source")  # fmt: skip
    return None


@contextmanager
def _open_video(path: Path) -> Iterator[tuple[Any, Any]]:
    if path.stat().st_size == 0:
        raise EmptyVideoError(path, "the file is empty (0 bytes)")
    try:
        container = av.open(str(path))
    except av.error.EOFError as exc:
        truncated = _mp4_truncation(path)
        if truncated:
            raise TruncatedVideoError(path, truncated) from exc
        raise EmptyVideoError(
            path, "the file ends before any frame (an empty or truncated video)"
        ) from exc
    except av.error.FFmpegError as exc:
        truncated = _mp4_truncation(path)
        if truncated:
            raise TruncatedVideoError(path, truncated) from exc
        raise NotAVideoError(path, f"not a video ({exc.strerror or exc})") from exc
    try:
        if not container.streams.video:
            raise NotAVideoError(path, "not a video (the file has no video stream)")
        yield container, container.streams.video[0]
    finally:
        container.close()


def _announced_frames(stream: Any) -> int:
    """The frame count a video stream's header announces (0 when it does not say)."""
    return int(stream.frames or 0)


def _packet_times(path: Path) -> tuple[list[int], float, str | None]:
    """Presentation timestamps of all video packets (sorted), the time base, and the error that
    stopped demuxing early (None when the whole file was read).

    Raises:
        TruncatedVideoError: the file's structure or its header's frame count says it was cut
            short (fewer than :data:`TRUNCATED_SHARE` of the announced frames are there).
    """
    stamps: list[int] = []
    problem: str | None = None
    truncated = _mp4_truncation(path)
    if truncated:
        raise TruncatedVideoError(path, truncated)
    with _open_video(path) as (container, stream):
        announced = _announced_frames(stream)
        time_base = float(stream.time_base) if stream.time_base else 1.0
        try:
            for n, packet in enumerate(container.demux(stream)):
                if packet.size == 0:
                    continue
                ts = packet.pts if packet.pts is not None else packet.dts
                stamps.append(int(ts) if ts is not None else n)
        except av.error.FFmpegError as exc:
            problem = f"the file could not be read past frame {len(stamps)} ({exc.strerror or exc})"
    stamps = sorted(set(stamps))
    if announced and len(stamps) < TRUNCATED_SHARE * announced:
        raise TruncatedVideoError(
            path,
            f"the file is cut short: its header announces {announced} frames but only "
            f"{len(stamps)} are in it ({100 * len(stamps) / announced:.0f} %); copy it again "
            "from the source",
        )
    return stamps, time_base, problem


def _rotate(image: np.ndarray, rotation: float) -> np.ndarray:
    """Apply a display-matrix rotation (degrees counter-clockwise, PyAV's convention)."""
    quarter = int(round(rotation / 90.0)) % 4
    return np.ascontiguousarray(np.rot90(image, k=quarter)) if quarter else image


def read_video(
    path: str | Path,
    selection: FrameSelection | None = None,
    *,
    on_corrupt: OnCorrupt = "skip",
    max_side: int | None = None,
) -> Frames:
    """Decode the selected frames of a video file.

    Args:
        path: a video file FFmpeg can read (mp4, mov, avi, webm, mkv, ...).
        selection: which frames to keep (default: all).
        on_corrupt: ``"skip"``: frames that fail to decode are left out, with a
            :class:`CorruptFrameWarning` listing their indices; ``"raise"``: raise
            :class:`CorruptFrameError` instead.
        max_side: downscale so that the longer image side is at most this many pixels.
    Returns:
        Frames with (N, H, W, 3) uint8 RGB images in display orientation, times in seconds
        from the first frame and the frames' indices in the video.
    Raises:
        InputNotFoundError: no such file.
        NotAVideoError: not a container FFmpeg opens, or no video stream in it.
        TruncatedVideoError: the file was cut short (its structure or its header says so).
        EmptyVideoError: no frame in the video or in the selected time range, or every
            selected frame is corrupt.
        CorruptFrameError: a selected frame is corrupt and ``on_corrupt="raise"``.
    """
    path = Path(path)
    selection = selection or FrameSelection()
    if on_corrupt not in ("skip", "raise"):
        raise ValueError(f"on_corrupt must be 'skip' or 'raise', got {on_corrupt!r}")
    if not path.exists():
        raise InputNotFoundError(path, "no such file")
    if not path.is_file():
        raise NotAVideoError(path, "not a video (it is not a file)")

    stamps, time_base, read_problem = _packet_times(path)
    if not stamps:
        raise EmptyVideoError(path, read_problem or "the video holds no frame")
    index_of = {ts: i for i, ts in enumerate(stamps)}
    times = (np.asarray(stamps, dtype=np.float64) - stamps[0]) * time_base
    keep = selection.select(times)
    if len(keep) == 0:
        raise EmptyVideoError(
            path,
            f"no frame in the selected time range [{selection.start_s}, {selection.end_s}] s "
            f"(the video spans 0 to {times[-1]:.3f} s)",
        )
    wanted = set(keep.tolist())
    last_wanted = int(keep[-1])

    decoded: dict[int, np.ndarray] = {}
    source_size: tuple[int, int] | None = None
    corrupt: set[int] = set()
    fps: float | None = None
    with _open_video(path) as (container, stream):
        rate = stream.average_rate or stream.guessed_rate
        fps = float(rate) if rate else None
        sequential = 0
        try:
            for packet in container.demux(stream):
                try:
                    frames = packet.decode()
                except av.error.FFmpegError:
                    ts = packet.pts if packet.pts is not None else packet.dts
                    if ts is not None and int(ts) in index_of:
                        corrupt.add(index_of[int(ts)])
                    continue
                for frame in frames:
                    index = index_of.get(int(frame.pts)) if frame.pts is not None else None
                    if index is None:
                        index = sequential
                    sequential = index + 1
                    if index not in wanted:
                        continue
                    if frame.is_corrupt:
                        corrupt.add(index)
                        continue
                    image = _rotate(frame.to_ndarray(format="rgb24"), frame.rotation or 0)
                    if max_side is not None:  # per frame: a long 4K video need not fit in memory
                        if max(image.shape[:2]) > max_side:
                            source_size = (image.shape[1], image.shape[0])
                        image = resize_max_side(image, max_side)
                    decoded[index] = image
                if sequential > last_wanted:
                    break
        except av.error.FFmpegError as exc:  # demuxing failed mid-file: keep what was decoded
            read_problem = read_problem or f"the file could not be read to its end ({exc})"
    missing = sorted((wanted - set(decoded)) | (corrupt & wanted))
    if missing:
        reason = read_problem or "the data of these frames is corrupt"
        if on_corrupt == "raise":
            raise CorruptFrameError(
                path,
                f"{len(missing)} frame(s) could not be decoded: {format_indices(missing)} "
                f"({reason})",
                missing,
            )
        if len(missing) == len(wanted):
            raise EmptyVideoError(path, f"none of the selected frames could be decoded ({reason})")
        warnings.warn(
            f"{path}: skipped {len(missing)} frame(s) that could not be decoded: "
            f"{format_indices(missing)} "
            f"({reason})",
            CorruptFrameWarning,
            stacklevel=2,
        )
    order = sorted(decoded)
    shapes = {decoded[i].shape for i in order}
    if len(shapes) > 1:
        raise InputFormatError(path, f"the frame size changes within the video: {sorted(shapes)}")
    images = np.stack([decoded[i] for i in order])
    if fps is None and len(times) > 1 and times[-1] > 0:
        fps = (len(times) - 1) / times[-1]
    return Frames(
        images=images,
        timestamps=times[order],
        indices=np.asarray(order, dtype=np.int64),
        fps=fps,
        source=str(path),
        source_size=source_size,
    )


def count_video_frames(path: str | Path) -> int:
    """Number of frames in a video's first video stream (packets listed without decoding).

    Raises:
        InputNotFoundError, NotAVideoError.
    """
    path = Path(path)
    if not path.is_file():
        raise InputNotFoundError(path, "no such file")
    stamps, _, _ = _packet_times(path)
    return len(stamps)
