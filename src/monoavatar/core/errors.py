"""The error hierarchy: every error monoavatar raises for a user's input or settings is a
:class:`MonoavatarError`, which the CLI turns into a one-line message and exit code 2.

Input errors (:class:`InputError` and below) name the file they are about (``path``) and say
what is wrong with it, so that a message reads e.g.
``clip.mp4: not a video (Invalid data found when processing input)``.
Readers raise before they return anything: a reader never hands back a partial result after
an error, and nothing is written to disk by a reader.
"""

from __future__ import annotations

from pathlib import Path


class MonoavatarError(Exception):
    """An error with a message for the user: bad input, bad settings, or a stage that cannot go
    on with what it was given. Each stage's error class derives from it (and from the built-in
    class that describes it, e.g. ``ValueError``)."""


class InputError(MonoavatarError, ValueError):
    """An input file or folder cannot be used.

    Attributes:
        path: the offending file or folder.
        problem: what is wrong, in words.
    """

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class InputNotFoundError(InputError, FileNotFoundError):
    """The input file or folder does not exist."""


class NotAVideoError(InputError):
    """The file cannot be opened as a video (not a container FFmpeg knows, or no video stream)."""


class EmptyVideoError(InputError):
    """The video (or image folder, or the selected time range) holds no decodable frame."""


class TruncatedVideoError(InputError):
    """The video file is cut short (an interrupted copy, download or recording): its own
    structure says it should be longer."""


class CorruptFrameError(InputError):
    """A frame could not be decoded (raised only when corrupt frames are not to be skipped).

    Attributes:
        frames: source indices of the frames that failed to decode.
    """

    def __init__(self, path: str | Path, problem: str, frames: list[int]) -> None:
        self.frames = list(frames)
        super().__init__(path, problem)


class InputFormatError(InputError):
    """A structured input (People-Snapshot files, OpenPose JSON, an image) is malformed."""


class UnsafePickleError(InputFormatError):
    """A pickle file asks to construct an object outside the small allowed set."""


class InputWarning(UserWarning):
    """Something about an input is suspicious but usable; the message says what."""


class CorruptFrameWarning(InputWarning):
    """Frames that could not be decoded were skipped; the message lists their indices."""


def format_indices(indices: list[int], limit: int = 50) -> str:
    """``[1, 5, 9]``, or the first ``limit`` indices and how many more."""
    if len(indices) <= limit:
        return str(list(indices))
    return f"{list(indices[:limit])} and {len(indices) - limit} more"
