from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from monoavatar.core.camera import CameraError, PinholeCamera
from monoavatar.io import DEFAULT_DIAGONAL_FOV_DEG, default_camera, default_focal, resolve_camera


def test_default_focal_gives_the_assumed_diagonal_fov() -> None:
    f = default_focal(1080, 1920)
    diagonal_fov = 2 * math.degrees(math.atan(math.hypot(1080, 1920) / 2 / f))
    assert diagonal_fov == pytest.approx(DEFAULT_DIAGONAL_FOV_DEG)
    assert f == pytest.approx(0.7413 * math.hypot(1080, 1920), rel=1e-3)
    # orientation-independent, and proportional to the image size
    assert default_focal(1920, 1080) == pytest.approx(f)
    assert default_focal(540, 960) == pytest.approx(f / 2)
    with pytest.raises(ValueError, match="positive"):
        default_focal(0, 10)
    with pytest.raises(ValueError, match="diagonal_fov_deg"):
        default_focal(10, 10, 180.0)


def test_default_camera_centre_and_square_pixels() -> None:
    cam = default_camera(640, 480)
    assert (cam.width, cam.height) == (640, 480)
    assert cam.K[0, 0] == cam.K[1, 1] == pytest.approx(default_focal(640, 480))
    np.testing.assert_allclose(cam.K[:2, 2], [320.0, 240.0])
    assert resolve_camera(640, 480).K.tolist() == cam.K.tolist()


def test_focal_from_user() -> None:
    cam = resolve_camera(100, 50, focal_px=123.0)
    assert cam.K[0, 0] == 123.0 and cam.K[1, 1] == 123.0
    with pytest.raises(CameraError, match="positive"):
        resolve_camera(100, 50, focal_px=-1.0)


def test_camera_json(tmp_path: Path) -> None:
    cam = PinholeCamera(
        K=np.array([[800.0, 0, 330], [0, 810, 250], [0, 0, 1]]),
        R=np.eye(3), t=np.zeros(3), width=640, height=480,
    )
    path = tmp_path / "camera.json"
    cam.save_json(path)
    same = resolve_camera(640, 480, camera_path=path)
    np.testing.assert_allclose(same.K, cam.K)
    half = resolve_camera(320, 240, camera_path=path)  # frames read with max_side
    np.testing.assert_allclose(half.K[:2], cam.K[:2] / 2)
    assert (half.width, half.height) == (320, 240)
    message = r"camera\.json: camera is for 640x480 .* 480x640.*rotation"
    with pytest.raises(CameraError, match=message):
        resolve_camera(480, 640, camera_path=path)
    with pytest.raises(CameraError, match="not both"):
        resolve_camera(640, 480, focal_px=500.0, camera_path=path)
    with pytest.raises(CameraError, match="not found"):
        resolve_camera(640, 480, camera_path=tmp_path / "none.json")
