"""The ``Frames`` result of every reader, and frame selection.

Conventions: images are RGB ``uint8`` arrays ``(N, H, W, 3)`` in display orientation (rotation
metadata and EXIF orientation already applied); pixel coordinates have their origin at the
top-left corner of the top-left pixel (DESIGN.md); times are seconds from the first frame of
the source.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np


@dataclass(frozen=True)
class FrameSelection:
    """Which frames of a source to keep.

    The index range and the time range are applied first, then either ``step`` or
    ``num_keyframes``.

    Attributes:
        step: keep every ``step``-th frame of the range (1 keeps all).
        num_keyframes: keep this many frames spread evenly over the range, first and last
            included (all frames when the range has fewer). Exclusive with ``step > 1``.
        first: first source frame to keep (0-based index, inclusive; None: the first).
        stop: source frame index to stop before (exclusive; None: to the end).
        start_s: first time to keep, seconds from the source's first frame (inclusive).
        end_s: last time to keep, seconds (inclusive). ``None``: to the end.
    """

    step: int = 1
    num_keyframes: int | None = None
    start_s: float | None = None
    end_s: float | None = None
    first: int | None = None
    stop: int | None = None

    def __post_init__(self) -> None:
        if int(self.step) != self.step or self.step < 1:
            raise ValueError(f"FrameSelection.step must be an integer >= 1, got {self.step!r}")
        if self.num_keyframes is not None:
            if int(self.num_keyframes) != self.num_keyframes or self.num_keyframes < 1:
                raise ValueError(
                    f"FrameSelection.num_keyframes must be an integer >= 1, "
                    f"got {self.num_keyframes!r}"
                )
            if self.step != 1:
                raise ValueError(
                    "FrameSelection: give either step or num_keyframes, not both "
                    f"(step={self.step}, num_keyframes={self.num_keyframes})"
                )
        for name in ("start_s", "end_s"):
            value = getattr(self, name)
            if value is not None and (not math.isfinite(value) or value < 0):
                raise ValueError(f"FrameSelection.{name} must be finite and >= 0, got {value!r}")
        for name in ("first", "stop"):
            value = getattr(self, name)
            if value is not None and (int(value) != value or value < 0):
                raise ValueError(f"FrameSelection.{name} must be an integer >= 0, got {value!r}")
        if self.first is not None and self.stop is not None and self.stop <= self.first:
            raise ValueError(f"FrameSelection: stop ({self.stop}) must be after first "
                             f"({self.first})")  # fmt: skip
        if self.start_s is not None and self.end_s is not None and self.end_s < self.start_s:
            raise ValueError(
                f"FrameSelection: end_s ({self.end_s}) is before start_s ({self.start_s})"
            )

    @property
    def uses_time(self) -> bool:
        """Whether a time range is set."""
        return self.start_s is not None or self.end_s is not None

    def select(self, times: np.ndarray) -> np.ndarray:
        """Positions to keep among source frames with the given times.

        Args:
            times: (M,) time of each source frame in seconds, increasing. NaN times are
                accepted only when no time range is set.
        Returns:
            (K,) int64 positions into ``times``, increasing.
        """
        times = np.asarray(times, dtype=np.float64)
        candidates = np.arange(len(times), dtype=np.int64)[self.first : self.stop]
        if self.uses_time:
            lo = -np.inf if self.start_s is None else self.start_s - 1e-9
            hi = np.inf if self.end_s is None else self.end_s + 1e-9
            candidates = candidates[(times[candidates] >= lo) & (times[candidates] <= hi)]
        if self.num_keyframes is not None:
            if len(candidates) > self.num_keyframes:
                pick = np.round(np.linspace(0, len(candidates) - 1, self.num_keyframes))
                candidates = candidates[pick.astype(np.int64)]
            return candidates
        return candidates[:: self.step]


@dataclass(frozen=True)
class Frames:
    """Decoded frames of a video, an image folder or a single image.

    Attributes:
        images: (N, H, W, 3) uint8 RGB, display orientation.
        timestamps: (N,) float64 seconds from the source's first frame; NaN when the source
            has no timing (image folders read without ``fps``, single images).
        indices: (N,) int64 index of each frame in the source (0-based, presentation order,
            counted before selection), e.g. ``[0, 5, 10]`` for ``step=5``.
        fps: frame rate of the source in frames per second; ``None`` when unknown.
        source: where the frames came from (a path, or a short description).
        source_size: (width, height) of the source's frames when they were downscaled on
            reading (``max_side``); None when the images are the source's size.
    """

    images: np.ndarray
    timestamps: np.ndarray
    indices: np.ndarray
    fps: float | None = None
    source: str = "<array>"
    source_size: tuple[int, int] | None = None

    @property
    def scale(self) -> float:
        """These images' pixels per source pixel (below 1 when downscaled on reading)."""
        if self.source_size is None:
            return 1.0
        return float(self.images.shape[2]) / float(self.source_size[0])

    def __post_init__(self) -> None:
        images = np.asarray(self.images)
        if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
            raise ValueError(
                f"Frames.images must be (N, H, W, 3) uint8 RGB, got shape {images.shape} "
                f"dtype {images.dtype}"
            )
        n = images.shape[0]
        timestamps = np.asarray(self.timestamps, dtype=np.float64).reshape(-1)
        indices = np.asarray(self.indices, dtype=np.int64).reshape(-1)
        if timestamps.shape != (n,) or indices.shape != (n,):
            raise ValueError(
                f"Frames: {n} images but {timestamps.shape[0]} timestamps and "
                f"{indices.shape[0]} indices"
            )
        if n > 1 and np.any(np.diff(indices) <= 0):
            raise ValueError("Frames.indices must be strictly increasing")
        if self.fps is not None and not (math.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"Frames.fps must be positive or None, got {self.fps!r}")
        object.__setattr__(self, "images", images)
        object.__setattr__(self, "timestamps", timestamps)
        object.__setattr__(self, "indices", indices)

    # -- construction -------------------------------------------------------------------
    @staticmethod
    def from_images(
        images: np.ndarray | list[np.ndarray], fps: float | None = None, source: str = "<array>"
    ) -> Frames:
        """Frames from in-memory RGB images: (N, H, W, 3) or a list of (H, W, 3) uint8.

        A single (H, W, 3) image becomes one frame. Indices are ``0..N-1``; timestamps are
        ``index / fps`` (NaN without ``fps``).
        """
        array = np.asarray(images)
        if array.ndim == 3:
            array = array[None]
        n = array.shape[0] if array.ndim == 4 else 0
        idx = np.arange(n, dtype=np.int64)
        times = idx / fps if fps else np.full(n, np.nan)
        return Frames(images=array, timestamps=times, indices=idx, fps=fps, source=source)

    # -- properties ---------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.images.shape[0])

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return int(self.images.shape[1])

    @property
    def width(self) -> int:
        """Image width in pixels."""
        return int(self.images.shape[2])

    @cached_property
    def digest(self) -> str:
        """A content hash (hex) of the images and their source indices; used as a cache key."""
        h = hashlib.blake2b(digest_size=20)
        h.update(repr(self.images.shape).encode())
        h.update(np.ascontiguousarray(self.indices).tobytes())
        h.update(np.ascontiguousarray(self.images).data)
        return h.hexdigest()

    # -- transforms ---------------------------------------------------------------------
    def subset(self, positions: np.ndarray | list[int]) -> Frames:
        """The frames at the given positions (0..N-1, increasing)."""
        pos = np.asarray(positions, dtype=np.int64)
        return Frames(
            images=self.images[pos],
            timestamps=self.timestamps[pos],
            indices=self.indices[pos],
            fps=self.fps,
            source=self.source,
            source_size=self.source_size,
        )

    def resized(self, max_side: int) -> Frames:
        """Frames downscaled (area interpolation) so that the longer side is ``max_side``.

        Returns ``self`` when the images are already small enough. Scale a camera for the
        new size with ``PinholeCamera.scaled(new_width / old_width)``.
        """
        if max(self.height, self.width) <= max_side:
            return self
        return Frames(
            images=resize_max_side(self.images, max_side),
            timestamps=self.timestamps,
            indices=self.indices,
            fps=self.fps,
            source=self.source,
            source_size=self.source_size or (self.width, self.height),
        )


def resize_max_side(images: np.ndarray, max_side: int) -> np.ndarray:
    """Downscale (N, H, W, C) or (H, W, C) images so the longer side is at most ``max_side``."""
    if max_side < 1:
        raise ValueError(f"max_side must be >= 1, got {max_side}")
    single = images.ndim == 3
    batch = images[None] if single else images
    h, w = batch.shape[1:3]
    if max(h, w) <= max_side:
        return images
    scale = max_side / max(h, w)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    out = np.stack([cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in batch])
    return out[0] if single else out
