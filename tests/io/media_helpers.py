"""Helpers that write small media files in the formats the readers accept."""

from __future__ import annotations

import struct
from pathlib import Path

import av
import numpy as np

LEVEL = 20  # frame k is filled with grey level LEVEL * k (decodable despite compression)


def frame_image(k: int, width: int, height: int) -> np.ndarray:
    """Frame k: uniform grey LEVEL*k, with a white top-left quadrant (an orientation marker)."""
    img = np.full((height, width, 3), (LEVEL * k) % 200, dtype=np.uint8)
    img[: height // 2, : width // 2] = 255
    return img


def frame_number(image: np.ndarray) -> int:
    """Inverse of :func:`frame_image` (reads the bottom-right quadrant of the coded frame)."""
    h, w = image.shape[:2]
    return round(float(image[h // 2 + 4 :, w // 2 + 4 :].mean()) / LEVEL)


def write_video(
    path: Path,
    n: int = 10,
    width: int = 64,
    height: int = 48,
    fps: int = 25,
    codec: str = "libx264",
    rotation: int | None = None,
    faststart: bool = False,
) -> Path:
    """Encode frames ``frame_image(0..n-1)`` with PyAV; ``rotation`` sets the display matrix
    (degrees counter-clockwise, PyAV's convention); ``faststart`` writes the index (moov box)
    before the data, as streaming-friendly mp4s have it."""
    options = {"movflags": "faststart"} if faststart else {}
    container = av.open(str(path), "w", options=options)
    stream = container.add_stream(codec, rate=fps)
    stream.width, stream.height = width, height
    stream.pix_fmt = "yuv420p"
    if codec == "libx264":
        stream.options = {"crf": "10", "threads": "1"}
    if rotation is not None:
        stream.set_display_rotation(rotation)
    for k in range(n):
        frame = av.VideoFrame.from_ndarray(frame_image(k, width, height), format="rgb24")
        for packet in stream.encode(frame):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
    container.close()
    return path


def set_mp4_matrix(path: Path, matrix: tuple[int, ...]) -> None:
    """Overwrite the display matrix of an mp4's first track header ('tkhd' box, version 0),
    as another muxer (a phone) would have written it."""
    data = bytearray(path.read_bytes())
    k = data.index(b"tkhd")
    assert data[k + 4] == 0, "expected a version-0 tkhd box"
    offset = k + 4 + 4 + 5 * 4 + 8 + 4 * 2
    data[offset : offset + 36] = struct.pack(">9I", *matrix)
    path.write_bytes(bytes(data))
