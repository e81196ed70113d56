"""The face error against detected face-mesh landmarks: a closed form for a shifted detection,
zero for the map's own projection, and the pixel shift a known move of the body gives."""

from __future__ import annotations

import numpy as np
import torch

from monoavatar.body import BodyModel
from monoavatar.body.face_map import load_face_map
from monoavatar.core.camera import PinholeCamera
from monoavatar.fit.face import EYE_CORNERS, face_errors, relative_face_error


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
