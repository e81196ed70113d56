"""The face error against detected face-mesh landmarks: a closed form for a shifted detection,
zero for the map's own projection, and the pixel shift a known move of the body gives."""

from __future__ import annotations

import numpy as np
import torch

from monoavatar.body import BodyModel
from monoavatar.body.face_map import load_face_map
from monoavatar.core.camera import PinholeCamera
from monoavatar.fit.face import EYE_CORNERS, face_errors, face_rays, relative_face_error


def test_relative_error_of_a_shifted_detection_and_frames_without_a_face() -> None:
    rng = np.random.default_rng(0)
    projected = rng.uniform(0, 500, (3, 468, 2))
    detected = np.concatenate([projected + [3.0, 4.0], np.ones((3, 468, 1))], axis=-1)
    detected[1] = np.nan  # no face in frame 1
    left, right = detected[:, EYE_CORNERS[0], :2], detected[:, EYE_CORNERS[1], :2]
    eyes = np.linalg.norm(left - right, axis=-1)
    out = relative_face_error(projected, detected)
    np.testing.assert_allclose(out[[0, 2]], 5.0 / eyes[[0, 2]])
    assert np.isnan(out[1])


def test_the_error_of_a_moved_face_is_its_image_shift(anny32: BodyModel) -> None:
    face_map = load_face_map(anny32)
    with torch.no_grad():
        rest, _ = anny32.rest_shape(anny32.default_shape(1))
    v = rest[0].double()
    head = face_map.points(v, anny32.faces).mean(0).numpy()
    # a camera 1 m in front of the face (the body faces +Z), image y down
    R = np.diag([1.0, -1.0, -1.0])
    K = np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]])
    camera = PinholeCamera(K, R, -R @ (head + [0.0, 0.0, 1.0]), 640, 480)
    projected, _ = camera.project(face_map.points(v, anny32.faces))
    detected = np.concatenate([projected.numpy(), np.ones((468, 1))], axis=-1)[None]
    assert face_errors(anny32, face_map, v[None], camera, detected)[0] < 1e-9
    # the body 5 mm to its left: the face's points move by about 800 * 0.005 / depth pixels
    moved = face_errors(anny32, face_map, (v + torch.tensor([0.005, 0.0, 0.0]))[None], camera,
                        detected)[0]  # fmt: skip
    depth = 1.0 - (face_map.points(v, anny32.faces).numpy()[:, 2] - head[2])
    eyes = np.linalg.norm(detected[0, EYE_CORNERS[0], :2] - detected[0, EYE_CORNERS[1], :2])
    np.testing.assert_allclose(moved, np.median(800 * 0.005 / depth) / eyes, rtol=0.01)


# -- the face term's rays (Eq. C.6) ---------------------------------------------------------------


def _close_up(body: BodyModel, distance: float = 0.8) -> PinholeCamera:
    """A 640x640 camera ``distance`` in front of the average body's face."""
    face_map = load_face_map(body)
    with torch.no_grad():
        rest, _ = body.rest_shape(body.default_shape(1))
    centre = face_map.points(rest[0].double(), body.faces).mean(0).numpy()
    return PinholeCamera.look_at(eye=centre + [0.0, 0.0, distance], target=centre,
                                 up=np.array([0.0, 1.0, 0.0]), focal_px=900.0, width=640,
                                 height=640)  # fmt: skip


def _posed_detections(body: BodyModel, pose: torch.Tensor, camera: PinholeCamera):
    """The exact projections (F, 468, 3) of the average body's face points posed by ``pose``
    (F, J, 3), the joint transforms, and the canonical vertices."""
    face_map = load_face_map(body)
    shape = body.default_shape(1)
    with torch.no_grad():
        rest, _ = body.rest_shape(shape)
        out = body(shape=shape.expand(len(pose), -1), pose=pose)
        pix, _ = camera.project(face_map.points(out.vertices.double(), body.faces))
    detected = np.concatenate([pix.numpy(), np.ones((len(pose), 468, 1))], axis=-1)
    return face_map, detected, out.transforms, rest[0]


def _head_poses(body: BodyModel) -> torch.Tensor:
    pose = torch.zeros(4, body.num_joints, 3)
    pose[:, 0, 1] = torch.tensor([0.0, 0.4, -0.3, np.pi])  # the last frame seen from behind
    pose[1, body.joint_index("neck"), 0] = 0.25  # nodding
    pose[2, body.joint_index("head"), 2] = -0.3  # tilting
    return pose


def test_face_rays_of_exact_detections_pass_through_the_canonical_face_points(anny32):
    body = anny32
    camera = _close_up(body)
    face_map, detected, transforms, canonical = _posed_detections(body, _head_poses(body), camera)
    detected[2, :10] = np.nan  # a frame with an incomplete face counts as no face
    rays, conf = face_rays(body, face_map, canonical, transforms, detected, camera)
    frames = np.bincount(rays.frame, minlength=4)
    assert frames[0] > 400 and frames[1] > 300  # nearly all landmarks face the camera
    assert frames[2] == 0  # no face: no rays
    assert frames[3] < 5  # seen from behind: at most an outline point at an ear
    assert np.all(conf == 1.0) and len(conf) == len(rays)
    # the line shifted by -delta passes through the dominant vertex exactly when the
    # original one passes through the face point: the unposed rays meet the canonical face
    # up to the blend of skinning weights across a triangle (micrometres on the face)
    d = rays.distances(canonical.double().numpy())
    assert np.median(d) < 2e-5 and d.max() < 3e-4
    assert rays.image_distance.max() < 1e-3  # pixels
    # frame 1 turns 23° away (and nods 14°): left out when faces may turn at most 15°
    frontal, _ = face_rays(body, face_map, canonical, transforms, detected, camera,
                           max_turn_deg=15.0)  # fmt: skip
    assert np.array_equal(np.unique(frontal.frame), [0])
    assert np.sum(frontal.frame == 0) == frames[0]


def test_a_detection_shifted_by_k_pixels_misses_by_k_depth_over_focal(anny32):
    body = anny32
    camera = _close_up(body, distance=0.8)
    pose = torch.zeros(1, body.num_joints, 3)
    face_map, detected, transforms, canonical = _posed_detections(body, pose, camera)
    detected[..., 0] += 4.5
    rays, _ = face_rays(body, face_map, canonical, transforms, detected, camera)
    assert len(rays) > 400
    # each landmark's ray misses its canonical face point by 4.5 px * depth / focal (the
    # rays lie near the optical axis; the depth taken at the ray's vertex, millimetres from
    # the face point: within 2 %)
    v = canonical.double().numpy()
    depth = camera.world_to_camera(torch.as_tensor(v[rays.vertex_ids]))[:, 2].numpy()
    d = rays.distances(v)
    assert np.median(np.abs(d / (4.5 * depth / 900.0) - 1)) < 0.02
