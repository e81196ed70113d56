"""Surface distances between triangle meshes, and the dissertation's surface-error metric.

The dissertation measures reconstruction accuracy as the **bi-directional vertex-to-surface
distance** between the reconstruction and the ground-truth geometry (Paper B, Sec. B.4.1 and
Tab. B.1; Paper D, Sec. D.4.2; Paper E, Sec. E.8.3), after adjusting pose and scale of the
reconstruction to the ground truth (B.6.2, E.8.3): every vertex of one mesh is measured to the
closest point of the other mesh's *surface* (not to its closest vertex), in both directions.
:func:`bidirectional_surface_error` implements the measurement;
:func:`monoavatar.eval.icp.surface_error_after_alignment` the full protocol (similarity
alignment by ICP, then the measurement).

All coordinates and distances are in metres. Distances are exact point-to-triangle distances
(closest point on a triangle, Ericson, "Real-Time Collision Detection", Sec. 5.1.5, in the
plane-projection / boundary-segment form), found with an exact KD-tree candidate search.

This module depends on numpy and scipy only, and deliberately on nothing else in monoavatar, so
that a bug in the reconstruction code cannot hide in a helper shared with its own evaluation.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from monoavatar.eval._checks import FloatArray, IntArray, as_faces, as_points

__all__ = [
    "ClosestPoints",
    "SurfaceError",
    "bidirectional_surface_error",
    "closest_points_on_mesh",
    "point_to_surface_distance",
]

# Pairs (point, candidate triangle) evaluated at once; bounds memory to a few hundred MB.
_PAIR_CHUNK = 200_000
# Nearest triangle centroids per point and bin taken in one array query; points with more
# candidates than that fall back to a ball query.
_NEAREST_CENTROIDS = 16


# --------------------------------------------------------------------------------------------
# exact closest point on triangles


def _closest_on_segments(
    p: FloatArray, start: FloatArray, end: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Closest points on segments ``start→end`` to points ``p``; all (K, 3).

    Returns (closest (K, 3), parameter t in [0, 1] (K,), squared distance (K,)).
    A zero-length segment is its start point.
    """
    d = end - start
    dd = np.einsum("ij,ij->i", d, d)
    safe = np.where(dd > 0, dd, 1.0)
    t = np.clip(np.einsum("ij,ij->i", p - start, d) / safe, 0.0, 1.0)
    t = np.where(dd > 0, t, 0.0)
    q = start + t[:, None] * d
    diff = p - q
    return q, t, np.einsum("ij,ij->i", diff, diff)


def _closest_on_triangles(
    p: FloatArray, tri: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Exact closest points on triangles, pairwise.

    Args:
        p: (K, 3) query points.
        tri: (K, 3, 3) triangles, ``tri[k, i]`` is vertex ``i`` of the k-th triangle.

    Returns:
        closest (K, 3), barycentric coordinates of the closest point (K, 3), squared distance
        (K,). If the orthogonal projection of a point onto the triangle's plane falls inside the
        triangle it is the closest point; otherwise the closest point lies on the boundary and is
        the nearest of the closest points on the three edges. Degenerate (collinear or
        coincident-vertex) triangles are handled as their edges, so every result is finite.
    """
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab = b - a
    ac = c - a
    ap = p - a
    n = np.cross(ab, ac)
    n2 = np.einsum("ij,ij->i", n, n)
    ab2 = np.einsum("ij,ij->i", ab, ab)
    ac2 = np.einsum("ij,ij->i", ac, ac)
    # |ab × ac|² = |ab|² |ac|² sin²(angle at a); a near-collinear triangle has sin ≈ 0 there.
    nondegenerate = n2 > 1e-20 * ab2 * ac2
    inv_n2 = np.where(nondegenerate, 1.0 / np.where(nondegenerate, n2, 1.0), 0.0)
    v = np.einsum("ij,ij->i", np.cross(ap, ac), n) * inv_n2
    w = np.einsum("ij,ij->i", np.cross(ab, ap), n) * inv_n2
    u = 1.0 - v - w
    inside = nondegenerate & (u >= 0) & (v >= 0) & (w >= 0)

    q0, t0, d0 = _closest_on_segments(p, a, b)
    q1, t1, d1 = _closest_on_segments(p, b, c)
    q2, t2, d2 = _closest_on_segments(p, c, a)
    edge = np.argmin(np.stack([d0, d1, d2], axis=1), axis=1)
    zeros = np.zeros_like(t0)
    bary_edges = np.stack(
        [
            np.stack([1.0 - t0, t0, zeros], axis=1),
            np.stack([zeros, 1.0 - t1, t1], axis=1),
            np.stack([t2, zeros, 1.0 - t2], axis=1),
        ],
        axis=1,
    )  # (K, 3 edges, 3)
    q_edges = np.stack([q0, q1, q2], axis=1)  # (K, 3 edges, 3)
    rows = np.arange(len(p))
    bary = bary_edges[rows, edge]
    closest = q_edges[rows, edge]

    bary[inside] = np.stack([u[inside], v[inside], w[inside]], axis=1)
    closest[inside] = (a + v[:, None] * ab + w[:, None] * ac)[inside]
    diff = p - closest
    return closest, bary, np.einsum("ij,ij->i", diff, diff)


@dataclass(frozen=True)
class ClosestPoints:
    """Closest points on a triangle mesh's surface to a set of query points.

    Attributes:
        points: (N, 3) closest surface points, metres.
        distances: (N,) Euclidean distances from the queries to ``points``, metres.
        face_indices: (N,) index of the triangle that holds each closest point.
        barycentric: (N, 3) barycentric coordinates of each closest point with respect to the
            vertices ``faces[face_indices]`` in their stored order (non-negative, sum 1).
    """

    points: FloatArray
    distances: FloatArray
    face_indices: IntArray
    barycentric: FloatArray


class TriangleIndex:
    """Exact nearest-triangle search over a fixed set of triangles.

    Each triangle is bounded by the sphere around its centroid whose radius ``r`` is the largest
    centroid-to-vertex distance, so ``dist(p, triangle) >= |p - centroid| - r``. A query first
    takes the exact distance ``d`` to the triangle with the nearest centroid as an upper bound,
    then evaluates exactly every triangle with ``|p - centroid| - r <= d``. The candidates come
    from KD-trees of the centroids, one per bin of triangles of similar ``r`` (powers of two
    above the median, ``R`` the largest in the bin) searched within ``d + R``: the ``k`` nearest
    centroids in one array query, and for the few points with more candidates than that, every
    centroid in the ball.
    """

    def __init__(self, triangles: FloatArray, *, k: int = _NEAREST_CENTROIDS) -> None:
        self.triangles = triangles  # (F, 3, 3)
        self.k = k
        self.centroids = triangles.mean(axis=1)
        self.radii = np.sqrt(((triangles - self.centroids[:, None, :]) ** 2).sum(axis=2)).max(
            axis=1
        )
        self.all_tree = cKDTree(self.centroids)
        positive = self.radii[self.radii > 0]
        reference = float(np.median(positive)) if positive.size else 1.0
        level = np.ceil(np.log2(np.maximum(self.radii, reference) / reference)).astype(np.int64)
        self.bins: list[tuple[IntArray, float, Any]] = []
        for value in np.unique(level):
            members = np.flatnonzero(level == value).astype(np.int64)
            self.bins.append(
                (members, float(self.radii[members].max()), cKDTree(self.centroids[members]))
            )

    def query(self, points: FloatArray) -> ClosestPoints:
        n = points.shape[0]
        if n == 0:
            return ClosestPoints(
                points=np.zeros((0, 3)),
                distances=np.zeros(0),
                face_indices=np.zeros(0, dtype=np.int64),
                barycentric=np.zeros((0, 3)),
            )
        _, first = self.all_tree.query(points)
        first = np.asarray(first, dtype=np.int64)
        q, bary, d2 = _closest_on_triangles(points, self.triangles[first])
        best = ClosestPoints(points=q, distances=d2, face_indices=first, barycentric=bary)
        for members, radius, tree in self.bins:
            # Only a triangle with |p - centroid| - r <= the best distance so far can be closer.
            bound = np.sqrt(best.distances) * (1.0 + 1e-9) + 1e-12
            reach = bound + radius
            cap = float(np.quantile(reach, 0.99))  # a scalar bound keeps far bins cheap
            k = min(self.k, len(members))
            found, nearest = tree.query(points, k=k, distance_upper_bound=cap)
            found = np.asarray(found).reshape(n, k)
            nearest = np.asarray(nearest, dtype=np.int64).reshape(n, k)
            hit = found <= reach[:, None]
            pid = np.broadcast_to(np.arange(n)[:, None], (n, k))[hit]
            fid = members[nearest[hit]]
            # Rows of k hits, and points that reach beyond the cap: search the whole ball.
            more = np.flatnonzero((hit[:, -1] & (k < len(members))) | (reach > cap))
            if more.size:
                lists = tree.query_ball_point(points[more], reach[more])
                counts = np.fromiter((len(item) for item in lists), np.int64, len(lists))
                total = int(counts.sum())
                extra = members[np.fromiter(itertools.chain.from_iterable(lists), np.int64, total)]
                searched = np.zeros(n, dtype=bool)
                searched[more] = True
                keep = ~searched[pid]
                pid = np.concatenate([pid[keep], np.repeat(more, counts)])
                fid = np.concatenate([fid[keep], extra])
            # The bin's bound R let in triangles whose own sphere is smaller: test each.
            gap = np.linalg.norm(points[pid] - self.centroids[fid], axis=1) - self.radii[fid]
            close = gap <= bound[pid]
            self._update(best, points, pid[close], fid[close])
        best.distances[:] = np.sqrt(best.distances)
        return best

    def _update(self, best: ClosestPoints, points: FloatArray, pid: IntArray,
                fid: IntArray) -> None:  # fmt: skip
        """Evaluate the pairs (point ``pid``, triangle ``fid``) exactly and keep, per point,
        the closest triangle found so far (``best.distances`` holds squared distances)."""
        for lo in range(0, len(pid), _PAIR_CHUNK):
            p_ids = pid[lo : lo + _PAIR_CHUNK]
            f_ids = fid[lo : lo + _PAIR_CHUNK]
            q, bary, d2 = _closest_on_triangles(points[p_ids], self.triangles[f_ids])
            # Best pair per point: sort by (point, distance), take each group's first.
            order = np.lexsort((d2, p_ids))
            sorted_ids = p_ids[order]
            is_first = np.ones(len(order), dtype=bool)
            is_first[1:] = sorted_ids[1:] != sorted_ids[:-1]
            sel = order[is_first]
            sel = sel[d2[sel] < best.distances[p_ids[sel]]]
            target = p_ids[sel]
            best.distances[target] = d2[sel]
            best.face_indices[target] = f_ids[sel]
            best.points[target] = q[sel]
            best.barycentric[target] = bary[sel]


def closest_points_on_mesh(
    points: ArrayLike, vertices: ArrayLike, faces: ArrayLike
) -> ClosestPoints:
    """Exact closest point on a triangle mesh's surface for every query point.

    Args:
        points: (N, 3) query points, metres.
        vertices: (M, 3) mesh vertices, metres.
        faces: (F, 3) integer vertex indices of the triangles, ``F >= 1``.

    Returns:
        :class:`ClosestPoints` with the closest surface points, distances, triangle indices
        and barycentric coordinates. Where several triangles are equally close, any one of them.
    """
    p = as_points("points", points)
    v = as_points("vertices", vertices, min_count=1)
    f = as_faces("faces", faces, v.shape[0])
    return TriangleIndex(v[f]).query(p)


def point_to_surface_distance(
    points: ArrayLike, vertices: ArrayLike, faces: ArrayLike
) -> FloatArray:
    """Exact Euclidean distance from each point to the closest point on a triangle mesh.

    The distance is to the mesh *surface* (triangle interiors, edges and vertices), not to the
    nearest vertex; it is unsigned.

    Args:
        points: (N, 3) query points, metres.
        vertices: (M, 3) mesh vertices, metres.
        faces: (F, 3) integer vertex indices of the triangles, ``F >= 1``.

    Returns:
        (N,) float64 distances in metres.
    """
    return closest_points_on_mesh(points, vertices, faces).distances


# --------------------------------------------------------------------------------------------
# the metric


@dataclass(frozen=True)
class SurfaceError:
    """Bi-directional vertex-to-surface distance between a prediction and the ground truth.

    Attributes:
        mean: the metric, metres: ``(pred_to_gt_mean + gt_to_pred_mean) / 2``. Each direction
            is weighted equally whatever the two meshes' vertex counts, so a densely sampled
            ground truth (a scan) does not dominate a coarser prediction, or vice versa.
        pred_to_gt_mean: mean over predicted vertices of the distance to the ground-truth
            surface, metres (accuracy: penalises predicted geometry that is not in the truth).
        gt_to_pred_mean: mean over ground-truth vertices of the distance to the predicted
            surface, metres (completeness: penalises true geometry the prediction misses).
        pred_to_gt: (V_pred,) per predicted vertex distance to the ground-truth surface,
            metres (for a heat map on the prediction).
        gt_to_pred: (V_gt,) per ground-truth vertex distance to the predicted surface, metres
            (for a heat map on the ground truth).
    """

    mean: float
    pred_to_gt_mean: float
    gt_to_pred_mean: float
    pred_to_gt: FloatArray
    gt_to_pred: FloatArray

    @property
    def mean_mm(self) -> float:
        """:attr:`mean` in millimetres, the unit the dissertation's tables use."""
        return self.mean * 1000.0


def bidirectional_surface_error(
    pred_vertices: ArrayLike,
    pred_faces: ArrayLike,
    gt_vertices: ArrayLike,
    gt_faces: ArrayLike,
) -> SurfaceError:
    """Bi-directional vertex-to-surface distance, as the dissertation evaluates shape.

    Every predicted vertex is measured to the closest point on the ground-truth surface and
    every ground-truth vertex to the closest point on the predicted surface (exact
    point-to-triangle distances); the metric is the average of the two directional means.
    No alignment is done here: the meshes are compared where they are (see
    :func:`surface_error_after_alignment` for the dissertation's protocol, which first aligns
    pose and scale). Every vertex counts, including vertices used by no face.

    Args:
        pred_vertices: (V_pred, 3) predicted vertices, metres.
        pred_faces: (F_pred, 3) predicted triangles (vertex indices).
        gt_vertices: (V_gt, 3) ground-truth vertices, metres.
        gt_faces: (F_gt, 3) ground-truth triangles (vertex indices).

    Returns:
        :class:`SurfaceError` with the mean, both directional means and per-vertex distances,
        all in metres.
    """
    pv = as_points("pred_vertices", pred_vertices, min_count=1)
    pf = as_faces("pred_faces", pred_faces, pv.shape[0])
    gv = as_points("gt_vertices", gt_vertices, min_count=1)
    gf = as_faces("gt_faces", gt_faces, gv.shape[0])
    pred_to_gt = TriangleIndex(gv[gf]).query(pv).distances
    gt_to_pred = TriangleIndex(pv[pf]).query(gv).distances
    a = float(pred_to_gt.mean())
    b = float(gt_to_pred.mean())
    return SurfaceError(
        mean=0.5 * (a + b),
        pred_to_gt_mean=a,
        gt_to_pred_mean=b,
        pred_to_gt=pred_to_gt,
        gt_to_pred=gt_to_pred,
    )
