"""One entry point for every kind of frame source: a video file, an image folder, an image."""

from __future__ import annotations

from pathlib import Path

from monoavatar.core.errors import InputNotFoundError
from monoavatar.io.frames import Frames, FrameSelection
from monoavatar.io.images import IMAGE_EXTENSIONS, read_image, read_image_folder
from monoavatar.io.video import OnCorrupt, read_video


def read_frames(
    path: str | Path,
    selection: FrameSelection | None = None,
    *,
    fps: float | None = None,
    on_corrupt: OnCorrupt = "skip",
    max_side: int | None = None,
) -> Frames:
    """Read frames from a video file, a folder of images, or a single image.

    A folder is read with :func:`read_image_folder` (``fps`` gives it timestamps), a file with
    an image extension (``.png``, ``.jpg``, ...) with :func:`read_image` (``selection`` is then
    ignored), anything else with :func:`read_video` (which raises ``NotAVideoError`` for files
    that are not videos).

    Returns:
        Frames: (N, H, W, 3) uint8 RGB images in display orientation, see :class:`Frames`.
    """
    path = Path(path)
    if not path.exists():
        raise InputNotFoundError(path, "no such file or folder")
    if path.is_dir():
        return read_image_folder(
            path, selection, fps=fps, on_corrupt=on_corrupt, max_side=max_side
        )
    if path.suffix.lower() in IMAGE_EXTENSIONS:
        return read_image(path, max_side=max_side)
    return read_video(path, selection, on_corrupt=on_corrupt, max_side=max_side)
