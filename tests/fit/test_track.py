"""Tracking a finished avatar into frames it was not built from: the interpolation between
key-frames in closed form, and poses recovered from renders of a textured body."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from monoavatar.body.model import BodyModel
from monoavatar.fit.flow_refine import FlowRefineSettings
from monoavatar.fit.pose import PoseSettings
from monoavatar.fit.track import interpolate_poses, track_frames
from tests.fit.observations import scene_observations
from tests.fit.test_flow_refine import (
    _perturbed,
    _scene,
    _track,
    _vertex_error_mm,
    _visible_reprojection_px,
)


def _about_z(degrees: float) -> np.ndarray:
    return np.array([0.0, 0.0, np.radians(degrees)])


def test_interpolation_turns_each_joint_in_proportion_to_time() -> None:
    """Key-frames 6 and 0 (given out of order): joint 0 turns 0° → 60° about z, joint 1 from
    170° to -170° (the short way round, through 180°), the translation 0 → 0.6 m in x."""
    keys = np.array([6, 0])
    poses = np.stack([np.stack([_about_z(60.0), _about_z(-170.0)]),
                      np.stack([_about_z(0.0), _about_z(170.0)])])  # fmt: skip
    translations = np.array([[0.6, 0.0, 0.0], [0.0, 0.0, 0.0]])
    p, t = interpolate_poses(keys, poses, translations, np.array([2, 3, 9, -3]))

    angle = Rotation.from_rotvec(p[:, 0]).as_euler("xyz", degrees=True)[:, 2]
    np.testing.assert_allclose(angle, [20.0, 30.0, 60.0, 0.0], atol=1e-9)  # held at the ends
    turn = Rotation.from_rotvec(p[:, 1]).as_euler("xyz", degrees=True)[:, 2]
    np.testing.assert_allclose(np.mod(turn, 360.0), [176.6666667, 180.0, 190.0, 170.0],
                               atol=1e-6)  # fmt: skip
    np.testing.assert_allclose(t[:, 0], [0.2, 0.3, 0.6, 0.0], atol=1e-12)
    # at a key-frame, its own pose
    p_key, t_key = interpolate_poses(keys, poses, translations, keys)
    np.testing.assert_allclose(p_key, poses, atol=1e-12)
    np.testing.assert_allclose(t_key, translations, atol=1e-12)


def test_interpolation_checks_its_input() -> None:
    poses = np.zeros((2, 3, 3))
    with pytest.raises(ValueError, match="must not repeat"):
        interpolate_poses(np.array([1, 1]), poses, np.zeros((2, 3)), np.array([0]))
    with pytest.raises(ValueError, match=r"translations must be \(2, 3\)"):
        interpolate_poses(np.array([0, 1]), poses, np.zeros((3, 3)), np.array([0]))
    one, t = interpolate_poses(np.array([4]), poses[:1] + 0.1, np.ones((1, 3)), np.array([0, 9]))
    np.testing.assert_allclose(one, 0.1)
    np.testing.assert_allclose(t, 1.0)


def test_tracking_recovers_poses_the_key_frames_got_wrong(anny32: BodyModel) -> None:
    """Renders at yaws 0°, 40°, 80°, 120°; the key-frames are the first and the last, with
    the root turned 5° too far and both upper arms twisted by 12° (constant errors, so the
    interpolation carries them into the two new frames exactly). Tracking with the textured
    avatar takes them back out."""
    obs, images, poses, texture = _scene(anny32)
    keys = _track(anny32, _perturbed(anny32, poses)[[0, 3]], obs.camera)
    keys = replace(keys, frame_indices=np.array([0, 3]))
    new = scene_observations(obs.masks[1:3], obs.keypoints[1:3], obs.camera)
    new = replace(new, frame_indices=np.array([1, 2]))
    shape = anny32.default_shape(1)[0].double().numpy()
    offsets = np.zeros((anny32.num_vertices, 3))
    pose_settings = PoseSettings(silhouette_points=600, boundary_points=150, smooth_weight=0.0)
    settings = FlowRefineSettings(iterations=30, contour_weight=0.0, workers=1)

    start = track_frames(anny32, new, images[1:3], keys, shape, offsets, texture, None, 0)
    np.testing.assert_allclose(start.poses, _perturbed(anny32, poses)[1:3], atol=1e-9)
    assert start.frame_indices.tolist() == [1, 2] and not start.failed.any()

    tracked = track_frames(anny32, new, images[1:3], keys, shape, offsets, texture, None, 2,
                           settings, pose_settings)  # fmt: skip
    true = poses[1:3]
    before = (_visible_reprojection_px(anny32, start, true, obs.camera),
              _vertex_error_mm(anny32, start, true))  # fmt: skip
    after = (_visible_reprojection_px(anny32, tracked, true, obs.camera),
             _vertex_error_mm(anny32, tracked, true))  # fmt: skip
    # measured: 4.0 px / 31 mm interpolated, 2.0 px / 16 mm tracked
    assert after[0] < 0.6 * before[0] and after[1] < 0.7 * before[1], (before, after)
    assert np.isfinite(tracked.energy).all()


def test_tracking_checks_its_input(anny32: BodyModel) -> None:
    obs, images, poses, texture = _scene(anny32)
    keys = _track(anny32, poses, obs.camera)
    shape = anny32.default_shape(1)[0].double().numpy()
    offsets = np.zeros((anny32.num_vertices, 3))
    with pytest.raises(ValueError, match="rounds must be >= 0"):
        track_frames(anny32, obs, images, keys, shape, offsets, texture, None, -1)
    with pytest.raises(ValueError, match="3 images for 4 observations"):
        track_frames(anny32, obs, images[:3], keys, shape, offsets, texture, None, 0)
    failed = replace(keys, failed=np.ones(len(poses), bool))
    with pytest.raises(ValueError, match="no frame that did not fail"):
        track_frames(anny32, obs, images, failed, shape, offsets, texture, None, 0)
