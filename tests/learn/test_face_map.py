"""Building the face-mesh landmark map: the back-projection against a plane in closed form, the
shipped map reproduced by the builder, and the map checked against the face mesh run on views
it was not built from."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from monoavatar.body import BodyModel
from monoavatar.body.face_map import FaceMap, load_face_map
from monoavatar.cli import main
from monoavatar.core.camera import PinholeCamera
from monoavatar.learn import face_map as fm
from monoavatar.perception.mediapipe_backend import MediaPipeFaceMesh
from monoavatar.render import rasterize


def test_back_projection_lands_on_the_triangle_under_the_pixel() -> None:
    # a square 2 m x 2 m in the plane z = 3 (tilted about y) seen by a camera at the origin
    tilt = np.radians(30)
    corners = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    rot = np.array([[np.cos(tilt), 0, np.sin(tilt)], [0, 1, 0], [-np.sin(tilt), 0, np.cos(tilt)]])
    vertices = corners @ rot.T + [0.0, 0.0, 3.0]
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    K = np.array([[300.0, 0, 100], [0, 300.0, 100], [0, 0, 1]])
    camera = PinholeCamera(K, np.eye(3), np.zeros(3), 200, 200)
    face_id = rasterize(torch.as_tensor(vertices), torch.as_tensor(faces), camera).face_id.numpy()
    pixels = np.random.default_rng(0).uniform(60, 140, (50, 2))
    points = fm.back_project(vertices, faces, camera, face_id, pixels)
    normal = rot[:, 2]
    np.testing.assert_allclose((points - [0.0, 0.0, 3.0]) @ normal, 0.0, atol=1e-9)  # on it
    projected, _ = camera.project(torch.as_tensor(points))
    np.testing.assert_allclose(projected.numpy(), pixels, atol=1e-6)  # on the pixels' rays
    # off the square: NaN, unless within reach of its outline (then on its outline)
    off = np.array([[5.0, 100.0]])  # left of the square (its near edge projects to x ≈ 26)
    assert np.isnan(fm.back_project(vertices, faces, camera, face_id, off)).all()
    near = fm.back_project(vertices, faces, camera, face_id, off, reach_px=500.0)
    assert np.isfinite(near).all()


def test_train_face_map_reproduces_the_shipped_map(anny32: BodyModel, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["train", "face-map", "-o", str(tmp_path)]) == 0
    assert "the views agree within" in capsys.readouterr().out
    built = FaceMap.load(tmp_path / "face_map_anny.npz")
    shipped = load_face_map(anny32)
    with torch.no_grad():
        rest, _ = anny32.rest_shape(anny32.default_shape(1))
        a = built.points(rest[0], anny32.faces).numpy()
        b = shipped.points(rest[0], anny32.faces).numpy()
    assert np.linalg.norm(a - b, axis=1).max() < 5e-4
    # the preview: the render with the detections (red) and the map (green) drawn on it
    preview = np.asarray(Image.open(tmp_path / "face_map_preview.png"))
    assert ((preview == [40, 255, 40]).all(-1).sum() > 1000
            and (preview == [255, 40, 40]).all(-1).sum() > 200)  # fmt: skip


def test_the_map_predicts_the_face_mesh_in_views_it_was_not_built_from(anny32: BodyModel
                                                                         ) -> None:  # fmt: skip
    settings = fm.FaceMapSettings()
    texture = fm.painted_face_texture(anny32, settings)
    detector = MediaPipeFaceMesh(max_faces=1)
    with torch.no_grad():
        rest, _ = anny32.rest_shape(anny32.default_shape(1))
        points = load_face_map(anny32).points(rest[0].double(), anny32.faces)
    shuffled = points[torch.as_tensor(np.random.default_rng(0).permutation(468))]
    for yaw, distance in ((-25.0, 0.7), (25.0, 0.7), (15.0, 1.2)):
        camera = fm.head_camera(anny32, yaw, replace(settings, distance_m=distance))
        image, _ = fm.render_head(anny32, camera, texture)
        detected = np.asarray(detector.detect(image)[0], np.float64)[:, :2]
        eyes = np.linalg.norm(detected[33] - detected[263])  # outer eye corners, pixels
        error = np.linalg.norm(camera.project(points)[0].numpy() - detected, axis=1)
        assert np.median(error) < 0.08 * eyes, (yaw, np.median(error), eyes)
        # the check has power: landmarks put on each other's places miss by far more
        wrong = np.linalg.norm(camera.project(shuffled)[0].numpy() - detected, axis=1)
        assert np.median(wrong) > 0.3 * eyes
