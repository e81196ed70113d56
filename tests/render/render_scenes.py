"""Shared scene helpers for the renderer tests (imported by the test modules)."""

from __future__ import annotations

import numpy as np
import trimesh

from monoavatar.core.camera import PinholeCamera


def look_at_camera(
    eye: np.ndarray, target: np.ndarray, focal: float, width: int, height: int
) -> PinholeCamera:
    """OpenCV camera at ``eye`` looking at ``target`` with world +y up in the image.

    Built here rather than with ``PinholeCamera.look_at`` so the tests depend only on the
    camera's documented R, t convention.
    """
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    down = np.array([0.0, -1.0, 0.0])
    x = np.cross(down, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return PinholeCamera.from_focal(focal, width, height, R=R, t=-R @ eye)


def concatenate(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """``trimesh.util.concatenate`` with its result typed as a mesh."""
    mesh = trimesh.util.concatenate(meshes)
    assert isinstance(mesh, trimesh.Trimesh)
    return mesh


def raycast(mesh: trimesh.Trimesh, camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """Independent reference: cast one ray per pixel centre (embree via trimesh).

    Returns face ids (H, W) int64 (-1 = miss) and camera-z depth (H, W) float64 (inf = miss).
    """
    H, W = camera.height, camera.width
    cols, rows = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    pix = np.stack([cols.ravel(), rows.ravel(), np.ones(H * W)], axis=1)
    d_cam = pix @ np.linalg.inv(camera.K).T
    d_world = d_cam @ camera.R  # R^T d
    d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
    origins = np.tile(camera.center, (H * W, 1))
    loc, ray_idx, tri_idx = mesh.ray.intersects_location(origins, d_world, multiple_hits=False)
    face_id = np.full(H * W, -1, dtype=np.int64)
    depth = np.full(H * W, np.inf)
    face_id[ray_idx] = tri_idx
    depth[ray_idx] = (loc @ camera.R.T + camera.t)[:, 2]
    return face_id.reshape(H, W), depth.reshape(H, W)
