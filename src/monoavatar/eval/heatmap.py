"""Per-vertex error heat maps, like the dissertation's Fig. B.6 (blue 0 mm, red ≥ 2 cm).

Errors are in metres. The colour ramp is piecewise linear through five stops:
blue (0) → cyan (¼ max) → green (½ max) → yellow (¾ max) → red (≥ max), default max 20 mm.
"""

from __future__ import annotations

import os

import numpy as np
from numpy.typing import ArrayLike

from monoavatar.eval._checks import FloatArray, as_faces, as_points

__all__ = ["DEFAULT_MAX_ERROR", "NAN_COLOR", "error_to_rgb", "write_heatmap_ply"]

DEFAULT_MAX_ERROR = 0.02
"""Error (metres) mapped to full red, as in Fig. B.6."""

NAN_COLOR = (0.5, 0.5, 0.5)
"""RGB given to vertices whose error is NaN (not measured)."""

_STOPS = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
_COLORS = np.array(
    [
        [0.0, 0.0, 1.0],  # blue
        [0.0, 1.0, 1.0],  # cyan
        [0.0, 1.0, 0.0],  # green
        [1.0, 1.0, 0.0],  # yellow
        [1.0, 0.0, 0.0],  # red
    ]
)


def error_to_rgb(errors: ArrayLike, max_error: float = DEFAULT_MAX_ERROR) -> FloatArray:
    """Map per-vertex errors to heat-map colours.

    Args:
        errors: (V,) non-negative errors in metres (NaN allowed: coloured :data:`NAN_COLOR`).
        max_error: error in metres shown as full red; larger errors are clipped to red.

    Returns:
        (V, 3) float64 RGB in [0, 1] (multiply by 255 and round for 8-bit colours).

    Raises:
        ValueError: if ``errors`` is not 1-D, has a negative or infinite value, or
            ``max_error <= 0``.
    """
    e = np.asarray(errors, dtype=np.float64)
    if e.ndim != 1:
        raise ValueError(f"errors: expected shape (V,), got {e.shape}")
    if not max_error > 0:
        raise ValueError(f"max_error: expected > 0 metres, got {max_error}")
    nan = np.isnan(e)
    if np.any(np.isinf(e)) or np.any(e[~nan] < 0):
        raise ValueError("errors: expected non-negative finite values (or NaN)")
    t = np.clip(np.where(nan, 0.0, e) / max_error, 0.0, 1.0)
    rgb = np.stack([np.interp(t, _STOPS, _COLORS[:, k]) for k in range(3)], axis=1)
    rgb[nan] = NAN_COLOR
    return rgb


def write_heatmap_ply(
    path: str | os.PathLike[str],
    vertices: ArrayLike,
    faces: ArrayLike,
    errors: ArrayLike,
    max_error: float = DEFAULT_MAX_ERROR,
) -> FloatArray:
    """Write a binary little-endian PLY mesh whose vertex colours show per-vertex errors.

    Vertex positions are written as float32 (metres), colours as 8-bit ``red green blue``,
    triangles as ``vertex_indices`` lists; any PLY viewer (MeshLab, Blender) shows the colours.

    Args:
        path: output file path (``.ply``).
        vertices: (V, 3) vertices, metres.
        faces: (F, 3) triangles (vertex indices).
        errors: (V,) per-vertex errors, metres (see :func:`error_to_rgb`).
        max_error: error in metres shown as full red.

    Returns:
        (V, 3) float64 RGB in [0, 1], the colours written.
    """
    v = as_points("vertices", vertices, min_count=1)
    f = as_faces("faces", faces, v.shape[0])
    e = np.asarray(errors, dtype=np.float64)
    if e.shape != (v.shape[0],):
        raise ValueError(f"errors: expected shape ({v.shape[0]},), got {e.shape}")
    rgb = error_to_rgb(e, max_error)

    vertex_records = np.empty(
        v.shape[0],
        dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")],
    )
    vertex_records["x"], vertex_records["y"], vertex_records["z"] = v.T.astype(np.float32)
    rgb8 = np.round(rgb * 255.0).astype(np.uint8)
    vertex_records["r"], vertex_records["g"], vertex_records["b"] = rgb8.T
    face_records = np.empty(f.shape[0], dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face_records["n"] = 3
    face_records["i"] = f.astype(np.int32)

    header = (
        "ply\n"
        "format binary_little_endian 1.0\n"
        "comment monoavatar per-vertex error heat map, "
        f"blue = 0 m, red >= {max_error:g} m\n"
        f"element vertex {v.shape[0]}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        f"element face {f.shape[0]}\n"
        "property list uchar int vertex_indices\n"
        "end_header\n"
    )
    with open(path, "wb") as handle:
        handle.write(header.encode("ascii"))
        handle.write(vertex_records.tobytes())
        handle.write(face_records.tobytes())
    return rgb
