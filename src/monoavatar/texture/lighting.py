"""Spherical-harmonics lighting estimated from posed meshes and frames (for albedo textures).

Model: every observed pixel of the person is ``colour = albedo(vertex) * sh_shading(n, L)``
(:mod:`monoavatar.render.shading`), with one lighting ``L`` (3 x 9, world frame) shared by all
frames — a fixed light while the person moves or turns — and one albedo per mesh vertex (the
vertex nearest to the pixel's surface point). ``L`` and the albedos are found by alternating
least squares: with the albedos fixed, ``L`` is linear (nine unknowns per channel); with ``L``
fixed, each albedo is a ratio of sums.

What is and is not identifiable: a vertex must be seen with its normal in several directions
relative to the light (a person turning around). Lighting that varies only with a direction the
person turns *about* (the vertical, in a turn-around) cannot be told from albedo and ends up in
either; the product ``albedo * shading`` — what a render shows — is what the estimate fixes.
The overall scale is fixed so that the mean shading over the samples is 1.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor

from monoavatar.core.camera import PinholeCamera
from monoavatar.render import SH_BAND_FACTORS, rasterize, sh_basis, vertex_normals
from monoavatar.texture.atlas import TextureError, as_array

__all__ = ["estimate_sh", "fit_sh"]


def _design(normals: np.ndarray) -> np.ndarray:
    """(M, 9) matrix D with ``sh_shading(n, L)_c = D @ L_c``."""
    basis = sh_basis(torch.from_numpy(np.ascontiguousarray(normals))).numpy()
    return np.asarray(basis * (np.asarray(SH_BAND_FACTORS) / np.pi))


def _solve(design: np.ndarray, colours: np.ndarray, albedo: np.ndarray) -> np.ndarray:
    """Per-channel least squares ``colour_c ≈ albedo_c * design @ L_c`` via the 9 x 9 normal
    equations (a tiny ridge keeps unobserved directions finite)."""
    out = np.zeros((3, 9))
    for ch in range(3):
        a = albedo[:, ch]
        weighted = design * (a * a)[:, None]
        lhs = design.T @ weighted
        rhs = design.T @ (a * colours[:, ch])
        ridge = 1e-9 * max(float(np.trace(lhs)), 1e-300)
        out[ch] = np.linalg.solve(lhs + ridge * np.eye(9), rhs)
    return out


def fit_sh(
    normals: np.ndarray, colours: np.ndarray, albedo: np.ndarray | None = None
) -> np.ndarray:
    """Least-squares SH lighting from surface normals and colours with known albedo.

    Solves ``min_L sum_i (colour_ic - albedo_ic * sh_shading(n_i, L)_c)^2`` per channel.

    Args:
        normals: (M, 3) unit normals, world frame.
        colours: (M, 3) observed linear colours.
        albedo: (M, 3) albedo of each sample; None means white (1).
    Returns:
        (3, 9) float64 radiance coefficients (:mod:`monoavatar.render.shading` convention).
    """
    n = np.asarray(normals, dtype=np.float64)
    c = np.asarray(colours, dtype=np.float64)
    if n.ndim != 2 or n.shape[1] != 3 or c.shape != n.shape:
        raise TextureError(f"normals and colours must both be (M, 3), got {n.shape}, {c.shape}")
    a = np.ones_like(c) if albedo is None else np.asarray(albedo, dtype=np.float64)
    if a.shape != c.shape:
        raise TextureError(f"albedo must have shape {c.shape}, got {a.shape}")
    if n.shape[0] < 9:
        raise TextureError(f"need at least 9 samples to fit 9 SH coefficients, got {n.shape[0]}")
    return _solve(_design(n), c, a)


def _frame_samples(
    vertices: np.ndarray,
    faces: np.ndarray,
    image: np.ndarray,
    mask: np.ndarray,
    camera: PinholeCamera,
    margin: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normals (M, 3), nearest vertex (M,) and colours (M, 3) of the reliable person pixels."""
    import cv2

    frags = rasterize(vertices, faces, camera)
    face_id = frags.face_id.numpy()
    ok: np.ndarray = mask.astype(np.uint8)
    if margin > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
        ok = cv2.erode(ok, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=(0.0,))
    sel = (face_id >= 0) & ok.astype(bool)
    # drop the render's own silhouette rim too (grazing normals, mixed pixels)
    rim = cv2.erode((face_id >= 0).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    sel &= rim
    fid = face_id[sel]
    bary = frags.bary.numpy()[sel].astype(np.float64)
    corner = faces[fid]
    normals = vertex_normals(vertices, faces).numpy()
    n = np.einsum("mk,mkc->mc", bary, normals[corner])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    nearest = corner[np.arange(len(fid)), bary.argmax(axis=1)]
    colours = image[sel].astype(np.float64) / 255.0
    return n, nearest, colours


def estimate_sh(
    vertices: Tensor | np.ndarray,
    faces: Tensor | np.ndarray,
    images: np.ndarray,
    masks: np.ndarray,
    camera: PinholeCamera | Sequence[PinholeCamera],
    iterations: int = 10,
    max_samples: int = 100_000,
    mask_margin: int = 2,
    seed: int = 0,
) -> np.ndarray:
    """Estimate one SH lighting shared by the frames, with a per-vertex albedo (module docs).

    Args:
        vertices: (F, V, 3) posed meshes per frame, world metres.
        faces: (Fc, 3) vertex indices.
        images: (F, H, W, 3) uint8 frames (linear colour); masks: (F, H, W) bool person masks.
        camera: one camera for all frames or one per frame.
        iterations: alternations of the lighting and albedo least squares.
        max_samples: pixels drawn at random (with ``seed``) from all frames.
        mask_margin: pixels near the person mask's border that are ignored.
    Returns:
        (3, 9) float64 SH radiance coefficients, world frame, scaled so that the mean shading
        of the samples is 1.
    """
    verts = as_array(vertices, np.float64, "vertices")
    f = as_array(faces, np.int64, "faces")
    imgs = np.asarray(images)
    msks = np.asarray(masks)
    if verts.ndim != 3 or verts.shape[2] != 3:
        raise TextureError(f"vertices must have shape (F, V, 3), got {verts.shape}")
    n_frames = verts.shape[0]
    if imgs.shape[:1] != (n_frames,) or imgs.ndim != 4 or msks.shape != imgs.shape[:3]:
        raise TextureError(
            f"images (F, H, W, 3) and masks (F, H, W) must match F={n_frames}: got "
            f"{imgs.shape} and {msks.shape}"
        )
    cams = [camera] * n_frames if isinstance(camera, PinholeCamera) else list(camera)
    if len(cams) != n_frames:
        raise TextureError(f"expected {n_frames} cameras, got {len(cams)}")
    parts = [
        _frame_samples(verts[i], f, imgs[i], msks[i].astype(bool), cams[i], mask_margin)
        for i in range(n_frames)
    ]
    normals = np.concatenate([p[0] for p in parts])
    vertex = np.concatenate([p[1] for p in parts])
    colours = np.concatenate([p[2] for p in parts])
    if len(normals) < 9:
        raise TextureError(f"only {len(normals)} usable person pixels; cannot fit lighting")
    if len(normals) > max_samples:
        pick = np.random.default_rng(seed).choice(len(normals), max_samples, replace=False)
        normals, vertex, colours = normals[pick], vertex[pick], colours[pick]
    num_v = verts.shape[1]
    counts = np.maximum(np.bincount(vertex, minlength=num_v), 1)

    def per_vertex(values: np.ndarray) -> np.ndarray:
        return np.stack([np.bincount(vertex, values[:, c], num_v) for c in range(3)], axis=1)

    design = _design(normals)
    albedo = per_vertex(colours) / counts[:, None]  # start: shading 1 everywhere
    sh = _solve(design, colours, albedo[vertex])
    for _ in range(max(0, iterations - 1)):
        s = design @ sh.T
        albedo = per_vertex(colours * s) / np.maximum(per_vertex(s * s), 1e-12)
        sh = _solve(design, colours, albedo[vertex])
    mean = float((design @ sh.T).mean())
    if mean > 0:
        sh = sh / mean
    return sh
