"""Input validation shared by the metric modules (private to ``monoavatar.eval``).

Every public metric converts and checks its arguments here, so that a wrong shape or a
non-finite value is reported with the argument's name, the expected and the actual value,
instead of failing deep inside a matrix product.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


def as_points(name: str, value: ArrayLike, *, min_count: int = 0) -> FloatArray:
    """Return ``value`` as a finite float64 array of shape ``(N, 3)``.

    Raises:
        ValueError: if the shape is not ``(N, 3)``, ``N < min_count``, or a value is not finite.
    """
    points = np.asarray(value, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3), got {points.shape}")
    if points.shape[0] < min_count:
        raise ValueError(f"{name}: expected at least {min_count} points, got {points.shape[0]}")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{name}: contains {int(np.sum(~np.isfinite(points)))} non-finite values")
    return points


def as_faces(name: str, value: ArrayLike, n_vertices: int) -> IntArray:
    """Return ``value`` as an int64 triangle index array of shape ``(F, 3)``, ``F >= 1``.

    Raises:
        ValueError: if the shape is wrong, there is no face, or an index is outside
            ``[0, n_vertices)``.
        TypeError: if the indices are not integers.
    """
    faces = np.asarray(value)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (F, 3), got {faces.shape}")
    if faces.shape[0] == 0:
        raise ValueError(f"{name}: expected at least 1 triangle, got 0")
    if not np.issubdtype(faces.dtype, np.integer):
        raise TypeError(f"{name}: expected integer vertex indices, got dtype {faces.dtype}")
    faces = faces.astype(np.int64, copy=False)
    low, high = int(faces.min()), int(faces.max())
    if low < 0 or high >= n_vertices:
        raise ValueError(
            f"{name}: vertex indices must lie in [0, {n_vertices}), got range [{low}, {high}]"
        )
    return faces
