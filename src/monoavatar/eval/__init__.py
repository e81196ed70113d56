"""eval stage: metrics, independent of the reconstruction code.

Surface error (the dissertation's bi-directional vertex-to-surface distance, after aligning
pose and scale), the normal angular error and both per region of the truth, joint errors
(MPJPE, PA-MPJPE), silhouette IoU, PSNR and error heat maps. Depends on numpy and scipy only;
imports nothing from other monoavatar subpackages, so that a bug in the reconstruction code
cannot hide in a helper shared with its own evaluation. Units: metres in; surface errors in
metres (``.mean_mm`` for millimetres), joint errors in mm, angles in degrees.
"""

from monoavatar.eval.alignment import SimilarityTransform, align_similarity
from monoavatar.eval.heatmap import error_to_rgb, write_heatmap_ply
from monoavatar.eval.icp import (
    AlignedSurfaceError,
    IcpResult,
    align_icp,
    surface_error_after_alignment,
)
from monoavatar.eval.image import psnr, silhouette_iou
from monoavatar.eval.joints import joint_errors, mpjpe, pa_mpjpe
from monoavatar.eval.normals import SurfaceComparison, compare_surfaces
from monoavatar.eval.surface import (
    ClosestPoints,
    SurfaceError,
    bidirectional_surface_error,
    closest_points_on_mesh,
    point_to_surface_distance,
)

__all__ = [
    "AlignedSurfaceError",
    "ClosestPoints",
    "IcpResult",
    "SimilarityTransform",
    "SurfaceComparison",
    "SurfaceError",
    "align_icp",
    "align_similarity",
    "bidirectional_surface_error",
    "closest_points_on_mesh",
    "compare_surfaces",
    "error_to_rgb",
    "joint_errors",
    "mpjpe",
    "pa_mpjpe",
    "point_to_surface_distance",
    "psnr",
    "silhouette_iou",
    "surface_error_after_alignment",
    "write_heatmap_ply",
]
