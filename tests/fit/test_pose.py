"""Pose fitting: the fitter recovers a known turn from renderings of its own body model,
without ever mirroring or flipping the body, also when the detector swaps left and right on
back views; settings validation, errors and the ``.npz`` round trip.

The observations are exact: masks rasterised from the posed Anny body, keypoints projected
from it, with confidence 1 where the keypoint is in front of (or within 8 cm behind) the
visible surface and 0 where the body hides it (as ``monoavatar synth`` marks visibility).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
import torch

from monoavatar.body import lbs
from monoavatar.body.model import BodyModel
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.landmarks import MEDIAPIPE_MIRROR
from monoavatar.eval import align_similarity, pa_mpjpe, silhouette_iou
from monoavatar.fit.pose import (
    PoseFitError,
    PoseSettings,
    PoseTrack,
    evaluate_fit,
    fit_poses,
)
from monoavatar.perception.observations import Observations
from monoavatar.render import rasterize
from tests.fit.observations import scene_observations

# Image size and focal length: the person is about 190 px tall. The silhouette term's 4-level
# pyramid needs that much (at level 3 a person of 90 px is an 11 px blob without limbs).
SIZE, FOCAL = 208, 290.0
# Small but converging settings: about 10 s per 20-frame fit on one core.
SETTINGS = PoseSettings(iterations=40, init_iterations=60, silhouette_points=300,
                        boundary_points=100)  # fmt: skip
FRAMES, STEP_DEG = 20, 10.0  # a half turn: from facing the camera to showing the back


@dataclass(frozen=True)
class Scene:
    obs: Observations
    poses: np.ndarray  # (N, J, 3) ground truth
    joints: np.ndarray  # (N, J, 3) ground-truth joints, world metres
    masks: np.ndarray  # (N, H, W) exact masks
    yaw_deg: np.ndarray  # (N,) turn about the vertical; 0 = facing the camera


def _camera() -> PinholeCamera:
    """As ``synth.scene.make_camera`` places it: 2.6 m in front of the person (who faces +Z),
    a little above the pelvis, looking slightly down."""
    return PinholeCamera.look_at(np.array([0.05, 0.1, 2.6]), np.array([0.0, -0.05, 0.0]),
                                 np.array([0.0, 1.0, 0.0]), FOCAL, SIZE, SIZE)  # fmt: skip


def _turn_poses(body: BodyModel, frames: int, step_deg: float) -> np.ndarray:
    """A turn about the vertical from facing the camera, with an asymmetric A-pose (left elbow
    bent, right leg stepping forward, head bowed), so that a mirrored body cannot match it."""
    pose = np.zeros((frames, body.num_joints, 3))
    pose[:, 0, 1] = np.radians(step_deg) * np.arange(frames)
    j = body.joint_index
    pose[:, j("shoulder_l"), 2], pose[:, j("shoulder_r"), 2] = 0.35, -0.35
    pose[:, j("elbow_l"), 0] = -0.4
    pose[:, j("hip_r"), 0], pose[:, j("knee_r"), 0] = -0.2, 0.3
    pose[:, j("neck"), 0] = 0.1
    return pose


def _render_scene(body: BodyModel, poses: np.ndarray, swap_deg: tuple[float, float] | None = None
                  ) -> Scene:  # fmt: skip
    """Exact masks and keypoints of the posed body; with ``swap_deg``, the keypoints of frames
    whose turn lies in that range have left and right exchanged (a detector that takes a back
    view for a front view)."""
    camera = _camera()
    n = len(poses)
    with torch.no_grad():
        out = body(pose=torch.as_tensor(poses, dtype=body.dtype))
        keypoints_3d = body.keypoints(out.vertices).double()
    masks = np.zeros((n, SIZE, SIZE), bool)
    keypoints = np.zeros((n, 33, 3), np.float32)
    for i in range(n):
        fragments = rasterize(out.vertices[i], body.faces, camera)
        masks[i] = fragments.mask.numpy()
        px, depth = camera.project(keypoints_3d[i])
        px_np, depth_np = px.numpy(), depth.numpy()
        cols, rows = (np.clip(np.floor(px_np[:, k]).astype(int), 0, SIZE - 1) for k in (0, 1))
        in_image = np.all((px_np >= 0) & (px_np < SIZE), axis=1)
        visible = in_image & (depth_np - fragments.depth.numpy()[rows, cols] < 0.08)
        keypoints[i] = np.concatenate([px_np, visible[:, None]], axis=1)
    yaw = np.degrees(poses[:, 0, 1])
    if swap_deg is not None:
        swap = (yaw >= swap_deg[0]) & (yaw <= swap_deg[1])
        assert swap.sum() >= 3
        keypoints[swap] = keypoints[swap][:, list(MEDIAPIPE_MIRROR)]
    obs = scene_observations(masks, keypoints, camera)
    return Scene(obs, poses, out.joints.double().numpy(), masks, yaw)


@dataclass(frozen=True)
class Fitted:
    track: PoseTrack
    joints: np.ndarray  # (N, J, 3)
    masks: np.ndarray  # (N, H, W) the fitted body rasterised


def _fit(body: BodyModel, scene: Scene) -> Fitted:
    torch.manual_seed(0)
    track = fit_poses(body, scene.obs, SETTINGS)
    n = len(scene.obs)
    with torch.no_grad():
        out = body(shape=torch.as_tensor(track.shape, dtype=body.dtype)[None].expand(n, -1),
                   pose=torch.as_tensor(track.poses, dtype=body.dtype),
                   translation=torch.as_tensor(track.translations, dtype=body.dtype))  # fmt: skip
    masks = np.stack([rasterize(v, body.faces, track.camera).mask.numpy() for v in out.vertices])
    return Fitted(track, out.joints.double().numpy(), masks)


@pytest.fixture(scope="module")
def turn(anny32: BodyModel) -> tuple[Scene, Fitted]:
    scene = _render_scene(anny32, _turn_poses(anny32, FRAMES, STEP_DEG))
    return scene, _fit(anny32, scene)


@pytest.fixture(scope="module")
def swapped_turn(anny32: BodyModel) -> tuple[Scene, Fitted]:
    scene = _render_scene(anny32, _turn_poses(anny32, FRAMES, STEP_DEG), swap_deg=(140.0, 220.0))
    return scene, _fit(anny32, scene)


# -- flip checks ------------------------------------------------------------------------------


def _side_pairs(body: BodyModel) -> list[tuple[int, int]]:
    names = body.joint_names
    return [(names.index(n), names.index(n[:-2] + "_r")) for n in names if n.endswith("_l")]


def _sides_swapped(pred: np.ndarray, gt: np.ndarray, pairs: list[tuple[int, int]],
                   rotate: bool) -> np.ndarray:  # fmt: skip
    """(N,) True where, after aligning the frame's fitted joints to the truth, some fitted left
    (right) joint is closer to the true right (left) joint than to the true left (right) one.

    ``rotate``: align by a similarity (Procrustes; catches a mirrored body where its depth
    differs, e.g. a limb bent forward on the wrong side); otherwise by translation and scale
    only (the fit is up to scale; catches mirrored bodies and bodies turned the wrong way,
    which a rotation would align away).
    """
    out = np.zeros(len(pred), bool)
    for i, (p, g) in enumerate(zip(pred, gt, strict=True)):
        if rotate:
            aligned = align_similarity(p, g).apply(p)
        else:
            pc, gc = p - p.mean(0), g - g.mean(0)
            aligned = pc * np.sqrt((gc**2).sum() / (pc**2).sum()) + g.mean(0)
        for a, b in pairs:
            for same, other in ((a, b), (b, a)):
                d_same = np.linalg.norm(aligned[same] - g[same])
                d_other = np.linalg.norm(aligned[same] - g[other])
                out[i] |= bool(d_other <= d_same)
    return out


def _heading_error_deg(poses: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N,) angle between the fitted and the true facing direction (root's +Z in world)."""
    fitted = lbs.axis_angle_to_matrix(torch.as_tensor(poses[:, 0])).numpy()[:, :, 2]
    true = lbs.axis_angle_to_matrix(torch.as_tensor(truth[:, 0])).numpy()[:, :, 2]
    return np.degrees(np.arccos(np.clip((fitted * true).sum(-1), -1.0, 1.0)))


def _assert_never_flipped(body: BodyModel, scene: Scene, fit: Fitted) -> None:
    pairs = _side_pairs(body)
    assert len(pairs) == 7
    procrustes = _sides_swapped(fit.joints, scene.joints, pairs, rotate=True)
    assert not procrustes.any(), f"mirrored body in frames {np.flatnonzero(procrustes)}"
    world = _sides_swapped(fit.joints, scene.joints, pairs, rotate=False)
    assert not world.any(), f"left/right swapped in frames {np.flatnonzero(world)}"
    heading = _heading_error_deg(fit.track.poses, scene.poses)
    assert heading.max() < 60.0, f"heading off by {heading.round(0)} degrees"


def test_flip_checks_catch_mirrored_and_turned_bodies(anny32: BodyModel) -> None:
    """The checks above can fail. A body mirrored through its sagittal plane, and the classic
    failure (the body turned by half a turn with its pose mirrored, so that it projects much
    like the truth), both put the fitted left joints on the true right side. (Procrustes alone
    would align much of that away: an A-pose body is nearly flat, so its mirror image is
    nearly the body turned by half a turn, which a rotation undoes.)"""
    poses = _turn_poses(anny32, 3, 30.0)
    pairs = _side_pairs(anny32)
    with torch.no_grad():
        truth = anny32(pose=torch.as_tensor(poses, dtype=anny32.dtype)).joints.double().numpy()
    # reflection x → −x in the body's frame: the same body with its labels swapped
    mirrored = np.empty_like(truth)
    for i, p in enumerate(poses):
        rot = lbs.axis_angle_to_matrix(torch.as_tensor(p[0])).numpy()
        local = (truth[i] - truth[i, 0]) @ rot
        local[:, 0] *= -1
        mirrored[i] = local @ rot.T + truth[i, 0]
    assert _sides_swapped(mirrored, truth, pairs, rotate=False).all()
    # turned by half a turn with the pose mirrored (left and right joints exchanged)
    flipped = poses.copy()
    flipped[:, 0, 1] += np.pi
    for a, b in pairs:
        flipped[:, [a, b]] = poses[:, [b, a]] * np.array([1.0, -1.0, -1.0])
    with torch.no_grad():
        turned = anny32(pose=torch.as_tensor(flipped, dtype=anny32.dtype)).joints.double().numpy()
    assert _sides_swapped(turned, truth, pairs, rotate=False).all()
    np.testing.assert_allclose(_heading_error_deg(flipped, poses), 180.0, atol=1e-3)
    # and the truth passes
    assert not _sides_swapped(truth, truth, pairs, rotate=True).any()
    assert not _sides_swapped(truth, truth, pairs, rotate=False).any()


# -- recovering a known turn --------------------------------------------------------------------


def test_fit_recovers_a_turn_from_its_own_rendering(
    anny32: BodyModel, turn: tuple[Scene, Fitted]
) -> None:
    scene, fit = turn
    track = fit.track
    n = len(scene.obs)
    assert track.poses.shape == (n, anny32.num_joints, 3) and track.translations.shape == (n, 3)
    assert not track.failed.any()
    assert not track.scale_known
    errors = np.array([pa_mpjpe(fit.joints[i], scene.joints[i]) for i in range(n)])
    # measured 15-27 mm (mean 20); the shape is fitted too; the bar is a 25 mm mean
    assert errors.mean() < 25.0 and errors.max() < 35.0, errors.round(1)
    iou = np.array([silhouette_iou(fit.masks[i], scene.masks[i]) for i in range(n)])
    # measured 0.85-0.93 (median 0.90); boundary pixels weigh heavily on a 190 px person
    assert np.median(iou) > 0.88 and iou.min() > 0.8, iou.round(3)
    np.testing.assert_allclose(track.silhouette_iou, iou, atol=1e-9)
    # keypoints land within a few pixels (measured ≤ 1.5 px)
    assert np.nanmax(track.keypoint_error) < 3.0, track.keypoint_error.round(2)


def test_fit_never_flips_the_body_while_it_turns_away(
    anny32: BodyModel, turn: tuple[Scene, Fitted]
) -> None:
    scene, fit = turn
    _assert_never_flipped(anny32, scene, fit)
    heading = _heading_error_deg(fit.track.poses, scene.poses)
    assert heading.mean() < 10.0, heading.round(1)  # measured 3-10° per frame, mean 6°


def test_swapped_back_view_keypoints_do_not_flip_the_fit(
    anny32: BodyModel, swapped_turn: tuple[Scene, Fitted], turn: tuple[Scene, Fitted]
) -> None:
    scene, fit = swapped_turn
    _assert_never_flipped(anny32, scene, fit)
    n = len(scene.obs)
    errors = np.array([pa_mpjpe(fit.joints[i], scene.joints[i]) for i in range(n)])
    assert errors.mean() < 25.0 and errors.max() < 35.0, errors.round(1)
    # the swapped frames are fitted as if the keypoints had been right
    clean = turn[1]
    swapped = scene.yaw_deg >= 140.0
    difference = _heading_error_deg(fit.track.poses[swapped], clean.track.poses[swapped])
    assert difference.max() < 5.0, difference.round(1)  # measured < 1°


def test_refit_recovers_a_back_view_fit_stalled_far_off(anny32: BodyModel) -> None:
    """A frame whose window fit stalled far from the truth (here a back-diagonal view, 120°,
    fitted from a start turned another 120°: the local fit ends 78° off) is recovered by the
    per-frame re-fit from its alternative starts (half and quarter turns, swapped keypoints)."""
    from monoavatar.fit import pose as posefit
    from monoavatar.fit import pose_energy as pe
    from monoavatar.fit.prior import apose_prior

    poses = _turn_poses(anny32, 1, 0.0)
    poses[0, 0, 1] = np.radians(120.0)
    scene = _render_scene(anny32, poses)
    settings = SETTINGS
    with torch.no_grad():
        rest, joints = anny32.rest_shape(torch.zeros(1, anny32.shape_dim, dtype=anny32.dtype))
    ctx = pe.energy_context(anny32, scene.obs.camera, settings, apose_prior(anny32), rest[0],
                           joints[0])  # fmt: skip
    ids = pe.subset_ids(anny32, settings.silhouette_points, settings.seed)
    sub = pe.make_subset(anny32, rest[0], joints[0], ids)
    frame = pe.frames_at(scene.obs, np.array([0]), settings, anny32.dtype)
    start = poses.copy()
    start[0, 0, 1] += np.radians(120.0)
    p0, t0, e0 = pe.fit_window(ctx, sub, frame, start, np.zeros((1, 3)), None)
    assert _heading_error_deg(p0, poses)[0] > 45.0  # measured 78°: the local fit stalls
    p, _, e = posefit.refit_frame(ctx, sub, frame, p0[0], t0[0], float(e0[0]))
    assert _heading_error_deg(p[None], poses)[0] < 20.0  # measured 13°
    assert e < 0.7 * e0[0]


# -- evaluation, settings, errors, file -------------------------------------------------------


def test_evaluate_fit_of_the_truth_is_perfect(anny32: BodyModel) -> None:
    scene = _render_scene(anny32, _turn_poses(anny32, 3, 60.0))
    shape = anny32.default_shape(1)[0]
    kp_error, iou = evaluate_fit(anny32, shape, scene.poses, np.zeros((3, 3)), scene.obs)
    np.testing.assert_array_equal(iou, 1.0)
    assert kp_error.max() < 1e-3
    # a shifted body loses both
    kp_error, iou = evaluate_fit(anny32, shape, scene.poses, np.tile([0.05, 0.0, 0.0], (3, 1)),
                                 scene.obs)  # fmt: skip
    assert kp_error.min() > 4.0 and iou.max() < 0.9


def test_height_must_be_in_metres() -> None:
    with pytest.raises(ValueError, match="metres"):
        PoseSettings(height=175)
    assert PoseSettings(height=1.75).height == 1.75
    with pytest.raises(ValueError, match="iterations"):
        PoseSettings(iterations=0)


def test_fit_needs_two_frames_with_a_person(anny32: BodyModel) -> None:
    scene = _render_scene(anny32, _turn_poses(anny32, 1, 0.0))
    obs = scene.obs
    n = 3
    masks = np.zeros((n, SIZE, SIZE), bool)
    masks[1] = obs.masks[0]
    keypoints = np.zeros((n, 33, 3), np.float32)
    keypoints[1] = obs.keypoints[0]
    lonely = Observations(masks=masks, keypoints=keypoints,
                          face=np.full((n, 468, 3), np.nan, np.float32),
                          no_person=np.array([True, False, True]),
                          multiple_people=np.zeros(n, bool), camera=obs.camera,
                          frame_indices=np.arange(n), timestamps=np.full(n, np.nan))  # fmt: skip
    with pytest.raises(PoseFitError, match=r"at least 2 frames with a person.*found 1"):
        fit_poses(anny32, lonely, SETTINGS)


def test_pose_track_save_load_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    n, j = 4, 20
    track = PoseTrack(
        body_model="anny:test",
        shape=rng.normal(size=6),
        poses=rng.normal(size=(n, j, 3)),
        translations=rng.normal(size=(n, 3)),
        camera=_camera(),
        frame_indices=np.array([0, 2, 4, 6]),
        keypoint_error=np.array([1.0, np.nan, 2.0, 0.5]),
        silhouette_iou=rng.uniform(size=n),
        energy=rng.uniform(size=n),
        failed=np.array([False, True, False, False]),
        height=1.71,
        scale_known=False,
        seconds=12.5,
        timings={"init": 1.0, "track": 2.5},
    )
    path = tmp_path / "poses.npz"
    track.save(path)
    back = PoseTrack.load(path)
    for name in ("shape", "poses", "translations", "frame_indices", "keypoint_error",
                 "silhouette_iou", "energy", "failed"):  # fmt: skip
        np.testing.assert_array_equal(getattr(back, name), getattr(track, name), err_msg=name)
    assert back.failed.dtype == np.bool_
    for name in ("K", "R", "t"):
        np.testing.assert_array_equal(getattr(back.camera, name), getattr(track.camera, name))
    assert (back.camera.width, back.camera.height) == (SIZE, SIZE)
    assert back.body_model == "anny:test" and back.height == 1.71 and back.seconds == 12.5
    assert back.scale_known is False and back.timings == track.timings
    replace(back, scale_known=True).save(path)
    assert PoseTrack.load(path).scale_known is True
    other = tmp_path / "other.npz"
    np.savez(other, poses=np.zeros(3))
    with pytest.raises(ValueError, match="not a monoavatar poses file"):
        PoseTrack.load(other)


def test_refine_poses_with_offsets_recovers_the_pose_of_a_clothed_body(anny32: BodyModel) -> None:
    """A body in "clothing" (offsets D of 2-4 cm along the normals of the trunk and legs) is
    rendered turning; refine_poses starts from poses turned 12° too little and shifted 3 cm and
    must find the true ones with D on the silhouette, the keypoints staying on the body."""
    from monoavatar.core.geometry import vertex_normals
    from monoavatar.fit.pose import refine_poses

    body, n = anny32, 8
    poses = _turn_poses(body, n, 20.0)
    with torch.no_grad():
        rest, _ = body.rest_shape(body.default_shape(1))
        normals = vertex_normals(rest[0], body.faces)
        height = (rest[0, :, 1] - rest[0, :, 1].min()) / float(np.ptp(rest[0, :, 1].numpy()))
        regions = body.regions
        clothed = (regions == 0) | ((regions != 1) & (height < 0.5))  # trunk and below the hips
        thickness = torch.where(clothed, 0.02 + 0.02 * (height < 0.5).to(rest.dtype), 0.0)
        offsets = normals * thickness[:, None]
    scene = _render_scene(body, poses)  # keypoints of the body itself
    camera = scene.obs.camera
    with torch.no_grad():
        dressed = body(pose=torch.as_tensor(poses, dtype=body.dtype), offsets=offsets)
    masks = np.stack([rasterize(v, body.faces, camera).mask.numpy() for v in dressed.vertices])
    obs = replace(scene.obs, masks=masks)
    start = poses.copy()
    start[:, 0, 1] -= np.radians(12.0)
    track = PoseTrack(
        body_model=body.identity, shape=body.default_shape(1)[0].double().numpy(), poses=start,
        translations=np.tile([0.03, 0.0, 0.0], (n, 1)), camera=camera,
        frame_indices=np.arange(n), keypoint_error=np.zeros(n), silhouette_iou=np.zeros(n),
        energy=np.zeros(n), failed=np.zeros(n, bool), height=1.7, scale_known=False, seconds=0.0,
    )  # fmt: skip
    refined = refine_poses(body, obs, track, offsets, replace(SETTINGS, refine_iterations=30))
    before = _heading_error_deg(start, poses)
    after = _heading_error_deg(refined.poses, poses)
    # measured 0.4-3.5° away from the front view, 7.8° where the body faces the camera (a
    # turn there changes the image only to second order)
    assert before.min() > 11.0 and after.mean() < 4.0 and after.max() < 9.0, after.round(1)
    assert np.median(np.abs(refined.translations), axis=0).max() < 0.015, refined.translations
    # the IoU is of the dressed body (shape + D) with the dressed masks (measured 0.94-0.99)
    assert np.median(refined.silhouette_iou) > 0.93, refined.silhouette_iou.round(3)
    assert not refined.failed.any() and "refine" in refined.timings


def test_subset_poses_keypoints_and_points_as_the_whole_body_does(anny32: BodyModel) -> None:
    """The subset's keypoints (from its per-joint basis) and its points with offsets D equal
    those of the whole body posed by its forward pass and regressed."""
    import monoavatar.fit.pose_energy as pe

    rng = np.random.default_rng(3)
    shape = torch.as_tensor(rng.normal(0.0, 0.5, (1, anny32.shape_dim)), dtype=anny32.dtype)
    pose = torch.as_tensor(rng.normal(0.0, 0.3, (2, anny32.num_joints, 3)), dtype=anny32.dtype)
    translation = torch.as_tensor(rng.normal(0.0, 0.5, (2, 3)), dtype=anny32.dtype)
    offsets = torch.as_tensor(rng.normal(0.0, 0.01, (anny32.num_vertices, 3)),
                              dtype=anny32.dtype)  # fmt: skip
    with torch.no_grad():
        rest, joints = anny32.rest_shape(shape)
        ids = pe.subset_ids(anny32, 200, 0)
        sub = replace(pe.make_subset(anny32, rest[0], joints[0], ids), offsets=offsets[ids])
        keypoints, posed_joints, points = sub.pose(lbs.axis_angle_to_matrix(pose), translation)
        plain = anny32(shape=shape.expand(2, -1), pose=pose, translation=translation)
        with_d = anny32(shape=shape.expand(2, -1), pose=pose, translation=translation,
                        offsets=offsets)  # fmt: skip
    # metres; float32 sums in another order
    np.testing.assert_allclose(keypoints, anny32.keypoints(plain.vertices), atol=5e-5)
    np.testing.assert_allclose(posed_joints, plain.joints, atol=2e-6)
    np.testing.assert_allclose(points, with_d.vertices[:, ids], atol=2e-6)


def test_damaged_poses_files_are_refused_with_a_typed_error(tmp_path: Path) -> None:
    from monoavatar.core.errors import InputFormatError, InputNotFoundError

    rng = np.random.default_rng(2)
    n = 3
    track = PoseTrack(
        body_model="anny:test", shape=np.zeros(4), poses=rng.normal(size=(n, 5, 3)),
        translations=np.zeros((n, 3)), camera=_camera(), frame_indices=np.arange(n),
        keypoint_error=np.zeros(n), silhouette_iou=np.ones(n), energy=np.zeros(n),
        failed=np.zeros(n, bool), height=1.7, scale_known=False, seconds=1.0,
    )  # fmt: skip
    path = tmp_path / "poses.npz"
    track.save(path)
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) // 2])  # truncated, as by a crash or a full disk
    with pytest.raises(InputFormatError, match="not a readable poses file"):
        PoseTrack.load(path)
    replace(track, failed=np.zeros(n + 1, bool)).save(path)
    with pytest.raises(InputFormatError, match="frame counts disagree"):
        PoseTrack.load(path)
    with pytest.raises(InputNotFoundError):
        PoseTrack.load(tmp_path / "missing.npz")


def test_fit_photo_matches_one_synthetic_photo(anny32, anny_local) -> None:  # type: ignore[no-untyped-def]
    """One photo (exact mask, keypoints): the fitted body overlaps the person (IoU) and its
    height matches the photo's within the scale the height option fixes."""
    from monoavatar.fit.pose import fit_photo
    from monoavatar.learn.photo_data import PhotoDataSettings, render_photo
    from tests.fit.observations import scene_observations

    scene = render_photo(anny_local, 3, PhotoDataSettings(image_size=320, texture_size=128))
    obs = scene_observations(scene.mask[None], scene.keypoints[None], scene.camera)
    height = float(np.ptp(scene.subject.rest_vertices[:, 1].numpy()))
    track = fit_photo(anny32, obs, PoseSettings(height=height))
    assert track.poses.shape == (1, anny32.num_joints, 3)
    assert track.silhouette_iou[0] > 0.8
    assert not track.failed[0]
    assert abs(track.height - height) < 0.03
    none = scene_observations(scene.mask[None], scene.keypoints[None], scene.camera)
    none.no_person[0] = True
    with pytest.raises(PoseFitError, match="no person"):
        fit_photo(anny32, none)


# -- frames that face against the turn --------------------------------------------------------


def test_facing_yaw_measures_turns_about_the_cameras_up() -> None:
    from monoavatar.fit.pose import facing_yaw, world_up

    # a camera rolled by 4°: its up is not the world's +Y
    roll = lbs.axis_angle_to_matrix(torch.tensor([0.0, 0.0, np.radians(4.0)])).numpy()
    camera = PinholeCamera(K=np.array([[500.0, 0, 256], [0, 500.0, 256], [0, 0, 1]]),
                           R=roll @ np.diag([1.0, -1.0, -1.0]), t=np.array([0.0, 0.0, 3.0]),
                           width=512, height=512)  # fmt: skip
    up = world_up(camera)
    angles = np.radians([0.0, 30.0, 170.0, -100.0])
    stand = lbs.axis_angle_to_matrix(torch.from_numpy(np.array([0.2, 0.0, 0.0]))).numpy()
    roots = np.stack([lbs.matrix_to_axis_angle(torch.from_numpy(
        lbs.axis_angle_to_matrix(torch.from_numpy(up * a)).numpy() @ stand)).numpy()
        for a in angles])  # fmt: skip
    yaw = facing_yaw(roots, up)
    turned = (yaw - yaw[0] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(turned, angles, atol=1e-9)


def test_half_turn_flips_finds_the_frames_that_face_against_the_turn() -> None:
    from monoavatar.fit.pose import half_turn_flips

    rng = np.random.default_rng(0)
    # an uneven turn (8°-16° between key-frames, a little over one turn) with fitting noise
    yaw = np.cumsum(rng.uniform(np.radians(8.0), np.radians(16.0), 30))
    yaw += rng.normal(0.0, np.radians(3.0), 30)
    assert not half_turn_flips(yaw, np.radians(30.0)).any()
    assert not half_turn_flips(yaw + np.pi, np.radians(30.0)).any()  # all agree: none flipped
    flipped = np.zeros(30, dtype=bool)
    flipped[[0, 1, 17, 18, 19, 29]] = True  # at both ends and a run of three
    found = half_turn_flips(yaw + np.pi * flipped, np.radians(30.0))
    np.testing.assert_array_equal(found, flipped)
    # a frame 50° off is a poor fit, not a flip
    off = yaw.copy()
    off[10] += np.radians(50.0)
    assert not half_turn_flips(off, np.radians(30.0)).any()
    assert not half_turn_flips(yaw[:2] + [0.0, np.pi], 0.5).any()  # too short to tell


def test_a_fit_facing_against_the_turn_is_turned_back(anny32: BodyModel) -> None:
    """Frame 2 of a quarter turn fitted facing backwards (its local fit from a half-turned
    start) is found against its neighbours and re-fitted facing the right way."""
    from monoavatar.fit import pose as posefit
    from monoavatar.fit import pose_energy as pe
    from monoavatar.fit.prior import apose_prior

    poses = _turn_poses(anny32, 5, 20.0)
    scene = _render_scene(anny32, poses)
    with torch.no_grad():
        rest, joints = anny32.rest_shape(torch.zeros(1, anny32.shape_dim, dtype=anny32.dtype))
    ctx = pe.energy_context(anny32, scene.obs.camera, SETTINGS, apose_prior(anny32), rest[0],
                           joints[0])  # fmt: skip
    sub = pe.make_subset(anny32, rest[0], joints[0],
                         pe.subset_ids(anny32, SETTINGS.silhouette_points, SETTINGS.seed))
    start = poses.copy()
    start[2, 0, 1] += np.pi
    p, t, e = pe.fit_window(ctx, sub, pe.frames_at(scene.obs, np.arange(5), SETTINGS,
                                                   anny32.dtype), start, np.zeros((5, 3)), None)
    assert _heading_error_deg(p, poses)[2] > 120.0  # it stays facing the wrong way
    fitted = {i: p[i] for i in range(5)}
    trans = {i: t[i] for i in range(5)}
    energy = np.array(e, dtype=float)
    posefit._turn_back_flips(ctx, sub, scene.obs, np.radians(30.0), fitted, trans, energy)
    heading = _heading_error_deg(np.stack([fitted[i] for i in range(5)]), poses)
    assert heading[2] < 15.0, heading.round(1)
    assert energy[2] < e[2]
