"""Normal angular error between triangle meshes, and both errors per region of the truth.

Silhouettes constrain a surface's position; detail (wrinkles, a face) shows in its *normals*.
Paper C measures both: the bi-directional vertex-to-surface distance of
:mod:`monoavatar.eval.surface`, and here the **bi-directional normal angular error**: every
vertex of one mesh is matched to the closest point of the other mesh's surface, and the angle
between the vertex's normal and the other surface's normal at that point is taken (the smooth
normal, the barycentric mean of the triangle's vertex normals); the metric is the mean of the
two directional means, in degrees.

Regions (the face, a garment) are sets of ground-truth vertices: the ground truth's side counts
its vertices in the set, the prediction's side counts the vertices whose closest ground-truth
triangle has a corner in the set.

Like :mod:`monoavatar.eval.surface`, this module depends on numpy and scipy only (its vertex
normals are computed here, not shared with the reconstruction code). Metres in; distances in
metres, angles in degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from monoavatar.eval._checks import FloatArray, IntArray, as_faces, as_points
from monoavatar.eval.surface import TriangleIndex

__all__ = ["SurfaceComparison", "compare_surfaces", "mesh_vertex_normals"]


def mesh_vertex_normals(vertices: FloatArray, faces: IntArray) -> FloatArray:
    """(V, 3) area-weighted unit vertex normals (zero where no face, or faces cancel)."""
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = twice the area
    out = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(out, faces[:, k], n)
    length = np.linalg.norm(out, axis=1, keepdims=True)
    return np.where(length > 0, out / np.where(length > 0, length, 1.0), 0.0)


def _angles(
    normals: FloatArray, target_normals: FloatArray, target_faces: IntArray,
    face: IntArray, bary: FloatArray,
) -> FloatArray:  # fmt: skip
    """Degrees between ``normals`` (N, 3) and the target's smooth normal at the closest points
    (triangle ``face`` (N,), barycentric ``bary`` (N, 3))."""
    at = np.einsum("nk,nkc->nc", bary, target_normals[target_faces[face]])
    at /= np.maximum(np.linalg.norm(at, axis=1, keepdims=True), 1e-12)
    cos = np.clip(np.einsum("nc,nc->n", normals, at), -1.0, 1.0)
    return np.asarray(np.degrees(np.arccos(cos)))


@dataclass(frozen=True)
class SurfaceComparison:
    """Distances and normal angles between a prediction and the ground truth, both ways.

    Attributes:
        pred_to_gt: (V_pred,) distance of each predicted vertex to the ground-truth surface, m.
        gt_to_pred: (V_gt,) distance of each ground-truth vertex to the predicted surface, m.
        pred_angle: (V_pred,) degrees between each predicted vertex's normal and the ground
            truth's normal at its closest point.
        gt_angle: (V_gt,) the same from the ground truth's side.
        pred_gt_face: (V_pred,) the ground-truth triangle closest to each predicted vertex.
        gt_faces: (F_gt, 3) the ground truth's triangles (for regions).
    """

    pred_to_gt: FloatArray
    gt_to_pred: FloatArray
    pred_angle: FloatArray
    gt_angle: FloatArray
    pred_gt_face: IntArray
    gt_faces: IntArray

    @property
    def distance(self) -> float:
        """The bi-directional vertex-to-surface distance, metres."""
        return 0.5 * float(self.pred_to_gt.mean() + self.gt_to_pred.mean())

    @property
    def angle(self) -> float:
        """The bi-directional normal angular error, degrees."""
        return 0.5 * float(self.pred_angle.mean() + self.gt_angle.mean())

    def region(self, gt_vertices: ArrayLike) -> tuple[float, float]:
        """(distance in metres, angle in degrees), both bi-directional, over a region given as
        (V_gt,) bool ground-truth vertices (see the module docstring); NaN for an empty one."""
        mask = np.asarray(gt_vertices, dtype=bool)
        if mask.shape != self.gt_to_pred.shape:
            raise ValueError(f"region: expected ({self.gt_to_pred.size},) bool, got {mask.shape}")
        pred = mask[self.gt_faces[self.pred_gt_face]].any(axis=1)
        if not mask.any() or not pred.any():
            return float("nan"), float("nan")
        distance = 0.5 * (self.pred_to_gt[pred].mean() + self.gt_to_pred[mask].mean())
        angle = 0.5 * (self.pred_angle[pred].mean() + self.gt_angle[mask].mean())
        return float(distance), float(angle)


def compare_surfaces(
    pred_vertices: ArrayLike,
    pred_faces: ArrayLike,
    gt_vertices: ArrayLike,
    gt_faces: ArrayLike,
) -> SurfaceComparison:
    """Exact closest points both ways, with their distances and normal angles (no alignment:
    align first, e.g. with :func:`monoavatar.eval.align_icp`).

    Args:
        pred_vertices: (V_pred, 3), pred_faces: (F_pred, 3); gt_vertices: (V_gt, 3),
        gt_faces: (F_gt, 3); metres, triangles wound consistently (normals by the right-hand
        rule, outward).
    """
    pv = as_points("pred_vertices", pred_vertices, min_count=1)
    pf = as_faces("pred_faces", pred_faces, pv.shape[0])
    gv = as_points("gt_vertices", gt_vertices, min_count=1)
    gf = as_faces("gt_faces", gt_faces, gv.shape[0])
    pn, gn = mesh_vertex_normals(pv, pf), mesh_vertex_normals(gv, gf)
    to_gt = TriangleIndex(gv[gf]).query(pv)
    to_pred = TriangleIndex(pv[pf]).query(gv)
    return SurfaceComparison(
        pred_to_gt=to_gt.distances,
        gt_to_pred=to_pred.distances,
        pred_angle=_angles(pn, gn, gf, to_gt.face_indices, to_gt.barycentric),
        gt_angle=_angles(gn, pn, pf, to_pred.face_indices, to_pred.barycentric),
        pred_gt_face=to_gt.face_indices,
        gt_faces=gf,
    )
