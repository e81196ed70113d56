"""The evaluation of one reconstruction folder against the synth scene it was made from:
every figure of :class:`~monoavatar.bench.metrics.SubjectMetrics`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from monoavatar.bench.heldout import (
    HELDOUT_TRACK_ROUNDS,
    ROOT_OFF_DEG,
    _heldout_psnr,
    _pose,
    _silhouettes,
    _tracked_psnr,
    heldout_frames,
    root_orientation_error_deg,
)
from monoavatar.bench.metrics import (
    BodyCache,
    HeatMap,
    MetricsError,
    Rig,
    SubjectMetrics,
    SubjectTruth,
    surface_metrics,
)
from monoavatar.io.avatar_folder import AvatarFolder


def evaluate_reconstruction(
    folder: str | Path,
    truth: SubjectTruth,
    bodies: BodyCache | None = None,
    *,
    max_heldout: int = 20,
    body_only: bool = True,
    perception: str = "mediapipe",
    track_rounds: int = HELDOUT_TRACK_ROUNDS,
    workers: int = 2,
) -> tuple[SubjectMetrics, HeatMap]:
    """Measure a reconstruction output folder against the synth scene it was made from.

    Args:
        folder: the ``monoavatar reconstruct`` output folder.
        truth: the scene's ground truth (:func:`load_truth`).
        bodies: body models to reuse between calls.
        max_heldout: at most this many held-out frames (evenly spread) for the PSNR.
        body_only: also measure the fitted body without its offsets.
        perception: what the held-out tracker sees of the held-out frames: ``"mediapipe"``
            (masks and keypoints perceived from the frames) or ``"ground-truth"`` (the
            scene's own, as ``reconstruct --perception ground-truth``).
        track_rounds: the tracker's flow rounds (0: the interpolated poses).
        workers: the tracker's threads.

    Returns:
        The metrics, and the per-vertex error of the aligned avatar for heat maps.
    """
    from monoavatar.eval import pa_mpjpe

    bodies = bodies or BodyCache()
    recon = AvatarFolder.load(folder)
    p = recon.params
    gt = truth.scene.ground_truth
    n = len(gt.poses)
    idx = p.frame_indices
    if len(idx) == 0 or len(idx) != len(p.poses) or idx.min() < 0 or idx.max() >= n:
        raise MetricsError(f"{folder}: frame_indices do not match the {n}-frame scene")

    body = bodies.get(p.body_model)
    if p.offsets.shape != (body.num_vertices, 3):
        raise MetricsError(
            f"{folder}: offsets have shape {p.offsets.shape}, the body model has "
            f"{body.num_vertices} vertices"
        )
    rest, rest_joints = _pose(body, p.shape, np.zeros((1, body.num_joints, 3)),
                              np.zeros((1, 3)), None)  # fmt: skip
    rig = Rig(body.skin_weights.double().numpy(), rest_joints[0], tuple(body.parents))
    # the articulated alignment needs the avatar on the body model's vertices (not, e.g., a
    # mesh of another resolution)
    same_mesh = recon.vertices.shape == (body.num_vertices, 3)
    surface, heat = surface_metrics(recon.vertices, recon.faces, truth.vertices, truth.faces,
                                    rig=rig if same_mesh else None,
                                    regions=truth.regions)  # fmt: skip

    body_only_mm = None
    if body_only:
        body_only_mm = surface_metrics(rest[0], body.faces.numpy(), truth.vertices,
                                       truth.faces, rig=rig)[0].mean_mm  # fmt: skip

    verts, joints = _pose(body, p.shape, p.poses, p.translations, p.offsets)
    names = list(body.joint_names)
    gt_names = list(truth.joint_names)
    common = [j for j in names if j in gt_names]
    if len(common) < 3 or names[0] not in gt_names:
        raise MetricsError(
            f"fitted and ground-truth skeletons share only joints {common} (root {names[0]!r})"
        )
    mine = joints[:, [names.index(j) for j in common]]
    theirs = truth.joints[idx][:, [gt_names.index(j) for j in common]]
    joint_mm = pa_mpjpe(mine, theirs)

    ious = _silhouettes(body, verts, p.camera, gt.masks[idx])
    root_deg = root_orientation_error_deg(p.poses[:, 0], p.camera.R, gt.poses[idx][:, 0],
                                          truth.scene.camera.R)  # fmt: skip

    held = heldout_frames(n, idx, max_heldout)
    transferred = _heldout_psnr(recon, body, truth, surface.alignment, held)
    psnr_rigid = transferred.mask_db
    if surface.pose_alignment is not None:
        transferred = _heldout_psnr(recon, body, truth, surface.pose_alignment, held,
                                    surface.aligned_pose)  # fmt: skip
    tracked = _tracked_psnr(recon, body, truth, held, perception, track_rounds, workers)
    heldout = tracked.tracked

    def heldout_pose_errors(found: tuple[np.ndarray, np.ndarray] | None,
                            ) -> tuple[float | None, float | None]:  # fmt: skip
        """PA-MPJPE (mm) and median root error (°) of held-out poses against the truth's."""
        if found is None:
            return None, None
        _, held_joints = _pose(body, p.shape, found[0], found[1], p.offsets)
        mm = pa_mpjpe(held_joints[:, [names.index(j) for j in common]],
                      truth.joints[held][:, [gt_names.index(j) for j in common]])  # fmt: skip
        deg = root_orientation_error_deg(found[0][:, 0], p.camera.R, gt.poses[held][:, 0],
                                         truth.scene.camera.R)  # fmt: skip
        return float(mm), float(np.median(deg))

    interp_mm, interp_deg = heldout_pose_errors(tracked.interpolated_poses)
    tracked_mm, tracked_deg = heldout_pose_errors(tracked.tracked_poses)

    report = recon.report
    return (
        SubjectMetrics(
            surface=surface,
            body_only_mm=body_only_mm,
            shape_only_mm=None,  # filled in from the shape-only run by the runner
            pa_mpjpe_mm=float(joint_mm),
            silhouette_iou=float(np.mean(ious)),
            silhouette_iou_min=float(np.min(ious)),
            psnr_db=heldout.mask_db,
            psnr_overlap_db=heldout.overlap_db,
            psnr_union_db=heldout.union_db,
            heldout_frames=int(len(held)) if heldout.mask_db is not None else 0,
            texture_lighting=heldout.lighting,
            keyframes=int(len(idx)),
            timings=dict(report.timings),
            reconstruct_seconds=report.seconds,
            peak_memory_mb=report.peak_memory_mb,
            warnings=list(report.warnings),
            psnr_rigid_db=psnr_rigid,
            missed_fraction=heldout.missed_fraction,
            missed_error_share=heldout.missed_error_share,
            root_error_deg=float(np.median(root_deg)),
            root_error_max_deg=float(root_deg.max()),
            root_off_frames=int((root_deg > ROOT_OFF_DEG).sum()),
            psnr_true_poses_db=transferred.mask_db,
            psnr_interpolated_db=tracked.interpolated.mask_db,
            heldout_track_seconds=tracked.seconds if heldout.mask_db is not None else None,
            heldout_pa_mpjpe_mm=tracked_mm,
            heldout_pa_mpjpe_interpolated_mm=interp_mm,
            heldout_root_error_deg=tracked_deg,
            heldout_root_error_interpolated_deg=interp_deg,
        ),
        heat,
    )


def _float_or_none(value: Any) -> float | None:
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        return None
