"""Plane sections and vertical hits of a triangle mesh, and the convex-hull girth of a section:
the geometry under every body measurement. Pure NumPy/SciPy on (V, 3) vertices in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

__all__ = ["Section", "girth", "plane_basis", "plane_section", "vertical_hits"]


@dataclass(frozen=True)
class Section:
    """The segments where a plane cuts a mesh.

    Attributes:
        segments: (S, 2, 3) segment end points, metres, in the mesh's frame.
        faces: (S,) index of the triangle each segment crosses.
        origin: (3,) a point of the plane; ``normal`` (3,) its unit normal.
    """

    segments: np.ndarray
    faces: np.ndarray
    origin: np.ndarray
    normal: np.ndarray

    def keep(self, mask: np.ndarray) -> Section:
        """The segments of the faces where ``mask`` (F,) bool, the mesh's faces, is set."""
        sel = mask[self.faces]
        return Section(self.segments[sel], self.faces[sel], self.origin, self.normal)

    def points(self) -> np.ndarray:
        """(2S, 3) all segment end points."""
        return self.segments.reshape(-1, 3)


def plane_basis(normal: np.ndarray) -> np.ndarray:
    """(2, 3) two orthonormal vectors spanning the plane of unit ``normal`` (3,)."""
    n = normal / np.linalg.norm(normal)
    helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(n, u)])


def plane_section(vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray,
                  normal: np.ndarray) -> Section:  # fmt: skip
    """Cut the mesh (V, 3) / (F, 3) by the plane through ``origin`` (3,) with ``normal`` (3,).

    A vertex exactly on the plane counts as being on its positive side, so each crossed
    triangle gives exactly one segment (its two edges whose ends lie on opposite sides)."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    d = (np.asarray(vertices, float) - origin) @ n  # (V,) signed distances
    side = d[faces] >= 0  # (F, 3)
    count = side.sum(axis=1)
    crossed = np.flatnonzero((count == 1) | (count == 2))
    if len(crossed) == 0:
        return Section(np.zeros((0, 2, 3)), np.zeros(0, np.int64), np.asarray(origin, float), n)
    tri = faces[crossed]
    s = side[crossed]
    # the vertex alone on its side: its two edges are the crossed ones
    lone = np.where(count[crossed] == 1, np.argmax(s, axis=1), np.argmin(s, axis=1))
    rows = np.arange(len(crossed))
    a = tri[rows, lone]
    b = tri[rows, (lone + 1) % 3]
    c = tri[rows, (lone + 2) % 3]

    def cut(i: np.ndarray, j: np.ndarray) -> np.ndarray:
        t = d[i] / (d[i] - d[j])  # d[i] and d[j] have opposite signs (or d[i] = 0)
        return vertices[i] + t[:, None] * (vertices[j] - vertices[i])

    segments = np.stack([cut(a, b), cut(a, c)], axis=1)
    return Section(segments, crossed.astype(np.int64), np.asarray(origin, float), n)


def girth(section: Section) -> tuple[float, np.ndarray]:
    """The length of the convex hull of a section in its plane (a tape measure drawn around
    it), metres, and the hull's corners (H, 3) in order, for drawing. 0 and an empty array when
    the section has fewer than three distinct points."""
    pts = section.points()
    if len(pts) < 3:
        return 0.0, np.zeros((0, 3))
    basis = plane_basis(section.normal)
    flat = (pts - section.origin) @ basis.T  # (P, 2)
    try:
        hull = ConvexHull(flat)
    except QhullError:  # all points on one line
        return 0.0, np.zeros((0, 3))
    corners = flat[hull.vertices]  # counter-clockwise in 2-D
    closed = np.vstack([corners, corners[:1]])
    length = float(np.linalg.norm(np.diff(closed, axis=0), axis=1).sum())
    return length, section.origin + corners @ basis


def vertical_hits(vertices: np.ndarray, faces: np.ndarray, x: float, z: float) -> np.ndarray:
    """Heights (K,) sorted and distinct, where the vertical line (x, ·, z) of a Y-up mesh
    crosses its triangles (barycentric test in the XZ plane, edges included)."""
    tri = vertices[faces]  # (F, 3, 3)
    p = np.array([x, z])
    a, b, c = tri[:, 0, [0, 2]], tri[:, 1, [0, 2]], tri[:, 2, [0, 2]]
    v0, v1, v2 = b - a, c - a, p - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    ok = np.abs(den) > 1e-15
    den = np.where(ok, den, 1.0)
    u = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
    w = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
    eps = 1e-9  # a line along an edge (a symmetric mesh's seam) meets both of its triangles
    inside = ok & (u >= -eps) & (w >= -eps) & (u + w <= 1 + eps)
    y = np.sort(tri[inside, 0, 1] + u[inside] * (tri[inside, 1, 1] - tri[inside, 0, 1])
                + w[inside] * (tri[inside, 2, 1] - tri[inside, 0, 1]))  # fmt: skip
    return y[np.concatenate([[True], np.diff(y) > 1e-7])] if len(y) else y
