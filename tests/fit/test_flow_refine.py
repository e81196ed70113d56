"""Flow refinement of key-frame poses: correspondences from a known flow field, and a pose
recovered from renders of a textured body, which the silhouette alone does not recover.

The frames are renders of Anny with a blob texture at known poses (exact masks; keypoints
projected from the body with 5 px of noise, all marked visible). The fits start from poses a
few degrees off: the root turned about the vertical, both upper arms twisted about their own
axes (rotations that keypoints and outline barely show).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from monoavatar.body.model import BodyModel
from monoavatar.core.camera import PinholeCamera
from monoavatar.fit.flow_refine import (
    FlowRefineSettings,
    contour_correspondences,
    flow_correspondences,
    refine_poses_with_flow,
)
from monoavatar.fit.pose import PoseSettings, PoseTrack
from monoavatar.perception.observations import Observations
from monoavatar.render import rasterize, render_textured
from tests.fit.observations import scene_observations

SIZE, FOCAL = 256, 360.0
YAWS_DEG = (0.0, 40.0, 80.0, 120.0)
# keypoint noise: about 2 % of the person's 235 px height, as a detector's errors on real video
KEYPOINT_NOISE_PX = 5.0


def _camera() -> PinholeCamera:
    return PinholeCamera.look_at(np.array([0.05, 0.1, 2.6]), np.array([0.0, -0.05, 0.0]),
                                 np.array([0.0, 1.0, 0.0]), FOCAL, SIZE, SIZE)  # fmt: skip


def _blob_texture(size: int = 256, seed: int = 0) -> np.ndarray:
    """(S, S, 3) float64 in [0, 1]: smooth random colour blobs a few texels across (flow
    needs structure to match)."""
    import cv2

    rng = np.random.default_rng(seed)
    noise = rng.random((size // 8, size // 8, 3)).astype(np.float32)
    tex = cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC)
    return np.clip(tex, 0.0, 1.0).astype(np.float64)


def _poses(body: BodyModel) -> np.ndarray:
    j = body.joint_index
    pose = np.zeros((len(YAWS_DEG), body.num_joints, 3))
    pose[:, 0, 1] = np.radians(YAWS_DEG)
    pose[:, j("shoulder_l"), 2], pose[:, j("shoulder_r"), 2] = 0.45, -0.45
    pose[:, j("elbow_l"), 0], pose[:, j("elbow_r"), 0] = -0.5, -0.3
    return pose


def _perturbed(body: BodyModel, poses: np.ndarray) -> np.ndarray:
    """The root turned by 5° about the vertical and both shoulders twisted by 12° about the
    upper arm (its rest axis is roughly sideways: X)."""
    out = poses.copy()
    out[:, 0, 1] += np.radians(5.0)
    for side in ("l", "r"):
        out[:, body.joint_index(f"shoulder_{side}"), 0] += np.radians(12.0)
    return out


def _scene(body: BodyModel) -> tuple[Observations, np.ndarray, np.ndarray, np.ndarray]:
    camera = _camera()
    poses = _poses(body)
    texture = _blob_texture()
    rng = np.random.default_rng(1)
    with torch.no_grad():
        out = body(pose=torch.as_tensor(poses, dtype=body.dtype))
        keypoints_3d = body.keypoints(out.vertices).double()
    n = len(poses)
    masks = np.zeros((n, SIZE, SIZE), bool)
    images = np.zeros((n, SIZE, SIZE, 3), np.uint8)
    keypoints = np.zeros((n, 33, 3), np.float32)
    tex = torch.as_tensor(texture)
    for i in range(n):
        frags = rasterize(out.vertices[i], body.faces, camera)
        masks[i] = frags.mask.numpy()
        px = camera.project(keypoints_3d[i])[0].numpy()
        keypoints[i, :, :2] = px + rng.normal(0.0, KEYPOINT_NOISE_PX, px.shape)
        keypoints[i, :, 2] = 1.0
        background = np.full((SIZE, SIZE, 3), 0.45) + 0.05 * rng.random((SIZE, SIZE, 1))
        image = render_textured(out.vertices[i].double(), body.faces, frags, body.uv,
                                body.face_uv, tex, background=background)  # fmt: skip
        images[i] = (np.clip(image.numpy(), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    obs = scene_observations(masks, keypoints, camera)
    return obs, images, poses, texture


def _track(body: BodyModel, poses: np.ndarray, camera: PinholeCamera) -> PoseTrack:
    n = len(poses)
    return PoseTrack(
        body_model=body.identity, shape=body.default_shape(1)[0].double().numpy(), poses=poses,
        translations=np.zeros((n, 3)), camera=camera, frame_indices=np.arange(n),
        keypoint_error=np.zeros(n), silhouette_iou=np.ones(n), energy=np.zeros(n),
        failed=np.zeros(n, bool), height=1.7, scale_known=False, seconds=0.0,
    )  # fmt: skip


def _vertex_error_mm(body: BodyModel, track: PoseTrack, poses: np.ndarray) -> float:
    """Mean distance between the track's posed vertices and the true ones, mm."""
    with torch.no_grad():
        fit = body(pose=torch.as_tensor(track.poses, dtype=body.dtype),
                   translation=torch.as_tensor(track.translations, dtype=body.dtype))  # fmt: skip
        true = body(pose=torch.as_tensor(poses, dtype=body.dtype))
    return float((fit.vertices - true.vertices).norm(dim=-1).mean()) * 1000.0


def _visible_reprojection_px(body: BodyModel, track: PoseTrack, poses: np.ndarray,
                             camera: PinholeCamera) -> float:  # fmt: skip
    """Mean image distance between the track's and the true projections of the vertices
    visible in the true render (what the texture sees), pixels."""
    with torch.no_grad():
        fit = body(pose=torch.as_tensor(track.poses, dtype=body.dtype),
                   translation=torch.as_tensor(track.translations, dtype=body.dtype))  # fmt: skip
        true = body(pose=torch.as_tensor(poses, dtype=body.dtype))
    errors = []
    for k in range(len(poses)):
        frags = rasterize(true.vertices[k], body.faces, camera)
        px, z = (t.numpy() for t in camera.project(true.vertices[k].double()))
        col = np.clip(px[:, 0].astype(int), 0, SIZE - 1)
        row = np.clip(px[:, 1].astype(int), 0, SIZE - 1)
        visible = np.abs(frags.depth.numpy()[row, col] - z) < 0.01
        fitted = camera.project(fit.vertices[k].double())[0].numpy()
        errors.append(np.linalg.norm(fitted - px, axis=1)[visible].mean())
    return float(np.mean(errors))


def test_correspondences_follow_a_known_flow_and_skip_hidden_points(anny32: BodyModel) -> None:
    camera = _camera()
    with torch.no_grad():
        verts = anny32(pose=torch.as_tensor(_poses(anny32)[:1], dtype=anny32.dtype))
    v = verts.vertices[0].double().numpy()
    frags = rasterize(verts.vertices[0], anny32.faces, camera)
    mask = np.ones((SIZE, SIZE), bool)
    flow = np.zeros((SIZE, SIZE, 2), np.float32)
    flow[..., 0], flow[..., 1] = 2.5, -1.5
    flow[:, SIZE // 2 :, 0] = 20.0  # the right half moves too far to be trusted
    settings = FlowRefineSettings(edge_margin=0.0)
    targets, valid = flow_correspondences(v, camera, frags, flow, mask, settings)

    px = camera.project(torch.as_tensor(v))[0].numpy()
    left = px[:, 0] < SIZE // 2 - 1
    right = px[:, 0] >= SIZE // 2
    np.testing.assert_allclose(targets[valid] - px[valid], [[2.5, -1.5]] * int(valid.sum()),
                               atol=1e-5)  # fmt: skip
    assert not valid[right].any()
    # the front of the body facing the camera is visible, the back is not: about half the
    # vertices on the left half are valid
    share = valid[left].mean()
    assert 0.3 < share < 0.75, share
    # a point's depth decides: the same vertices pushed 5 cm back are hidden (but for a few
    # at outline edges, about 3 %, which then project onto a surface 5 cm behind)
    behind = v + (camera.R.T @ np.array([0.0, 0.0, 0.05]))
    _, valid_behind = flow_correspondences(behind, camera, frags, flow, mask, settings)
    assert valid_behind[valid].mean() < 0.05, valid_behind[valid].mean()
    # with a margin, only points at least that far inside the render's outline
    import cv2

    _, valid_margin = flow_correspondences(v, camera, frags, flow, mask,
                                           FlowRefineSettings(edge_margin=3.0))  # fmt: skip
    assert valid_margin.sum() > 0.3 * valid.sum() and not (valid_margin & ~valid).any()
    inside = cv2.distanceTransform(frags.mask.numpy().astype(np.uint8), cv2.DIST_L2, 5)
    col, row = (np.clip(np.floor(px[:, k]).astype(int), 0, SIZE - 1) for k in (0, 1))
    assert inside[row, col][valid_margin].min() >= 2.9
    assert inside[row, col][valid & ~valid_margin].max() < 3.1
    # targets must land on the person
    _, valid_off = flow_correspondences(v, camera, frags, flow, np.zeros_like(mask), settings)
    assert not valid_off.any()


@pytest.mark.slow
def test_flow_recovers_turns_keypoints_and_silhouette_do_not_show(anny32: BodyModel) -> None:
    obs, images, poses, texture = _scene(anny32)
    start = _track(anny32, _perturbed(anny32, poses), obs.camera)
    pose_settings = PoseSettings(silhouette_points=600, boundary_points=150, window=4,
                                 smooth_weight=0.0)  # fmt: skip
    shape = anny32.default_shape(1)[0].double().numpy()
    offsets = np.zeros((anny32.num_vertices, 3))
    results = {}
    for name, weight in (("flow", FlowRefineSettings().weight), ("keypoints and silhouette", 1e-6)):
        track = start
        for _ in range(2):  # the render is made from the current poses: two rounds
            settings = FlowRefineSettings(iterations=30, weight=weight, contour_weight=0.0)
            track = refine_poses_with_flow(anny32, obs, images, track, shape, offsets, texture,
                                           None, settings, pose_settings)  # fmt: skip
        results[name] = (_visible_reprojection_px(anny32, track, poses, obs.camera),
                         _vertex_error_mm(anny32, track, poses))  # fmt: skip
    before = (_visible_reprojection_px(anny32, start, poses, obs.camera),
              _vertex_error_mm(anny32, start, poses))  # fmt: skip
    flow, plain = results["flow"], results["keypoints and silhouette"]
    # measured: 3.4 px / 30 mm at the start; 1.7 px / 18 mm with the flow; without it the
    # noisy keypoints win (3.3 px / 55 mm: one frame turns 16° the wrong way)
    assert flow[0] < 0.6 * before[0] and flow[1] < 0.7 * before[1], (before, results)
    assert flow[0] < 0.6 * plain[0] and flow[1] < 0.5 * plain[1], (before, results)


def _sphere(radius: float, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=5, radius=radius)
    return np.asarray(mesh.vertices) + centre, np.asarray(mesh.faces)


def test_contour_correspondences_on_a_sphere_measure_its_offset_and_skip_hidden_ones() -> None:
    """A sphere on the optical axis projects to a disc of radius f r / sqrt(D² − r²); the
    observed mask is that disc moved by a known sub-pixel offset. The matched vertices lie on
    the sphere's contour generator, their edge targets on the moved circle, and the offsets
    along the edge normals give back the move. A second sphere hidden behind the first gets no
    match, although its outline projects 2.3 px inside the first one's, nearer to the mask's
    edge than the first one's on the side the mask moved inwards."""
    camera = PinholeCamera(K=np.array([[FOCAL, 0, SIZE / 2], [0, FOCAL, SIZE / 2], [0, 0, 1]]),
                           R=np.eye(3), t=np.zeros(3), width=SIZE, height=SIZE)  # fmt: skip
    radius, depth = 0.3, 2.6
    front_v, front_f = _sphere(radius, np.array([0.0, 0.0, depth]))
    # hidden: projected radius f r' / sqrt(D'² − r'²) ≈ 39.5 px < 41.8 px
    back_v, back_f = _sphere(0.327, np.array([0.0, 0.0, 3.0]))
    vertices = np.concatenate([front_v, back_v])
    faces = np.concatenate([front_f, back_f + len(front_v)])
    frags = rasterize(vertices, faces, camera)
    disc = FOCAL * radius / np.sqrt(depth**2 - radius**2)  # about 41.8 px
    move = np.array([1.2, -0.7])
    ys, xs = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    mask = np.hypot(xs - SIZE / 2 - move[0], ys - SIZE / 2 - move[1]) < disc

    settings = FlowRefineSettings()
    ids, targets, normals = contour_correspondences(vertices, faces, camera, frags, mask,
                                                    settings)  # fmt: skip
    assert len(ids) > 150, len(ids)  # the disc's outline is about 260 px long
    assert (ids < len(front_v)).all()  # none on the hidden sphere
    view = vertices[ids] / np.linalg.norm(vertices[ids], axis=1, keepdims=True)
    normal_3d = (vertices[ids] - [0.0, 0.0, depth]) / radius
    assert np.abs(np.einsum("nc,nc->n", view, normal_3d)).max() <= settings.contour_max_cos
    # targets on the moved circle (sub-pixel edge of a binary mask), normals pointing out
    centre = np.array([SIZE / 2, SIZE / 2]) + move
    deviation = np.linalg.norm(targets - centre, axis=1) - disc
    assert np.abs(deviation).mean() < 0.1 and np.abs(deviation).max() < 0.5, deviation
    outward = (targets - centre) / np.linalg.norm(targets - centre, axis=1, keepdims=True)
    assert np.einsum("nc,nc->n", outward, normals).min() > 0.95
    # the edge lies `move` away from the projections, along the normals: least squares
    projected = camera.project(torch.as_tensor(vertices[ids]))[0].numpy()
    along = np.einsum("nc,nc->n", targets - projected, normals)
    estimate, *_ = np.linalg.lstsq(normals, along, rcond=None)
    np.testing.assert_allclose(estimate, move, atol=0.15)


def test_contour_term_pulls_the_outline_onto_the_mask(anny32: BodyModel) -> None:
    """Poses moved 1.5 cm sideways (about 2 px) and with the arms raised by 4°: one
    refinement with the outline term brings the rendered outline closer to the mask than the
    silhouette terms of the pose energy alone (the flow term off in both). Measured: 1 − IoU
    0.209 at the start, 0.013 with the outline term, 0.223 without (the noisy keypoints
    win)."""
    obs, images, poses, texture = _scene(anny32)
    start_poses = poses.copy()
    for side, sign in (("l", 1.0), ("r", -1.0)):
        start_poses[:, anny32.joint_index(f"shoulder_{side}"), 2] += sign * np.radians(4.0)
    start = replace(_track(anny32, start_poses, obs.camera),
                    translations=np.tile([0.015, 0.0, 0.0], (len(poses), 1)))  # fmt: skip
    pose_settings = PoseSettings(silhouette_points=600, boundary_points=150, smooth_weight=0.0)
    shape = anny32.default_shape(1)[0].double().numpy()
    offsets = np.zeros((anny32.num_vertices, 3))

    def outline_error(track: PoseTrack) -> float:
        """1 − IoU of the rendered body with the mask, mean over frames."""
        with torch.no_grad():
            out = anny32(pose=torch.as_tensor(track.poses, dtype=anny32.dtype),
                         translation=torch.as_tensor(track.translations, dtype=anny32.dtype))
        ious = []
        for k in range(len(poses)):
            covered = rasterize(out.vertices[k], anny32.faces, obs.camera).mask.numpy()
            ious.append((covered & obs.masks[k]).sum() / (covered | obs.masks[k]).sum())
        return 1.0 - float(np.mean(ious))

    errors = {}
    for weight in (0.0, FlowRefineSettings().contour_weight):
        settings = FlowRefineSettings(weight=1e-6, contour_weight=weight)
        track = refine_poses_with_flow(anny32, obs, images, start, shape, offsets, texture, None,
                                       settings, pose_settings)  # fmt: skip
        errors[weight] = outline_error(track)
    before = outline_error(start)
    with_contour, without = errors[FlowRefineSettings().contour_weight], errors[0.0]
    assert with_contour < 0.5 * before, (before, errors)
    assert with_contour < 0.7 * without, (before, errors)


def test_frames_fitted_side_by_side_match_one_by_one(anny32: BodyModel) -> None:
    """The frames are independent: preparing them in 3 threads and fitting them in one batch
    gives the poses that one thread and batches of one frame give (no state shared between
    frames, each its own padded points, results kept in frame order), up to rounding: runs in
    threads are not bit-identical (see ``frame_pool``)."""
    obs, images, poses, texture = _scene(anny32)
    start = _track(anny32, _perturbed(anny32, poses), obs.camera)
    pose_settings = PoseSettings(silhouette_points=600, boundary_points=150, smooth_weight=0.0)
    shape = anny32.default_shape(1)[0].double().numpy()
    offsets = np.zeros((anny32.num_vertices, 3))
    tracks = [refine_poses_with_flow(anny32, obs, images, start, shape, offsets, texture, None,
                                     FlowRefineSettings(iterations=5, workers=w, batch=b),
                                     pose_settings)
              for w, b in ((1, 1), (3, 30))]  # fmt: skip
    moved = np.abs(tracks[0].poses - start.poses).max()
    assert moved > 2e-3  # the fit moved the poses, by far more than the tolerance below
    np.testing.assert_allclose(tracks[1].poses, tracks[0].poses, atol=1e-4)
    np.testing.assert_allclose(tracks[1].translations, tracks[0].translations, atol=1e-5)


def test_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="points"):
        FlowRefineSettings(points=0)
    with pytest.raises(ValueError, match="workers"):
        FlowRefineSettings(workers=0)
    with pytest.raises(ValueError, match="batch"):
        FlowRefineSettings(batch=0)
    with pytest.raises(ValueError, match="max_flow"):
        FlowRefineSettings(max_flow=0.0)
    with pytest.raises(ValueError, match="contour_max_cos"):
        FlowRefineSettings(contour_max_cos=1.0)
    with pytest.raises(ValueError, match="contour_weight"):
        FlowRefineSettings(contour_weight=-1.0)


def test_frame_counts_must_match(anny32: BodyModel) -> None:
    obs, images, poses, texture = _scene(anny32)
    track = _track(anny32, poses, obs.camera)
    with pytest.raises(ValueError, match="frames"):
        refine_poses_with_flow(anny32, obs, images[:2], track, track.shape,
                               np.zeros((anny32.num_vertices, 3)), texture, None)  # fmt: skip
