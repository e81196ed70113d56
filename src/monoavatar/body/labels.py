"""Per-vertex labels derived from a rest mesh: regions, mirror pairs, landmark regressors.

Shared by the body-model back-ends; pure NumPy on the canonical (Y-up, +Z-facing) rest mesh.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.optimize import nnls
from scipy.spatial import cKDTree

from monoavatar.body.model import REGIONS


def regions_from_parts(rest: np.ndarray, parts: Sequence[str]) -> np.ndarray:
    """Region index (into :data:`REGIONS`) of every vertex.

    Args:
        rest: (V, 3) rest vertices, canonical frame, metres.
        parts: V names, each a region of REGIONS or ``"head"``; head vertices are split into
            ``face`` (front of the head, ears) and ``hair`` (scalp above the eyebrows and the back
            of the head), the region typically covered by hair.
    Returns:
        (V,) int64.
    """
    names = np.array(parts, dtype=object)
    head = np.flatnonzero(names == "head")
    if len(head):
        pts = rest[head]
        centre = pts.mean(axis=0)
        top = pts[:, 1].max()
        brow = centre[1] + 0.45 * (top - centre[1])  # eyebrows ≈ 45 % from centre to crown
        behind = (pts[:, 2] < centre[2] - 0.02) & (pts[:, 1] > centre[1] - 0.02)
        is_hair = (pts[:, 1] > brow) | behind
        names[head[is_hair]] = "hair"
        names[head[~is_hair]] = "face"
    return np.array([REGIONS.index(str(n)) for n in names], dtype=np.int64)


def mirror_pairs(rest: np.ndarray) -> tuple[np.ndarray, float]:
    """For each vertex, the vertex nearest to its mirror image across the x = 0 plane.

    Returns (V,) indices and the largest mirror mismatch in metres (0 for an exactly
    symmetric mesh)."""
    mirrored = rest * np.array([-1.0, 1.0, 1.0])
    dist, idx = cKDTree(rest).query(mirrored)
    return np.asarray(idx, dtype=np.int64), float(np.max(dist))


def surface_regressor(vertices: np.ndarray, target: np.ndarray, k: int = 12) -> np.ndarray:
    """Dense (V,) non-negative weights summing to 1 over the k vertices nearest to ``target``,
    chosen so that their weighted mean reproduces ``target`` as closely as possible: a
    landmark that rides with the surface under posing and offsets."""
    _, idx = cKDTree(vertices).query(target, k=k)
    A = np.vstack([vertices[idx].T, 100.0 * np.ones((1, k))])
    b = np.concatenate([target, [100.0]])
    w, _ = nnls(A, b)
    dense = np.zeros(len(vertices))
    dense[idx] = w / w.sum()
    return dense
