"""Pictures of a finished avatar: overlays of the input and the re-posed avatar, turntables
of the albedo (of the body model's mesh or of the once-subdivided one), UV maps as pictures."""

from __future__ import annotations

import numpy as np
import torch

from monoavatar.body import BodyModel
from monoavatar.core.camera import PinholeCamera
from monoavatar.fit.pose import PoseTrack
from monoavatar.fit.shape import CanonicalShape
from monoavatar.learn.uvmaps import UVLayout
from monoavatar.pipelines.stages import Inputs, posed_avatar, uint8_image
from monoavatar.render import rasterize, render_textured
from monoavatar.texture.backproject import UVTexture


def render_avatar(vertices: np.ndarray, body: BodyModel, texture: np.ndarray,
                  camera: PinholeCamera, background: np.ndarray,
                  sh: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """(H, W, 3) uint8: the avatar's vertices (V, 3) with ``texture`` (S, S, 3) in [0, 1],
    lit by ``sh`` (3, 9) or unlit, over ``background`` (H, W, 3) in [0, 1]."""
    v = torch.as_tensor(vertices, dtype=torch.float64)
    frags = rasterize(v, body.faces, camera)
    image = render_textured(v, body.faces, frags, body.uv, body.face_uv,
                            torch.as_tensor(texture, dtype=torch.float64),
                            sh=None if sh is None else torch.as_tensor(sh, dtype=torch.float64),
                            background=torch.as_tensor(background, dtype=torch.float64))
    return (np.clip(image.numpy(), 0, 1) * 255 + 0.5).astype(np.uint8)


def previews(body: BodyModel, inputs: Inputs, track: PoseTrack, shape: CanonicalShape,
             texture: UVTexture, sh: np.ndarray) -> dict[str, np.ndarray]:  # fmt: skip
    """``overlays``: input | re-posed avatar (lit by the estimated lighting) on six key-frames;
    ``turntable``: the canonical albedo avatar from eight directions, 256 px each."""
    tex = texture.as_float()
    picks = np.unique(np.linspace(0, len(track.poses) - 1, 6).round().astype(int))
    posed = posed_avatar(body, shape.shape, shape.offsets, track.poses[picks],
                         track.translations[picks])  # fmt: skip
    rows = []
    for k, i in enumerate(picks):
        frame = inputs.frames.images[i]
        render = render_avatar(posed[k], body, tex, track.camera,
                               frame.astype(np.float64) / 255, sh)  # fmt: skip
        rows.append(np.concatenate([frame, render], axis=1))
    sheet = np.concatenate([np.concatenate(rows[j : j + 2], axis=1) for j in
                            range(0, len(rows) - len(rows) % 2, 2)] or rows[:1], axis=0)
    verts = shape.vertices.double().numpy()
    centre = 0.5 * (verts.min(0) + verts.max(0))
    size = float(np.ptp(verts[:, 1]))
    tiles = []
    for angle in np.linspace(0, 2 * np.pi, 8, endpoint=False):
        eye = centre + 2.2 * size * np.array([np.sin(angle), 0.0, np.cos(angle)])
        cam = PinholeCamera.look_at(eye, centre, np.array([0.0, 1.0, 0.0]), 320.0, 256, 256)
        tiles.append(render_avatar(verts, body, tex, cam, np.full((256, 256, 3), 0.92)))
    grid = np.concatenate([np.concatenate(tiles[:4], 1), np.concatenate(tiles[4:], 1)], 0)
    return {"overlays": sheet, "turntable": grid}


def render_fine(vertices: np.ndarray, layout: UVLayout, texture: np.ndarray,
                camera: PinholeCamera, background: np.ndarray,
                sh: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """(H, W, 3) uint8: the fine mesh's vertices (V_f, 3) with ``texture`` (S, S, 3) in
    [0, 1], lit by ``sh`` (3, 9) or unlit, over ``background`` (H, W, 3) in [0, 1]."""
    sub = layout.subdivision
    v = torch.as_tensor(vertices, dtype=torch.float64)
    frags = rasterize(v, sub.faces, camera)
    image = render_textured(v, sub.faces, frags, sub.uv, sub.face_uv,
                            torch.as_tensor(texture, dtype=torch.float64),
                            sh=None if sh is None else torch.as_tensor(sh, dtype=torch.float64),
                            background=torch.as_tensor(background, dtype=torch.float64))
    return uint8_image(image.numpy())


def fine_turntable(vertices: np.ndarray, layout: UVLayout, texture: np.ndarray, views: int = 8,
              size: int = 256) -> np.ndarray:  # fmt: skip
    """The canonical avatar from ``views`` directions about the vertical, two rows."""
    centre = 0.5 * (vertices.min(0) + vertices.max(0))
    height = float(np.ptp(vertices[:, 1]))
    tiles = []
    for angle in np.linspace(0, 2 * np.pi, views, endpoint=False):
        eye = centre + 1.7 * height * np.array([np.sin(angle), 0.0, np.cos(angle)])
        cam = PinholeCamera.look_at(eye, centre, np.array([0.0, 1.0, 0.0]), 1.25 * size,
                                    size, size)  # fmt: skip
        tiles.append(render_fine(vertices, layout, texture, cam, np.full((size, size, 3), 0.92)))
    half = (views + 1) // 2
    rows = [np.concatenate(tiles[:half], 1), np.concatenate(tiles[half:], 1)]
    if rows[1].shape[1] < rows[0].shape[1]:
        pad = np.full((size, rows[0].shape[1] - rows[1].shape[1], 3), 235, np.uint8)
        rows[1] = np.concatenate([rows[1], pad], 1)
    return np.concatenate(rows, 0)
