"""One entry point for every kind of frame source: a video file, an image folder, an image,
or several image files."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from monoavatar.core.errors import InputNotFoundError
from monoavatar.io.frames import Frames, FrameSelection
from monoavatar.io.images import IMAGE_EXTENSIONS, read_image, read_image_files, read_image_folder
from monoavatar.io.video import OnCorrupt, read_video

InputPath = str | Path | Sequence[str | Path]
"""What the verbs take as INPUT: one path (a video, an image folder, an image) or several image
files."""


def input_paths(path: InputPath) -> list[Path]:
    """``path`` as a list of paths (one for a single path)."""
    if isinstance(path, (str, Path)):
        return [Path(path)]
    return [Path(p) for p in path]


def input_label(path: InputPath) -> str:
    """A short name of the input for messages and reports: the path, or for several files the
    first, the last and how many."""
    paths = input_paths(path)
    if len(paths) == 1:
        return str(paths[0])
    return f"{paths[0]} ... {paths[-1]} ({len(paths)} image files)"


def read_frames(
    path: InputPath,
    selection: FrameSelection | None = None,
    *,
    fps: float | None = None,
    on_corrupt: OnCorrupt = "skip",
    max_side: int | None = None,
) -> Frames:
    """Read frames from a video file, a folder of images, a single image, or several image
    files (a list of paths: :func:`read_image_files`).

    A folder is read with :func:`read_image_folder` (``fps`` gives it timestamps), a file with
    an image extension (``.png``, ``.jpg``, ...) with :func:`read_image` (``selection`` is then
    ignored), anything else with :func:`read_video` (which raises ``NotAVideoError`` for files
    that are not videos).

    Returns:
        Frames: (N, H, W, 3) uint8 RGB images in display orientation, see :class:`Frames`.
    """
    paths = input_paths(path)
    if len(paths) > 1:
        return read_image_files(paths, selection, fps=fps, on_corrupt=on_corrupt,
                                max_side=max_side)  # fmt: skip
    if not paths:
        raise ValueError("read_frames needs an input path")
    single = paths[0]
    if not single.exists():
        raise InputNotFoundError(single, "no such file or folder")
    if single.is_dir():
        return read_image_folder(
            single, selection, fps=fps, on_corrupt=on_corrupt, max_side=max_side
        )
    if single.suffix.lower() in IMAGE_EXTENSIONS:
        return read_image(single, max_side=max_side)
    return read_video(single, selection, on_corrupt=on_corrupt, max_side=max_side)
