import numpy as np
import pytest
import torch

from monoavatar.core.camera import CameraError, PinholeCamera, plucker, point_line_distance


def test_project_and_pixel_rays_round_trip():
    cam = PinholeCamera.look_at(
        eye=np.array([0.3, 1.0, 2.5]), target=np.zeros(3), up=np.array([0, 1.0, 0]),
        focal_px=600, width=540, height=540,
    )  # fmt: skip
    pts = torch.randn(100, 3, dtype=torch.float64) * 0.5
    px, depth = cam.project(pts)
    o, d = cam.pixel_rays(px)
    m, n = plucker(o, d)
    assert point_line_distance(pts, m, n).max() < 1e-9
    assert (depth > 0).all()


def test_look_at_puts_target_at_image_centre_and_up_is_up():
    cam = PinholeCamera.look_at(np.array([0, 0, 3.0]), np.zeros(3), np.array([0, 1.0, 0]),
                                500, 200, 100)  # fmt: skip
    px, z = cam.project(torch.tensor([[0.0, 0, 0], [0, 1.0, 0]], dtype=torch.float64))
    assert torch.allclose(px[0], torch.tensor([100.0, 50.0], dtype=torch.float64))
    assert px[1, 1] < px[0, 1]  # world up → smaller row
    assert z[0] == pytest.approx(3.0)


def test_pixel_centre_convention():
    cam = PinholeCamera.from_focal(100, 4, 4)
    _, d = cam.pixel_rays(torch.tensor([[2.0, 2.0]], dtype=torch.float64))
    assert torch.allclose(d, torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64))


def test_json_round_trip_and_errors(tmp_path):
    cam = PinholeCamera.from_focal(500, 640, 480, t=np.array([0, 0, 2.0]))
    cam.save_json(tmp_path / "camera.json")
    back = PinholeCamera.load_json(tmp_path / "camera.json")
    np.testing.assert_allclose(back.K, cam.K)
    np.testing.assert_allclose(back.t, cam.t)
    with pytest.raises(CameraError, match="not found"):
        PinholeCamera.load_json(tmp_path / "nope.json")
    with pytest.raises(CameraError, match="rotation"):
        PinholeCamera(K=cam.K, R=2 * np.eye(3), t=np.zeros(3), width=10, height=10)
    with pytest.raises(CameraError, match="K must be 3x3"):
        PinholeCamera(K=np.eye(2), R=np.eye(3), t=np.zeros(3), width=10, height=10)
    assert cam.scaled(0.5).K[0, 0] == 250
