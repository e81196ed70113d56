"""The flow renderer (Sec. A.3.2) against the closed-form flow of a rigidly moved plane and
finite differences, and the flow energy (Eq. A.1) against hand-computed sums."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from tests.gradcheck import directional_gradcheck

from monoavatar.core.camera import PinholeCamera
from monoavatar.render import rasterize
from monoavatar.render.flow import flow_energy, render_flow

F, W, H, Z0 = 120.0, 64, 48, 2.0


def _camera() -> PinholeCamera:
    """At the origin, looking down +z (R = I, t = 0)."""
    return PinholeCamera.from_focal(F, W, H, R=np.eye(3), t=np.zeros(3))


def _plane(n: int = 9, half: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """A grid of (n, n) vertices in the plane z = Z0, facing the camera; two triangles a cell."""
    xs = np.linspace(-half, half, n)
    x, y = np.meshgrid(xs, xs * 0.8)
    verts = np.stack([x.ravel(), y.ravel(), np.full(n * n, Z0)], axis=1)
    faces = []
    for r in range(n - 1):
        for c in range(n - 1):
            i = r * n + c
            faces += [[i, i + n, i + 1], [i + 1, i + n, i + n + 1]]
    return verts, np.asarray(faces)


def _visible(verts: np.ndarray, faces: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    """The faces, wound so that the camera sees their front (back faces are culled)."""
    frags = rasterize(verts, faces, camera)
    if not bool((frags.face_id >= 0).any()):
        return faces[:, ::-1].copy()
    return faces


def test_rigidly_moved_plane_matches_the_closed_form_flow() -> None:
    camera = _camera()
    verts, faces = _plane()
    faces = _visible(verts, faces, camera)
    rot = Rotation.from_euler("xyz", [4.0, -6.0, 3.0], degrees=True).as_matrix()
    move = np.array([0.03, -0.02, 0.05])
    centre = np.array([0.0, 0.0, Z0])
    previous = (verts - centre) @ rot.T + centre + move
    rendered = render_flow(torch.as_tensor(verts), torch.as_tensor(previous), faces, camera)
    mask = rendered.mask.numpy()
    assert mask.mean() > 0.5  # the plane fills most of the image
    rows, cols = np.nonzero(mask)
    px = np.stack([cols + 0.5, rows + 0.5], axis=1)  # pixel centres
    # the surface point under each pixel in frame i, moved rigidly, projected
    X = np.stack([(px[:, 0] - W / 2) / F * Z0, (px[:, 1] - H / 2) / F * Z0, np.full(len(px), Z0)],
                 axis=1)  # fmt: skip
    Xp = (X - centre) @ rot.T + centre + move
    expected = F * Xp[:, :2] / Xp[:, 2:3] + np.array([W / 2, H / 2]) - px
    got = rendered.flow.numpy()[rows, cols]
    assert np.abs(expected).max() > 2.0  # a motion of several pixels
    np.testing.assert_allclose(got, expected, atol=2e-3)
    assert np.all(rendered.flow.numpy()[~mask] == 0.0)


def test_no_motion_renders_no_flow() -> None:
    camera = _camera()
    verts, faces = _plane()
    faces = _visible(verts, faces, camera)
    rendered = render_flow(verts, verts.copy(), faces, camera)
    assert rendered.mask.any()
    assert float(rendered.flow.abs().max()) < 1e-9


def test_gradients_match_finite_differences() -> None:
    camera = _camera()
    verts, faces = _plane(5)
    faces = _visible(verts, faces, camera)
    rng = np.random.default_rng(0)
    now = torch.as_tensor(verts + rng.normal(scale=0.01, size=verts.shape))
    before = now + torch.as_tensor(rng.normal(scale=0.02, size=verts.shape))
    frags = rasterize(now, faces, camera)  # visibility held fixed, as in the fit
    fd, ad = directional_gradcheck(lambda p: render_flow(now, p, faces, camera, frags).flow,
                                   before)  # fmt: skip
    assert ad == pytest.approx(fd, rel=1e-6, abs=1e-9)
    fd, ad = directional_gradcheck(lambda v: render_flow(v, before, faces, camera, frags).flow,
                                   now)  # fmt: skip
    assert ad == pytest.approx(fd, rel=1e-6, abs=1e-9)


def test_flow_energy_is_the_squared_difference_on_covered_valid_pixels() -> None:
    camera = _camera()
    verts, faces = _plane()
    faces = _visible(verts, faces, camera)
    rendered = render_flow(verts, verts + np.array([0.01, 0.0, 0.0]), faces, camera)
    covered = int(rendered.mask.sum())
    same = rendered.flow.detach().clone()
    assert float(flow_energy(rendered, same)) == pytest.approx(0.0, abs=1e-12)
    shifted = same + torch.tensor([1.0, 2.0], dtype=same.dtype)  # |(1, 2)|² = 5 per pixel
    assert float(flow_energy(rendered, shifted)) == pytest.approx(5.0 * covered, rel=1e-9)
    valid = np.zeros((H, W), bool)
    valid[: H // 2] = True
    half = int((rendered.mask.numpy() & valid).sum())
    assert float(flow_energy(rendered, shifted, valid)) == pytest.approx(5.0 * half, rel=1e-9)
    with pytest.raises(ValueError, match="observed flow must have shape"):
        flow_energy(rendered, np.zeros((H, W)))


def test_vertex_sets_of_different_sizes_are_refused() -> None:
    verts, faces = _plane()
    with pytest.raises(ValueError, match="differ"):
        render_flow(verts, verts[:-1], faces, _camera())
