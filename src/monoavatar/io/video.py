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
    format_indices,
)
from monoavatar.io.frames import Frames, FrameSelection, resize_max_side

VIDEO_EXTENSIONS = (".mp4", ".mov", ".m4v", ".avi", ".webm", ".mkv", ".mpg", ".mpeg", ".wmv")

OnCorrupt = Literal["skip", "raise"]


@contextmanager
def _open_video(path: Path) -> Iterator[tuple[Any, Any]]:
    if path.stat().st_size == 0:
        raise EmptyVideoError(path, "the file is empty (0 bytes)")
    try:
        container = av.open(str(path))
    except av.error.EOFError as exc:
        raise EmptyVideoError(
            path, "the file ends before any frame (an empty or truncated video)"
        ) from exc
    except av.error.FFmpegError as exc:
        raise NotAVideoError(path, f"not a video ({exc.strerror or exc})") from exc
    try:
        if not container.streams.video:
            raise NotAVideoError(path, "not a video (the file has no video stream)")
        yield container, container.streams.video[0]
    finally:
        container.close()


def _packet_times(path: Path) -> tuple[list[int], float, str | None]:
    """Presentation timestamps of all video packets (sorted), the time base, and the error that
    stopped demuxing early (None when the whole file was read)."""
    stamps: list[int] = []
    problem: str | None = None
    with _open_video(path) as (container, stream):
        time_base = float(stream.time_base) if stream.time_base else 1.0
        try:
            for n, packet in enumerate(container.demux(stream)):
                if packet.size == 0:
                    continue
                ts = packet.pts if packet.pts is not None else packet.dts
                stamps.append(int(ts) if ts is not None else n)
        except av.error.FFmpegError as exc:
            problem = f"the file could not be read past frame {len(stamps)} ({exc.strerror or exc})"
    return sorted(set(stamps)), time_base, problem


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
