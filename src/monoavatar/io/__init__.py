"""Reading inputs: videos, image folders, single images, camera intrinsics, and precomputed
perception from People-Snapshot folders and OpenPose JSON.

Entry point: :func:`read_frames` (any frame source → :class:`Frames`), then
:func:`resolve_camera` for the intrinsics.
"""

from monoavatar.io.errors import (
    CorruptFrameError,
    CorruptFrameWarning,
    EmptyVideoError,
    InputError,
    InputFormatError,
    InputNotFoundError,
    InputWarning,
    NotAVideoError,
    UnsafePickleError,
)
from monoavatar.io.frames import Frames, FrameSelection
from monoavatar.io.images import load_image, read_image, read_image_folder
from monoavatar.io.intrinsics import (
    DEFAULT_DIAGONAL_FOV_DEG,
    default_camera,
    default_focal,
    resolve_camera,
)
from monoavatar.io.openpose import read_openpose_folder
from monoavatar.io.people_snapshot import (
    PeopleSnapshot,
    is_people_snapshot,
    read_people_snapshot,
)
from monoavatar.io.reader import read_frames
from monoavatar.io.safe_pickle import safe_load
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
    "InputWarning",
    "NotAVideoError",
    "PeopleSnapshot",
    "UnsafePickleError",
    "count_video_frames",
    "default_camera",
    "default_focal",
    "is_people_snapshot",
    "load_image",
    "read_frames",
    "read_image",
    "read_image_folder",
    "read_openpose_folder",
    "read_people_snapshot",
    "read_video",
    "resolve_camera",
    "safe_load",
]
