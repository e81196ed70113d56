"""Poses of frames the avatar was not built from: the finished avatar tracked into them.

The key-frames' track is interpolated in time to the new frames (spherical linear
interpolation of every joint's local rotation between the two nearest key-frames, linear
interpolation of the root translation), and each new frame's pose is then refined by the
flow rounds of :mod:`monoavatar.fit.flow_refine`: optical flow from the textured avatar's
render to the frame, the outline, and the pose energy on the frame's own perception. The
avatar (shape, offsets, texture, lighting) stays as it is; only the poses move. This is
Paper A's analysis-by-synthesis tracking with the reconstructed avatar as the template.

The bench measures the texture in held-out poses with it (:mod:`monoavatar.bench.heldout`):
the frames of the video that were not key-frames, posed by this tracker (only the poses are
fitted to those frames; the avatar never sees them). The
interpolation takes the shorter way round, so key-frames must lie less than a half turn
apart for any joint (a turn-around in 120 frames with 30 key-frames: 12°).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation, Slerp
from torch import Tensor

from monoavatar.body import BodyModel
from monoavatar.fit.flow_refine import FlowRefineSettings, refine_poses_with_flow
from monoavatar.fit.pose import PoseSettings, PoseTrack
from monoavatar.perception.observations import Observations

__all__ = ["interpolate_poses", "track_frames"]


def interpolate_poses(
    key_indices: np.ndarray, poses: np.ndarray, translations: np.ndarray, at: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Poses at other frames of the same source, interpolated from key-frames.

    Args:
        key_indices: (K,) frame indices of the key-frames (any order, no repeats).
        poses: (K, J, 3) axis-angle local joint rotations at the key-frames, radians.
        translations: (K, 3) root translations, metres.
        at: (M,) frame indices to interpolate at; beyond the first or last key-frame the
            nearest key-frame's pose is held.
    Returns:
        (M, J, 3) poses, every joint's rotation on the shortest arc between the two
        neighbouring key-frames' rotations in proportion to the frame index, and (M, 3)
        translations interpolated linearly.
    """
    key = np.asarray(key_indices, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    translations = np.asarray(translations, dtype=np.float64)
    if key.ndim != 1 or len(key) == 0:
        raise ValueError(f"key_indices must be a non-empty (K,) array, got shape {key.shape}")
    if poses.shape[0] != len(key) or poses.ndim != 3 or poses.shape[2] != 3:
        raise ValueError(f"poses must be ({len(key)}, J, 3), got {poses.shape}")
    if translations.shape != (len(key), 3):
        raise ValueError(f"translations must be ({len(key)}, 3), got {translations.shape}")
    if len(np.unique(key)) != len(key):
        raise ValueError("key_indices must not repeat")
    order = np.argsort(key)
    key, poses, translations = key[order], poses[order], translations[order]
    q = np.clip(np.asarray(at, dtype=np.float64).reshape(-1), key[0], key[-1])
    num_joints = poses.shape[1]
    out_p = np.empty((len(q), num_joints, 3))
    if len(key) == 1:
        out_p[:] = poses[0]
    else:
        for j in range(num_joints):
            out_p[:, j] = Slerp(key, Rotation.from_rotvec(poses[:, j]))(q).as_rotvec()
    out_t = np.stack([np.interp(q, key, translations[:, c]) for c in range(3)], axis=1)
    return out_p, out_t


def track_frames(
    body: BodyModel,
    obs: Observations,
    images: np.ndarray,
    key_track: PoseTrack,
    shape: Tensor | np.ndarray,
    offsets: Tensor | np.ndarray,
    texture: np.ndarray,
    sh: np.ndarray | None,
    rounds: int = 3,
    settings: FlowRefineSettings | None = None,
    pose_settings: PoseSettings | None = None,
    *,
    progress: bool = False,
) -> PoseTrack:
    """Track a finished avatar into new frames of the video it was built from.

    Args:
        body: the body model.
        obs: the new frames' observations (masks, keypoints, the avatar's camera);
            ``obs.frame_indices`` index the same source as ``key_track.frame_indices``.
        images: (N, H, W, 3) uint8 new frames.
        key_track: the avatar's key-frame poses (those flagged ``failed`` are not used).
        shape: (S,) the avatar's shape parameters; offsets: (V, 3) its canonical offsets D,
            metres.
        texture: (T, T, 3) the texture in [0, 1] (an albedo when ``sh`` is given).
        sh: (3, 9) the lighting the texture was divided by, or None.
        rounds: flow rounds after the interpolation (0: the interpolated poses).
        settings: the flow term's options; pose_settings: the pose energy's.
    Returns:
        A track of the new frames (``failed``: frames without a person, whose pose stays the
        interpolated one; ``energy``: the last round's pose energy, NaN after 0 rounds).
    """
    if rounds < 0:
        raise ValueError(f"rounds must be >= 0, got {rounds}")
    n = len(obs)
    if len(images) != n:
        raise ValueError(f"{len(images)} images for {n} observations")
    good = ~np.asarray(key_track.failed, dtype=bool)
    if not good.any():
        raise ValueError("the key-frame track has no frame that did not fail")
    poses, translations = interpolate_poses(
        key_track.frame_indices[good], key_track.poses[good], key_track.translations[good],
        obs.frame_indices,
    )  # fmt: skip
    nan = np.full(n, np.nan)
    track = replace(
        key_track, poses=poses, translations=translations, camera=obs.camera,
        frame_indices=np.asarray(obs.frame_indices, dtype=np.int64).copy(),
        keypoint_error=nan.copy(), silhouette_iou=nan.copy(), energy=nan.copy(),
        failed=np.asarray(obs.no_person, dtype=bool).copy(), seconds=0.0, timings={},
    )  # fmt: skip
    for _ in range(rounds):
        track = refine_poses_with_flow(body, obs, images, track, shape, offsets, texture, sh,
                                       settings, pose_settings, progress=progress)  # fmt: skip
    return track
