"""Reading inputs: videos, image folders, single images and camera intrinsics; writing meshes,
glTF avatars and the avatar folder. Data sets with their own perception are read by
:mod:`monoavatar.datasets`.

Entry point: :func:`read_frames` (any frame source → :class:`Frames`), then
:func:`resolve_camera` for the intrinsics.
"""

from monoavatar.core.errors import (
    CorruptFrameError,
    CorruptFrameWarning,
    EmptyVideoError,
    InputError,
    InputFormatError,
    InputNotFoundError,
    InputWarning,
    NotAVideoError,
    TruncatedVideoError,
    UnsafePickleError,
)
from monoavatar.io.frames import Frames, FrameSelection
from monoavatar.io.images import load_image, read_image, read_image_files, read_image_folder
from monoavatar.io.intrinsics import (
    DEFAULT_DIAGONAL_FOV_DEG,
    default_camera,
    default_focal,
    resolve_camera,
)
from monoavatar.io.reader import InputPath, input_label, input_paths, read_frames
from monoavatar.io.video import count_video_frames, read_video

__all__ = [
    "DEFAULT_DIAGONAL_FOV_DEG",
    "CorruptFrameError",
    "CorruptFrameWarning",
    "EmptyVideoError",
    "FrameSelection",
    "Frames",
    "InputError",
    "InputFormatError",
    "InputNotFoundError",
    "InputPath",
    "InputWarning",
    "NotAVideoError",
    "TruncatedVideoError",
    "UnsafePickleError",
    "count_video_frames",
    "default_camera",
    "default_focal",
    "input_label",
    "input_paths",
    "load_image",
    "read_frames",
    "read_image",
    "read_image_files",
    "read_image_folder",
    "read_video",
    "resolve_camera",
]
