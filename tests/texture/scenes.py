"""Small textured meshes and views for the texture tests."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from monoavatar.core.camera import PinholeCamera
from monoavatar.render import rasterize, render_textured


@dataclass
class UVMesh:
    """A triangle mesh with separately indexed glTF UVs."""

    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64, outward normals by the right-hand rule
    uv: np.ndarray  # (T, 2) float64
    face_uv: np.ndarray  # (F, 3) int64
    side: np.ndarray  # (F,) int64 which part (cube side, quad) a face belongs to


# (normal, a, b) with a x b = normal: outward-facing grids on the six cube sides
_SIDES = [
    ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    ((-1, 0, 0), (0, 0, 1), (0, 1, 0)),
    ((0, 1, 0), (0, 0, 1), (1, 0, 0)),
    ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
    ((0, 0, 1), (1, 0, 0), (0, 1, 0)),
    ((0, 0, -1), (0, 1, 0), (1, 0, 0)),
]


def grid_patch(
    origin: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    n: int,
    uv_box: tuple[float, float, float, float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An n x n grid of quads spanning ``origin + s a + t b`` (s, t in [0, 1]), its faces
    (normal along a x b) and UVs filling ``uv_box = (u0, v0, u1, v1)``."""
    s, t = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    s, t = s.ravel(), t.ravel()
    points = origin + s[:, None] * a + t[:, None] * b
    u0, v0, u1, v1 = uv_box
    uv = np.stack([u0 + s * (u1 - u0), v0 + t * (v1 - v0)], axis=1)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    p00 = (i * (n + 1) + j).ravel()
    p10, p01 = p00 + (n + 1), p00 + 1
    p11 = p10 + 1
    faces = np.concatenate([np.stack([p00, p10, p11], 1), np.stack([p00, p11, p01], 1)])
    return points, faces, uv


def weld(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> UVMesh:
    """Join patches, merging vertices at the same position (UVs stay per patch: seams)."""
    points, faces, uvs, face_uv, side = [], [], [], [], []
    offset = 0
    for k, (p, f, uv) in enumerate(parts):
        points.append(p)
        faces.append(f + offset)
        uvs.append(uv)
        face_uv.append(f + offset)
        side.append(np.full(len(f), k))
        offset += len(p)
    allp = np.concatenate(points)
    _, first, inverse = np.unique(np.round(allp, 9), axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    # keep vertex order stable: new index = rank of the first occurrence
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return UVMesh(
        vertices=allp[first[order]],
        faces=rank[inverse][np.concatenate(faces)],
        uv=np.concatenate(uvs),
        face_uv=np.concatenate(face_uv),
        side=np.concatenate(side),
    )


def cube(n: int = 4, size: float = 1.0, centre=(0.0, 0.0, 0.0), margin: float = 0.04) -> UVMesh:
    """A cube of n x n quads per side, vertices welded, each side its own UV chart in a 3 x 2
    layout (so every cube edge is a UV seam)."""
    c = np.asarray(centre, dtype=np.float64)
    parts = []
    for k, (normal, a, b) in enumerate(_SIDES):
        nv, av, bv = (np.asarray(x, dtype=np.float64) * size for x in (normal, a, b))
        origin = c + 0.5 * nv - 0.5 * av - 0.5 * bv
        col, row = k % 3, k // 3
        box = (
            (col + margin) / 3,
            (row + margin) / 2,
            (col + 1 - margin) / 3,
            (row + 1 - margin) / 2,
        )
        parts.append(grid_patch(origin, av, bv, n, box))
    return weld(parts)


def smooth_texture(size: int, seed: int = 0) -> np.ndarray:
    """(size, size, 3) float32 low-frequency colours in [0.1, 0.9]."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid((np.arange(size) + 0.5) / size, (np.arange(size) + 0.5) / size)
    out = np.zeros((size, size, 3))
    for c in range(3):
        fu, fv, ph = rng.uniform(1, 4), rng.uniform(1, 4), rng.uniform(0, 2 * np.pi)
        out[..., c] = 0.5 + 0.4 * np.sin(2 * np.pi * (fu * u + fv * v) + ph)
    return out.astype(np.float32)


def camera_towards(
    direction, distance: float = 3.0, target=(0.0, 0.0, 0.0), size: int = 96, focal=100.0
) -> PinholeCamera:
    """A camera at ``target + distance * direction`` looking at ``target``."""
    d = np.asarray(direction, dtype=np.float64)
    d /= np.linalg.norm(d)
    up = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([0.0, 0.0, 1.0])
    t = np.asarray(target, dtype=np.float64)
    return PinholeCamera.look_at(t + distance * d, t, up, focal, size, size)


def render_views(
    mesh: UVMesh,
    texture: np.ndarray,
    cameras: list[PinholeCamera],
    sh: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """uint8 images (N, H, W, 3) and bool masks (N, H, W) of the textured mesh."""
    images, masks = [], []
    for cam in cameras:
        frags = rasterize(mesh.vertices, mesh.faces, cam)
        img = render_textured(
            mesh.vertices, mesh.faces, frags, mesh.uv, mesh.face_uv,
            torch.from_numpy(texture), sh=sh, background=0.0,
        )  # fmt: skip
        images.append((np.clip(img.numpy(), 0, 1) * 255 + 0.5).astype(np.uint8))
        masks.append(frags.mask.numpy())
    return np.stack(images), np.stack(masks)
