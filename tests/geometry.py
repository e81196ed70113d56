"""Brute-force geometric references for tests (independent of the code under test)."""

from __future__ import annotations

import numpy as np


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Exact distance of every point (N, 3) to the nearest of all triangles (F, 3, 3), by
    brute force over all pairs (Ericson, Real-Time Collision Detection, 5.1.5). (N,)."""
    out = np.empty(len(points))
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    ab, ac = b - a, c - a
    for i, p in enumerate(points):
        ap, bp, cp = p - a, p - b, p - c
        d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
        d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
        d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
        va = d3 * d6 - d5 * d4
        vb = d5 * d2 - d1 * d6
        vc = d1 * d4 - d3 * d2
        denom = va + vb + vc
        with np.errstate(divide="ignore", invalid="ignore"):
            v = vb / denom
            w = vc / denom
        q = a + ab * v[:, None] + ac * w[:, None]  # interior
        # regions, later assignments take precedence in reverse order of the algorithm
        cond_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        t_bc = np.clip((d4 - d3) / np.where(cond_bc, (d4 - d3) + (d5 - d6), 1), 0, 1)
        q = np.where(cond_bc[:, None], b + t_bc[:, None] * (c - b), q)
        cond_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        t_ac = np.clip(d2 / np.where(cond_ac, d2 - d6, 1), 0, 1)
        q = np.where(cond_ac[:, None], a + t_ac[:, None] * ac, q)
        cond_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        t_ab = np.clip(d1 / np.where(cond_ab, d1 - d3, 1), 0, 1)
        q = np.where(cond_ab[:, None], a + t_ab[:, None] * ab, q)
        q = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, q)
        q = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, q)
        q = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, q)
        out[i] = np.sqrt(((q - p) ** 2).sum(1).min())
    return out
