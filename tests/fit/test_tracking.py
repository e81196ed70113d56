"""The Paper A tracker (:mod:`monoavatar.fit.tracking`): its flow term is the flow renderer's
Eq. A.1 at sampled pixels, its 3D-landmark term vanishes at the model's own landmarks, and on
exact renderings of a known motion (masks, keypoints and the flow the motion causes) it
recovers the joints; too short or empty clips are refused."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from monoavatar.body.model import BodyModel
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.geometry import ray_rotations
from monoavatar.fit import pose_energy as pe
from monoavatar.fit.prior import apose_prior
from monoavatar.fit.tracking import (
    LANDMARK_BONES,
    TrackError,
    TrackSettings,
    _flow_energy,
    closeness_energy,
    flow_targets,
    rescale_landmarks,
    track_motion,
    world_landmark_energy,
)
from monoavatar.render import rasterize
from monoavatar.render.flow import render_flow
from tests.fit.observations import scene_observations

SIZE, FOCAL = 208, 290.0


def _camera() -> PinholeCamera:
    return PinholeCamera.look_at(np.array([0.3, 0.1, 2.6]), np.array([0.0, -0.05, 0.0]),
                                 np.array([0.0, 1.0, 0.0]), FOCAL, SIZE, SIZE)  # fmt: skip


def _walk(body: BodyModel, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """A few steps of walking in place, turned 40° from the camera, drifting sideways."""
    t = np.arange(frames) / 10.0
    pose = np.zeros((frames, body.num_joints, 3))
    j = body.joint_index
    s = np.sin(2 * np.pi * 0.8 * t)
    pose[:, 0, 1] = np.radians(40.0)
    pose[:, j("hip_l"), 0], pose[:, j("hip_r"), 0] = -0.4 * s, 0.4 * s
    pose[:, j("knee_l"), 0] = 0.1 + 0.6 * np.clip(s, 0, None)
    pose[:, j("knee_r"), 0] = 0.1 + 0.6 * np.clip(-s, 0, None)
    pose[:, j("shoulder_l"), 2], pose[:, j("shoulder_r"), 2] = 0.3, -0.3
    pose[:, j("shoulder_l"), 0], pose[:, j("shoulder_r"), 0] = 0.3 * s, -0.3 * s
    pose[:, j("elbow_l"), 0] = pose[:, j("elbow_r"), 0] = -0.4
    trans = np.zeros((frames, 3))
    trans[:, 0] = 0.02 * np.arange(frames)
    return pose, trans


def _render(body: BodyModel, poses: np.ndarray, trans: np.ndarray):
    """Exact masks, keypoints (visibility as synth marks it), the forward flow each frame's
    motion causes (the flow renderer, frame i's pixels to frame i + 1) and the joints."""
    camera = _camera()
    n = len(poses)
    with torch.no_grad():
        out = body(pose=torch.as_tensor(poses, dtype=body.dtype),
                   translation=torch.as_tensor(trans, dtype=body.dtype))  # fmt: skip
        kp3d = body.keypoints(out.vertices).double()
    masks = np.zeros((n, SIZE, SIZE), bool)
    keypoints = np.zeros((n, 33, 3), np.float32)
    flow = np.zeros((n - 1, SIZE, SIZE, 2), np.float32)
    for i in range(n):
        frags = rasterize(out.vertices[i], body.faces, camera)
        masks[i] = frags.mask.numpy()
        px, depth = camera.project(kp3d[i])
        cols, rows = (np.clip(np.floor(px[:, k].numpy()).astype(int), 0, SIZE - 1) for k in (0, 1))
        visible = depth.numpy() - frags.depth.numpy()[rows, cols] < 0.08
        keypoints[i] = np.concatenate([px.numpy(), visible[:, None]], axis=1)
        if i + 1 < n:
            flow[i] = render_flow(out.vertices[i], out.vertices[i + 1], body.faces, camera,
                                  frags).flow.numpy()  # fmt: skip
    obs = replace(scene_observations(masks, keypoints, camera), flow=flow)
    return obs, out.joints.double().numpy(), kp3d.numpy(), out.vertices


def test_flow_term_is_the_rendered_flow_at_the_sampled_pixels(anny32: BodyModel) -> None:
    poses, trans = _walk(anny32, 3)
    obs, _, _, vertices = _render(anny32, poses, trans)
    targets = flow_targets(vertices[0], anny32.faces, obs.camera, obs.flow[0], obs.masks[0],
                           200, 0, seed=0)  # fmt: skip
    assert len(targets) == 200
    # the sampled surface points, taken to frame 1, land on their targets: the observed flow
    # here is the flow renderer's, so π(X_1) − p = F_r(0→1, p) = F_o(p)
    points = (targets.bary[..., None] * vertices[1][targets.vertex_ids]).sum(1)
    projected, _ = obs.camera.project(points.double())
    np.testing.assert_allclose(projected.numpy(), targets.targets.numpy(), atol=2e-3)
    # so the energy is zero at frame 1's true pose and grows when it moves
    rest, joints = anny32.rest_shape(anny32.default_shape(1))
    ctx = pe.energy_context(anny32, obs.camera, pe.PoseSettings(), apose_prior(anny32), rest[0],
                            joints[0])  # fmt: skip
    scale = torch.tensor([1.0])
    sub = pe.make_subset(anny32, rest[0], joints[0], torch.arange(10))
    at = []
    for d in (0.0, 0.05):
        var = pe.Variables(poses[1:2] + d, trans[1:2], anny32.dtype)
        transforms = sub.transforms(var.rotations(), var.translation)
        at.append(_flow_energy(ctx, rest[0], anny32.skin_weights, transforms, targets, scale,
                               3.0).item())  # fmt: skip
    assert at[0] < 1e-6 and at[1] > 100 * max(at[0], 1e-8)


def test_world_landmark_term_vanishes_at_the_models_own_landmarks() -> None:
    camera = _camera()
    gen = torch.Generator().manual_seed(3)
    kp = torch.randn(1, 33, 3, generator=gen, dtype=torch.float64) * 0.3
    cam = kp @ torch.as_tensor(camera.R).T + torch.as_tensor(camera.t)
    hips = 0.5 * (cam[:, 23] + cam[:, 24])
    rel = cam - hips[:, None]
    # the detector reports them in axes along its line of sight to the hips
    turn = ray_rotations(hips[0])
    observed = torch.cat([rel @ turn, torch.ones(1, 33, 1, dtype=torch.float64)], -1)
    valid = torch.ones(33, dtype=torch.bool)
    assert world_landmark_energy(kp, camera, observed, valid, 10.0).item() < 1e-12
    moved = kp.clone()
    moved[0, 15, 2] += 0.1
    assert world_landmark_energy(moved, camera, observed, valid, 10.0).item() > 1e-3


def test_landmarks_are_rescaled_to_the_bodys_bone_lengths() -> None:
    """A detector that saw the model at 0.8 of its size (an average person), with a frame
    missing, one landmark absent and one bone wildly off in another frame: scaled back by
    exactly 1 / 0.8, the absent values left NaN, the input untouched."""
    rng = np.random.default_rng(0)
    model = rng.normal(scale=0.3, size=(33, 3))
    valid = np.ones(33, dtype=bool)
    valid[31] = False  # a landmark the body model lacks
    world = np.zeros((5, 33, 4))
    world[..., :3] = 0.8 * (model - 0.5 * (model[23] + model[24]))
    world[..., 3] = 1.0
    world[1] = np.nan  # no person
    world[2, 15] = np.nan  # a wrist not seen
    world[3, 16, :3] += 5.0  # a forearm off by metres
    before = world.copy()
    out = rescale_landmarks(world, model, valid)
    np.testing.assert_allclose(out[0, :, :3], world[0, :, :3] / 0.8, rtol=1e-12)
    np.testing.assert_allclose(out[..., 3], world[..., 3])
    assert np.isnan(out[1]).all() and np.isnan(out[2, 15]).all()
    np.testing.assert_array_equal(np.isnan(world), np.isnan(before))
    assert np.allclose(np.nan_to_num(world), np.nan_to_num(before))
    for i, j in LANDMARK_BONES:
        if valid[i] and valid[j]:
            assert np.linalg.norm(out[0, j, :3] - out[0, i, :3]) == pytest.approx(
                np.linalg.norm(model[j] - model[i]), rel=1e-12)


def test_ray_rotation_takes_the_optical_axis_to_the_ray() -> None:
    for direction in ([0.3, -0.2, 1.0], [0.0, 0.0, 1.0], [-1.0, 0.5, 0.2]):
        d = torch.tensor(direction, dtype=torch.float64)
        R = ray_rotations(d)
        np.testing.assert_allclose((R @ torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)).numpy(),
                                   (d / d.norm()).numpy(), atol=1e-12)  # fmt: skip
        np.testing.assert_allclose((R.T @ R).numpy(), np.eye(3), atol=1e-12)
        assert abs(torch.linalg.det(R).item() - 1.0) < 1e-12
        # the smallest such rotation: its axis is perpendicular to both
        axis = torch.linalg.cross(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), d)
        if axis.norm() > 0:
            np.testing.assert_allclose((R @ axis).numpy(), axis.numpy(), atol=1e-12)


def test_tracking_recovers_a_known_motion_from_its_renderings(anny32: BodyModel) -> None:
    poses, trans = _walk(anny32, 10)
    obs, joints, _, _ = _render(anny32, poses, trans)
    settings = TrackSettings(pose=pe.PoseSettings(height=None, silhouette_points=300,
                                                  boundary_points=100, init_iterations=60))
    track = track_motion(anny32, obs, settings, shape=anny32.default_shape(1)[0])
    assert not track.failed.any()
    with torch.no_grad():
        out = anny32(pose=torch.as_tensor(track.poses, dtype=anny32.dtype),
                     translation=torch.as_tensor(track.translations, dtype=anny32.dtype))
    error = np.linalg.norm(out.joints.double().numpy() - joints, axis=-1).mean(axis=1)
    # the energy's own bias (silhouette pyramid, prior) leaves a few centimetres; a tracker
    # that carries a per-frame bias forward as a velocity drifts to 9 cm by the last frame
    assert error.mean() < 0.06 and error[-1] < 0.08, error
    assert set(track.timings) >= {"init", "fit", "flow"}


def test_tracking_refuses_one_frame_empty_clips_and_missing_flow(anny32: BodyModel) -> None:
    poses, trans = _walk(anny32, 2)
    obs, _, _, _ = _render(anny32, poses, trans)
    one = scene_observations(obs.masks[:1], obs.keypoints[:1], obs.camera)
    with pytest.raises(TrackError, match="at least 2 frames"):
        track_motion(anny32, one)
    empty = replace(obs, no_person=np.ones(2, bool))
    with pytest.raises(TrackError, match="no person"):
        track_motion(anny32, empty)
    with pytest.raises(TrackError, match="flow"):
        track_motion(anny32, replace(obs, flow=None))


def test_closeness_is_the_squared_change_from_the_previous_frame() -> None:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    prev_root = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    prev_body = rng.normal(size=(1, 19, 3))
    prev_t = rng.normal(size=(1, 3))
    previous = tuple(torch.as_tensor(x) for x in (prev_root[None], prev_body, prev_t))
    assert closeness_energy(*previous, previous).item() < 1e-20  # type: ignore[arg-type]
    # a turn of 0.1 rad about any axis, a body change of 0.2 rad and 5 cm of translation
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    root = Rotation.from_rotvec(0.1 * axis).as_matrix() @ prev_root
    body = prev_body.copy()
    body[0, 3, 1] += 0.2
    value = closeness_energy(torch.as_tensor(root[None]), torch.as_tensor(body),
                             torch.as_tensor(prev_t + [0.05, 0, 0]), previous)  # type: ignore[arg-type]
    np.testing.assert_allclose(value.item(), np.sin(0.1) ** 2 + 0.2**2 + 0.5**2, rtol=1e-9)


def test_smoothing_the_landmarks_keeps_lines_and_skips_missing_frames() -> None:
    from monoavatar.fit.tracking import smooth_landmarks

    n = 50
    t = np.arange(n, dtype=np.float64)
    world = np.zeros((n, 33, 4))
    world[..., 0] = 0.01 * t[:, None]  # x moves linearly, 1 cm per frame
    world[..., 1] = 0.2
    world[..., 3] = 1.0
    world[5] = np.nan  # a frame without landmarks
    out = smooth_landmarks(world, 2.0)
    # a line is its own Gaussian average where the whole kernel (± 6 frames) sees landmarks;
    # the missing frame stays missing
    interior = slice(12, n - 7)
    np.testing.assert_allclose(out[interior, :, 0], 0.01 * t[interior, None] * np.ones((1, 33)),
                               atol=1e-12)  # fmt: skip
    assert np.isnan(out[5]).all() and np.isfinite(out[[4, 6]]).all()
    np.testing.assert_allclose(out[..., 1][np.isfinite(out[..., 1])], 0.2, atol=1e-12)
    np.testing.assert_allclose(np.delete(out[:, :, 3], 5, axis=0), 1.0, atol=1e-12)
    # noise shrinks by about the kernel's effective width: σ_out ≈ σ_in / sqrt(2 √π σ)
    rng = np.random.default_rng(0)
    noisy = world.copy()
    noisy[5] = 0.0
    noisy[..., 3] = 1.0
    noisy[..., 2] = rng.normal(0.0, 0.05, (n, 33))
    smoothed = smooth_landmarks(noisy, 2.0)[interior, :, 2]
    expected = 0.05 / np.sqrt(2 * np.sqrt(np.pi) * 2.0)
    assert 0.7 * expected < smoothed.std() < 1.3 * expected
    # σ = 0 leaves them as they are
    np.testing.assert_array_equal(smooth_landmarks(world, 0.0), world)


def _hip_ray_view(camera: PinholeCamera, cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame landmarks (N, 33, 3) → their pixels with confidence 1 (N, 33, 3) and their
    positions about the hips in the hip-ray frame with confidence 1 (N, 33, 4)."""
    from monoavatar.learn.lifter import hip_ray_targets

    px = cam @ np.asarray(camera.K).T
    pixels = np.concatenate([px[..., :2] / px[..., 2:], np.ones((*cam.shape[:2], 1))], -1)
    rel = hip_ray_targets(torch.as_tensor(cam)).numpy()
    return pixels, np.concatenate([rel, np.ones((*cam.shape[:2], 1))], -1)


def test_hip_positions_put_exact_landmarks_back_where_they_were() -> None:
    """Exact pixels and exact hip-relative landmarks in the hip-ray frame give back the hips'
    midpoint (a closed-form round trip), wherever the person stands; a frame with the hips
    unseen, or with too few landmarks, gives none."""
    from monoavatar.fit.tracking import hip_positions

    camera = _camera()
    rng = np.random.default_rng(5)
    cam = rng.normal(0.0, 0.3, (6, 33, 3))
    cam += np.array([[[-0.8, 0.2, 2.5]], [[0.0, 0.0, 4.0]], [[0.6, -0.3, 6.0]],
                     [[0.1, 0.1, 3.0]], [[0.0, 0.0, 3.5]], [[0.2, 0.0, 5.0]]])  # fmt: skip
    pixels, rel = _hip_ray_view(camera, cam)
    pixels[3, 23, 2] = 0.0  # the left hip unseen
    pixels[4, [11, 12, 13, 14, 15, 16, 25, 26, 27, 28], 2] = 0.0  # only the hips
    hips = hip_positions(pixels, rel, np.asarray(camera.K))
    truth = 0.5 * (cam[:, 23] + cam[:, 24])
    np.testing.assert_allclose(hips[[0, 1, 2, 5]], truth[[0, 1, 2, 5]], atol=1e-9)
    assert np.isnan(hips[[3, 4]]).all()
    # landmarks of a body twice as large put it twice as far (depth from apparent size)
    doubled = rel.copy()
    doubled[..., :3] *= 2.0
    far = hip_positions(pixels, doubled, np.asarray(camera.K))
    assert abs(np.linalg.norm(far[1]) / np.linalg.norm(truth[1]) - 2.0) < 0.05


def test_smoothing_a_track_drops_outliers_and_keeps_lines() -> None:
    from monoavatar.fit.tracking import smooth_track

    n = 60
    line = np.stack([np.zeros(n), np.zeros(n), 3.0 + 0.01 * np.arange(n)], -1)
    spoiled = line.copy()
    spoiled[[10, 30]] = [0.0, 0.0, 9.0]  # two wild frames
    spoiled[40] = np.nan  # a frame without an estimate
    # median over 15 frames then a Gaussian of σ 4 (± 12 frames): a line stays a line inside
    interior = slice(20, n - 20)
    np.testing.assert_allclose(smooth_track(line, 15, 4.0)[interior], line[interior], atol=1e-5)
    # a wild frame or a missing one moves a median by at most one step (1 cm here), where a
    # mean over the same frames would move by tens of centimetres
    out = smooth_track(spoiled, 15, 4.0)
    assert np.isfinite(out).all() and np.abs(out - line)[interior].max() < 0.011
    # the median alone (σ = 0), and a frame whose whole window is empty stays empty
    empty = np.full((5, 3), np.nan)
    empty[0] = 1.0
    assert np.isnan(smooth_track(empty, 3, 0.0)[2:]).all()
    assert np.abs(smooth_track(spoiled, 15, 0.0) - line)[interior].max() < 0.011


def test_hip_term_measures_depth_along_the_ray_only() -> None:
    """Zero at the model's own hips and for a position at the same distance from the camera;
    the robust penalty of the depth difference (Geman-McClure) when moved along the ray."""
    from monoavatar.fit import energies
    from monoavatar.fit.tracking import hip_energy

    camera = _camera()
    gen = torch.Generator().manual_seed(4)
    kp = torch.randn(1, 33, 3, generator=gen, dtype=torch.float64) * 0.3
    cam = kp @ torch.as_tensor(camera.R).T + torch.as_tensor(camera.t)
    mid = 0.5 * (cam[:, 23] + cam[:, 24])
    assert hip_energy(kp, camera, mid, 20.0).item() < 1e-20
    turned = mid @ torch.as_tensor(ray_rotations(torch.tensor([0.1, 0.0, 1.0],
                                                              dtype=torch.float64))).T
    assert hip_energy(kp, camera, turned, 20.0).item() < 1e-18
    further = mid * (1 + 0.3 / mid.norm())  # 30 cm further along the ray
    expected = energies.geman_mcclure(torch.tensor(30.0**2, dtype=torch.float64), 20.0)
    assert hip_energy(kp, camera, further, 20.0).item() == pytest.approx(expected.item())


def test_a_bad_detection_does_not_teleport_the_body(anny32: BodyModel) -> None:
    """One frame's keypoints and mask are those of the body a metre further along its viewing
    ray (a detection the keypoints alone explain perfectly at the wrong depth): its re-fit is
    refused, the body stays where the motion predicts, and the frames after it do not drift."""
    poses, trans = _walk(anny32, 10)
    obs, joints, _, _ = _render(anny32, poses, trans)
    bad = 6
    centre = -_camera().R.T @ _camera().t  # the camera's centre, world frame
    ray = joints[bad, 0] - centre
    far = trans[bad : bad + 2] + ray / np.linalg.norm(ray)
    seen, _, _, _ = _render(anny32, poses[bad : bad + 2], far)
    keypoints, masks = obs.keypoints.copy(), obs.masks.copy()
    keypoints[bad], masks[bad] = seen.keypoints[0], seen.masks[0]
    obs = replace(obs, keypoints=keypoints, masks=masks)
    pose = pe.PoseSettings(height=None, silhouette_points=300, boundary_points=100,
                           init_iterations=60)  # fmt: skip
    track = track_motion(anny32, obs, TrackSettings(pose=pose), shape=anny32.default_shape(1)[0])
    assert track.reinitialised[bad]
    with torch.no_grad():
        out = anny32(pose=torch.as_tensor(track.poses, dtype=anny32.dtype),
                     translation=torch.as_tensor(track.translations, dtype=anny32.dtype))
    error = np.linalg.norm(out.joints.double().numpy() - joints, axis=-1).mean(axis=1)
    # the re-fit alone puts the body a metre away, and the next frames follow it part-way
    assert error[bad] < 0.15 and error[bad + 1 :].max() < 0.10, error
