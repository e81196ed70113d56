"""Reading single images and folders of images (through Pillow).

EXIF orientation is applied (the analogue of a video's rotation metadata), greyscale, palette
and RGBA images are converted to RGB (alpha is dropped). A folder's images are taken in natural
sort order (``frame2.png`` before ``frame10.png``) and must all have the same size.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from monoavatar.core.errors import (
    CorruptFrameError,
    CorruptFrameWarning,
    EmptyVideoError,
    InputFormatError,
    InputNotFoundError,
)
from monoavatar.io.frames import Frames, FrameSelection, resize_max_side
from monoavatar.io.video import OnCorrupt

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


def natural_sort_key(path: Path) -> list[object]:
    """Sort key ordering ``frame2.png`` before ``frame10.png``."""
    return [int(tok) if tok.isdigit() else tok.lower() for tok in re.split(r"(\d+)", path.name)]


def list_images(folder: str | Path) -> list[Path]:
    """Image files (by extension) directly inside ``folder``, in natural sort order."""
    folder = Path(folder)
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS]
    return sorted(files, key=natural_sort_key)


def load_image(path: str | Path) -> np.ndarray:
    """One image as (H, W, 3) uint8 RGB in display orientation (EXIF orientation applied).

    Raises:
        InputNotFoundError: no such file.
        InputFormatError: the file is not an image Pillow can decode, or is truncated.
    """
    path = Path(path)
    if not path.is_file():
        raise InputNotFoundError(path, "no such image file")
    try:
        with Image.open(path) as opened:
            opened.load()
            im = ImageOps.exif_transpose(opened)
            if im.mode.startswith("I") or im.mode == "F":  # 16/32-bit greyscale
                grey = np.clip(np.asarray(im, dtype=np.float64) / 257.0, 0, 255).astype(np.uint8)
                return np.repeat(grey[..., None], 3, axis=2)
            rgb = im.convert("RGB")
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        raise InputFormatError(path, f"not a readable image ({exc})") from exc
    return np.asarray(rgb, dtype=np.uint8)


def read_image(path: str | Path, *, max_side: int | None = None) -> Frames:
    """A single image as one frame (index 0, NaN timestamp, unknown fps)."""
    image = load_image(path)
    source_size = None
    if max_side is not None and max(image.shape[:2]) > max_side:
        source_size = (image.shape[1], image.shape[0])
        image = resize_max_side(image, max_side)
    return Frames(
        images=image[None], timestamps=np.full(1, np.nan), indices=np.zeros(1, np.int64),
        fps=None, source=str(path), source_size=source_size,
    )


def read_image_folder(
    folder: str | Path,
    selection: FrameSelection | None = None,
    *,
    fps: float | None = None,
    on_corrupt: OnCorrupt = "skip",
    max_side: int | None = None,
) -> Frames:
    """The images of a folder as frames, in natural sort order.

    Args:
        folder: a folder holding image files (other files are ignored).
        selection: which frames to keep; a time range needs ``fps``.
        fps: the frame rate the images were taken at; gives timestamps ``index / fps``
            (NaN without it).
        on_corrupt: ``"skip"`` unreadable images with a :class:`CorruptFrameWarning`, or
            ``"raise"`` :class:`CorruptFrameError`.
        max_side: downscale so that the longer side is at most this many pixels.
    Returns:
        Frames whose ``indices`` are positions in the sorted file list.
    Raises:
        InputNotFoundError, EmptyVideoError (no image in the folder), InputFormatError (images
        of different sizes), CorruptFrameError.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputNotFoundError(folder, "no such folder")
    files = list_images(folder)
    if not files:
        hint = (
            "; it looks like a People-Snapshot folder: read it with read_people_snapshot"
            if (folder / "masks.hdf5").is_file()
            else ""
        )
        raise EmptyVideoError(
            folder,
            f"the folder holds no image (looked for {', '.join(IMAGE_EXTENSIONS)}){hint}",
        )
    return _read_images(files, folder, selection, fps=fps, on_corrupt=on_corrupt,
                        max_side=max_side)  # fmt: skip


def read_image_files(
    files: Sequence[str | Path],
    selection: FrameSelection | None = None,
    *,
    fps: float | None = None,
    on_corrupt: OnCorrupt = "skip",
    max_side: int | None = None,
) -> Frames:
    """Several image files as frames, taken in natural sort order of their names as a folder's
    images are (``img2.jpg`` before ``img10.jpg``, whatever order a shell glob gave); the
    arguments and errors are those of :func:`read_image_folder`, and an input that is not an
    image file (by extension) raises InputFormatError.

    Returns:
        Frames whose ``indices`` are positions in the sorted file list.
    """
    paths = [Path(f) for f in files]
    if not paths:
        raise ValueError("read_image_files needs at least one file")
    for path in paths:
        if not path.exists():
            raise InputNotFoundError(path, "no such image file")
        if not path.is_file() or path.suffix.lower() not in IMAGE_EXTENSIONS:
            kinds = ", ".join(IMAGE_EXTENSIONS)
            raise InputFormatError(path, f"several inputs must all be image files ({kinds}); "
                                   "give a video or a folder alone")  # fmt: skip
    if len({p.resolve() for p in paths}) < len(paths):
        raise InputFormatError(paths[0], "the same image file is given twice")
    paths.sort(key=natural_sort_key)
    return _read_images(paths, paths[0].parent, selection, fps=fps, on_corrupt=on_corrupt,
                        max_side=max_side)  # fmt: skip


def _read_images(
    files: list[Path],
    folder: Path,
    selection: FrameSelection | None,
    *,
    fps: float | None,
    on_corrupt: OnCorrupt,
    max_side: int | None,
) -> Frames:
    """``files`` (sorted, not empty) read as frames; ``folder`` names the source in errors."""
    selection = selection or FrameSelection()
    if selection.uses_time and fps is None:
        raise ValueError(f"{folder}: a time range needs the folder's fps")
    times = np.arange(len(files)) / fps if fps else np.full(len(files), np.nan)
    keep = selection.select(times)
    if len(keep) == 0:
        raise EmptyVideoError(folder, "no image in the selected time range")
    images: list[np.ndarray] = []
    kept: list[int] = []
    bad: list[tuple[int, str]] = []
    first_size: tuple[int, int] | None = None  # (width, height) of the first image read
    for i in keep.tolist():
        try:
            image = load_image(files[i])
        except InputFormatError as exc:
            bad.append((i, f"{files[i].name}: {exc.problem}"))
            continue
        size = (image.shape[1], image.shape[0])
        if first_size is not None and size != first_size:
            raise InputFormatError(
                files[i],
                f"image size {size[0]}x{size[1]} differs from the first "
                f"image {files[kept[0]].name} ({first_size[0]}x{first_size[1]})",
            )
        first_size = size
        if max_side is not None:  # per image: a folder of large photos need not fit in memory
            image = resize_max_side(image, max_side)
        images.append(image)
        kept.append(i)
    if bad:
        listing = "; ".join(msg for _, msg in bad)
        indices = [i for i, _ in bad]
        if on_corrupt == "raise":
            raise CorruptFrameError(folder, f"unreadable image(s) {indices}: {listing}", indices)
        if not images:
            raise EmptyVideoError(folder, f"no selected image could be read: {listing}")
        warnings.warn(
            f"{folder}: skipped unreadable image(s) {indices}: {listing}",
            CorruptFrameWarning,
            stacklevel=2,
        )
    stack = np.stack(images)
    assert first_size is not None
    return Frames(
        images=stack,
        timestamps=times[kept],
        indices=np.asarray(kept, dtype=np.int64),
        fps=fps,
        source=str(folder),
        source_size=first_size if stack.shape[2] != first_size[0] else None,
    )
