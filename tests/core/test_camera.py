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


def test_camera_rays_scaled_by_depth_are_the_projected_points():
    """camera_rays inverts the projection: a camera-frame point is its pixel's ray times its
    depth (rays have z = 1)."""
    from monoavatar.core.geometry import camera_rays

    K = np.array([[610.0, 0, 250.5], [0, 590.0, 281.25], [0, 0, 1]])
    rng = np.random.default_rng(4)
    pts = rng.normal(size=(7, 5, 3)) * 0.4 + np.array([0.1, -0.2, 3.0])
    uvw = pts @ K.T
    pixels = uvw[..., :2] / uvw[..., 2:]
    rays = camera_rays(pixels, K)
    assert rays.shape == (7, 5, 3) and np.allclose(rays[..., 2], 1.0)
    np.testing.assert_allclose(rays * pts[..., 2:], pts, atol=1e-12)


def test_hip_ray_rotation_turns_the_axis_onto_the_hips_bisector():
    from monoavatar.core.geometry import hip_ray_rotations
    from monoavatar.core.landmarks import HIP_LANDMARKS, MEDIAPIPE_LANDMARKS

    assert [MEDIAPIPE_LANDMARKS[i] for i in HIP_LANDMARKS] == ["left_hip", "right_hip"]
    rng = np.random.default_rng(5)
    points = torch.as_tensor(rng.normal(size=(4, 33, 3)) * 0.3 + np.array([0.8, 0.3, 2.5]))
    R = hip_ray_rotations(points)
    unit = points / points.norm(dim=-1, keepdim=True)
    bisector = unit[:, 23] + unit[:, 24]
    bisector = bisector / bisector.norm(dim=-1, keepdim=True)
    assert torch.allclose(R[..., :, 2], bisector, atol=1e-12)  # the camera axis, turned
    eye = torch.eye(3, dtype=R.dtype).expand_as(R)
    assert torch.allclose(R.transpose(-1, -2) @ R, eye, atol=1e-12)
    assert torch.allclose(torch.linalg.det(R), torch.ones(4, dtype=R.dtype))
    # any length: rays and points along them give the same frame
    assert torch.allclose(hip_ray_rotations(points * 3.0), R, atol=1e-12)
