"""SH lighting from normals and colours; estimated lighting reproduces the frames."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from monoavatar.eval import psnr
from monoavatar.render import directional_light_sh, rasterize, render_textured, sh_shading
from monoavatar.texture import TextureError, TextureSettings, build_texture, estimate_sh, fit_sh
from tests.texture.scenes import camera_towards, cube, render_views, smooth_texture


def _lighting() -> np.ndarray:
    sh = directional_light_sh(np.array([0.4, 0.7, 0.6]), 0.6 * np.pi)
    sh[:, 0] += 0.45 * 2 * np.sqrt(np.pi)
    return sh


def test_fit_sh_recovers_lighting_exactly() -> None:
    rng = np.random.default_rng(0)
    n = rng.normal(size=(500, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    sh = _lighting() * np.array([[1.0], [0.9], [0.8]])
    albedo = rng.uniform(0.2, 0.9, size=(500, 3))
    colours = albedo * sh_shading(torch.from_numpy(n), torch.from_numpy(sh)).numpy()
    np.testing.assert_allclose(fit_sh(n, colours, albedo), sh, atol=1e-9)
    with pytest.raises(TextureError, match="at least 9"):
        fit_sh(n[:5], colours[:5])


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_estimated_lighting_reproduces_a_tumbling_cube() -> None:
    mesh = cube(n=6)
    texture = 0.3 + 0.5 * smooth_texture(48, seed=2)
    sh = _lighting()
    cam = camera_towards((0.0, 0.0, 1.0), distance=3.0, size=96)
    rng = np.random.default_rng(1)
    frames, images, masks = [], [], []
    for k in range(16):  # the cube turns under a fixed light: each point sees many normals
        R = _rotation(rng.normal(size=3), 0.4 * k + rng.uniform(0, 0.3))
        moved = mesh.vertices @ R.T
        posed = type(mesh)(moved, mesh.faces, mesh.uv, mesh.face_uv, mesh.side)
        img, m = render_views(posed, texture, [cam], sh=sh)
        frames.append(moved)
        images.append(img[0])
        masks.append(m[0])
    verts, imgs, msks = np.stack(frames), np.stack(images), np.stack(masks)
    est = estimate_sh(verts, mesh.faces, imgs, msks, cam)
    assert est.shape == (3, 9)
    # up to the overall scale, the shading of every direction the camera sees is the true one
    dirs = rng.normal(size=(2000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs = dirs[dirs[:, 2] > 0.3]
    true = sh_shading(torch.from_numpy(dirs), torch.from_numpy(sh)).numpy()
    got = sh_shading(torch.from_numpy(dirs), torch.from_numpy(est)).numpy()
    ratio = got / true
    assert ratio.std(axis=0).max() < 0.05 * ratio.mean()
    # albedo texture with the estimate, re-lit with the estimate, matches the frames
    settings = TextureSettings(size=48, sample_size=48)
    tex = build_texture(verts, mesh.faces, mesh.uv, mesh.face_uv, imgs, msks, cam, sh=est,
                        settings=settings)  # fmt: skip
    scores = []
    for i in range(0, 16, 3):
        frags = rasterize(verts[i], mesh.faces, cam)
        render = render_textured(verts[i], mesh.faces, frags, mesh.uv, mesh.face_uv,
                                 torch.from_numpy(tex.as_float()), sh=est)  # fmt: skip
        scores.append(psnr(np.clip(render.numpy(), 0, 1), imgs[i] / 255.0, msks[i]))
    assert np.mean(scores) > 28.0


def test_estimate_sh_rejects_mismatched_inputs() -> None:
    mesh = cube(n=1)
    cam = camera_towards((0.0, 0.0, 1.0))
    with pytest.raises(TextureError, match="must match"):
        estimate_sh(mesh.vertices[None], mesh.faces, np.zeros((2, 96, 96, 3), np.uint8),
                    np.zeros((2, 96, 96), bool), cam)  # fmt: skip
    with pytest.raises(TextureError, match="usable person pixels"):
        estimate_sh(mesh.vertices[None], mesh.faces, np.zeros((1, 96, 96, 3), np.uint8),
                    np.zeros((1, 96, 96), bool), cam)  # fmt: skip
