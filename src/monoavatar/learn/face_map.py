"""Building the face-mesh landmark map of a body mesh (Paper C, Sec. C.3.2): where each of the
468 face-mesh landmarks lies on the body's surface (:class:`monoavatar.body.face_map.FaceMap`).

The average body, its face painted as :mod:`monoavatar.synth` paints its subjects (eyes,
brows, lips) and no hair, is rendered head-on and turned a little either way
(``FaceMapSettings.yaws_deg``); mediapipe's face mesh runs on each render; each landmark's
viewing ray is intersected with the triangle the rasteriser shows at its pixel; the views'
points are averaged and snapped to the nearest surface point. No person is asked to click
anything, and the same command reproduces the shipped map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from monoavatar.body import MEDIAPIPE_LANDMARKS, BodyModel
from monoavatar.body.face_map import FaceMap
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.errors import MonoavatarError
from monoavatar.core.geometry import camera_rays
from monoavatar.core.landmarks import NUM_FACE_LANDMARKS
from monoavatar.render import rasterize, render_textured

__all__ = ["FaceMapBuild", "FaceMapError", "FaceMapSettings", "back_project", "build_face_map",
           "head_camera", "painted_face_texture", "render_head", "write_face_map"]  # fmt: skip


class FaceMapError(MonoavatarError, RuntimeError):
    """The face mesh found no face in a render of the body's head."""


@dataclass(frozen=True)
class FaceMapSettings:
    """Options of :func:`build_face_map`.

    Attributes:
        yaws_deg: the views, degrees about the vertical (0: head-on; positive: the camera
            moves to the body's left).
        size: render side in pixels.
        focal_px: focal length in pixels.
        distance_m: camera distance from the head's centre, metres.
        texture_size: texels of the painted texture's side.
        seed: the painted subject's colours (skin, hair).
        reach_px: a landmark off the head's outline by at most this many pixels is put on it
            (the face mesh's outline can lie wider than a narrow head).
    """

    yaws_deg: tuple[float, ...] = (-10.0, 0.0, 10.0)
    size: int = 512
    focal_px: float = 1400.0
    distance_m: float = 0.7
    texture_size: int = 1024
    seed: int = 0
    reach_px: float = 40.0


@dataclass(frozen=True)
class FaceMapBuild:
    """A built map and how well its views agreed.

    Attributes:
        face_map: the map.
        spread_mm: (468,) largest distance of one view's point from the views' mean, mm.
        snap_mm: (468,) distance from the views' mean to the surface point kept, mm.
    """

    face_map: FaceMap
    spread_mm: np.ndarray
    snap_mm: np.ndarray
    preview: np.ndarray  # (H, W, 3) uint8: the most frontal render, detections red, map green


def _average_rest(body: BodyModel) -> np.ndarray:
    with torch.no_grad():
        rest, _ = body.rest_shape(body.default_shape(1))
    return rest[0].double().numpy()


def head_camera(body: BodyModel, yaw_deg: float, settings: FaceMapSettings) -> PinholeCamera:
    """A camera ``settings.distance_m`` in front of the average body's head (the body faces
    +Z, Y up), turned ``yaw_deg`` about the vertical through the head's centre."""
    rest = torch.as_tensor(_average_rest(body), dtype=body.dtype)[None]
    with torch.no_grad():
        kp = body.keypoints(rest)[0].double().numpy()
    nose = kp[MEDIAPIPE_LANDMARKS.index("nose")]
    ears = 0.5 * (kp[MEDIAPIPE_LANDMARKS.index("left_ear")]
                  + kp[MEDIAPIPE_LANDMARKS.index("right_ear")])  # fmt: skip
    centre = np.array([ears[0], 0.5 * (nose[1] + ears[1]), ears[2]])
    a = np.radians(yaw_deg)
    turn = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    position = centre + turn @ np.array([0.0, 0.0, settings.distance_m])
    R = np.diag([1.0, -1.0, -1.0]) @ turn.T  # camera x right, y down, z forward
    s = settings.size
    K = np.array([[settings.focal_px, 0.0, s / 2], [0.0, settings.focal_px, s / 2], [0, 0, 1]])
    return PinholeCamera(K, R, -R @ position, s, s)


def painted_face_texture(body: BodyModel, settings: FaceMapSettings) -> np.ndarray:
    """(T, T, 3) albedo in ``body``'s UV layout: a synth subject's skin and face features
    (average shape, no hair volume)."""
    from monoavatar.synth.subjects import build_subject, sample_subject

    spec = sample_subject(np.random.default_rng(settings.seed), body, "minimal")
    spec = replace(spec, shape=np.zeros(body.shape_dim), hair_volume=0.0)
    return build_subject(body, spec, settings.texture_size).texture


def render_head(body: BodyModel, camera: PinholeCamera, texture: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The average body seen by ``camera`` under soft light from above → (H, W, 3) uint8
    image and the fragments' (H, W) face ids."""
    v = torch.as_tensor(_average_rest(body))
    frags = rasterize(v, body.faces, camera)
    sh = np.zeros((3, 9))
    sh[:, 0] = 0.8 * 2.0 * math.sqrt(math.pi)  # ambient: a flat 0.8 (Y00 = 1 / (2 √π))
    sh[:, 2] = 0.4  # more light from above
    image = render_textured(v, body.faces, frags, body.uv, body.face_uv, torch.as_tensor(texture),
                            sh=torch.as_tensor(sh), background=0.5)  # fmt: skip
    return (np.clip(image.numpy(), 0, 1) * 255 + 0.5).astype(np.uint8), frags.face_id.numpy()


def back_project(vertices: np.ndarray, faces: np.ndarray, camera: PinholeCamera,
                 face_id: np.ndarray, pixels: np.ndarray, reach_px: float = 0.0
                 ) -> np.ndarray:  # fmt: skip
    """(N, 2) pixel positions → (N, 3) world points where their viewing rays meet the plane of
    the triangle shown at their pixel (``face_id`` (H, W) of the rasterisation). A pixel that
    shows no triangle takes the nearest one that does, within ``reach_px`` pixels (a face
    outline landmark just off the head's outline); NaN rows where none does."""
    from scipy.ndimage import distance_transform_edt

    pixels = np.asarray(pixels, np.float64).copy()
    out = np.full((len(pixels), 3), np.nan)
    cols = np.clip(np.floor(pixels[:, 0]).astype(int), 0, camera.width - 1)
    rows = np.clip(np.floor(pixels[:, 1]).astype(int), 0, camera.height - 1)
    tri = face_id[rows, cols].copy()
    off = tri < 0
    if off.any() and reach_px > 0:
        distance, (near_r, near_c) = distance_transform_edt(face_id < 0, return_indices=True)
        near = off & (distance[rows, cols] <= reach_px)
        rows[near], cols[near] = near_r[rows[near], cols[near]], near_c[rows[near], cols[near]]
        pixels[near] = np.stack([cols[near], rows[near]], axis=1) + 0.5
        tri[near] = face_id[rows[near], cols[near]]
    inside = (pixels[:, 0] >= 0) & (pixels[:, 0] < camera.width)
    inside &= (pixels[:, 1] >= 0) & (pixels[:, 1] < camera.height)
    ok = (tri >= 0) & inside
    R, t = np.asarray(camera.R, np.float64), np.asarray(camera.t, np.float64)
    origin = -R.T @ t
    direction = camera_rays(pixels[ok], np.asarray(camera.K)) @ R  # rows: Rᵀ r, world axes
    a, b, c = (vertices[faces[tri[ok], k]] for k in range(3))
    normal = np.cross(b - a, c - a)
    depth = np.einsum("nc,nc->n", a - origin, normal) / np.einsum("nc,nc->n", direction, normal)
    out[ok] = origin + depth[:, None] * direction
    return out


def build_face_map(body: BodyModel, settings: FaceMapSettings | None = None) -> FaceMapBuild:
    """The face-mesh landmark map of ``body``'s mesh (module docstring).

    Raises:
        FaceMapError: the face mesh found no face in one of the renders.
    """
    import trimesh

    from monoavatar.perception.mediapipe_backend import MediaPipeFaceMesh

    settings = settings or FaceMapSettings()
    vertices = _average_rest(body)
    faces = body.faces.numpy()
    texture = painted_face_texture(body, settings)
    detector = MediaPipeFaceMesh(max_faces=1)
    points, views = [], []
    for yaw in settings.yaws_deg:
        camera = head_camera(body, yaw, settings)
        image, face_id = render_head(body, camera, texture)
        found = detector.detect(image)
        if not found:
            raise FaceMapError(f"the face mesh found no face in the render at {yaw:g}°")
        pixels = np.asarray(found[0], np.float64)[:NUM_FACE_LANDMARKS, :2]
        points.append(back_project(vertices, faces, camera, face_id, pixels,
                                   settings.reach_px))  # fmt: skip
        views.append((abs(yaw), image, camera, pixels))
    stack = np.stack(points)  # (views, 468, 3), NaN where a view missed the mesh
    mean = np.nanmean(stack, axis=0)
    if not np.isfinite(mean).all():
        raise FaceMapError("a face-mesh landmark fell off the body in every view")
    spread = np.nanmax(np.linalg.norm(stack - mean, axis=-1), axis=0)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    closest, distance, triangles = trimesh.proximity.closest_point(mesh, mean)
    bary = trimesh.triangles.points_to_barycentric(vertices[faces[triangles]], closest)
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(1, keepdims=True)
    face_map = FaceMap(np.asarray(triangles, np.int64), bary, len(vertices), len(faces))
    # the preview: the most frontal view, the map (green) under its detections (red)
    _, preview, camera, pixels = min(views, key=lambda view: view[0])
    _mark(preview, camera.project(torch.as_tensor(closest))[0].numpy(), (40, 255, 40), 2)
    _mark(preview, pixels, (255, 40, 40), 1)
    return FaceMapBuild(face_map, 1000.0 * spread, 1000.0 * np.asarray(distance), preview)


def _mark(image: np.ndarray, pixels: np.ndarray, colour: tuple[int, int, int], radius: int
          ) -> None:  # fmt: skip
    """Filled dots of ``radius`` pixels at (N, 2) pixel positions, in place."""
    import cv2

    for x, y in np.floor(pixels).astype(int):
        cv2.circle(image, (int(x), int(y)), radius, colour, -1)


def write_face_map(out_dir: str | Path, body: BodyModel, settings: FaceMapSettings | None = None,
                   name: str = "anny") -> FaceMapBuild:  # fmt: skip
    """Build the map (:func:`build_face_map`) and write ``OUT/face_map_NAME.npz`` (what
    ``monoavatar/body/data/`` ships) and ``OUT/face_map_preview.png``."""
    from PIL import Image

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    built = build_face_map(body, settings)
    built.face_map.save(out / f"face_map_{name}.npz")
    Image.fromarray(built.preview).save(out / "face_map_preview.png")
    return built
