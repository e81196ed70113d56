"""Convenience renders on top of :func:`~monoavatar.render.raster.rasterize` (deferred).

Each render takes the :class:`~monoavatar.render.raster.Fragments` of one rasterisation, so a
single rasterisation serves a silhouette, a normal map, a label map and a colour image.
Renders that produce floating-point images are differentiable in their floating inputs
(vertices through normals, UVs, textures, SH coefficients) with visibility held fixed.

UV convention (glTF 2.0): ``(u, v) = (0, 0)`` is the *top-left* corner of the texture image,
u grows to the right and v *downwards*; ``(1, 1)`` is the bottom-right corner. A texel
(col, row) of an ``H_t x W_t`` texture has its centre at ``((col + 0.5) / W_t,
(row + 0.5) / H_t)``. OBJ/OpenGL-style UVs (v upwards) convert with ``v_gltf = 1 - v_obj``.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from monoavatar.core.camera import PinholeCamera
from monoavatar.core.geometry import face_indices, float_tensor, vertex_normals, writable
from monoavatar.render.interpolate import interpolate, interpolate_masked, scatter_masked
from monoavatar.render.raster import Fragments
from monoavatar.render.shading import sh_shading

__all__ = [
    "render_depth",
    "render_face_labels",
    "render_normals",
    "render_over_image",
    "render_silhouette",
    "render_textured",
    "render_uv",
    "render_vertex_labels",
    "sample_texture",
    "vertex_normals",
]


def render_silhouette(fragments: Fragments) -> Tensor:
    """(H, W) bool mask, True where the mesh covers the pixel centre."""
    return fragments.face_id >= 0


def render_depth(fragments: Fragments, background: float = 0.0) -> Tensor:
    """(H, W) float32 camera-space z in metres, ``background`` where nothing is visible."""
    return torch.where(
        fragments.face_id >= 0,
        fragments.depth,
        torch.tensor(background, dtype=fragments.depth.dtype),
    )


def render_normals(
    vertices: Tensor | np.ndarray,
    faces: Tensor | np.ndarray,
    fragments: Fragments,
    camera: PinholeCamera | None = None,
) -> Tensor:
    """Smooth per-pixel unit normals: area-weighted vertex normals, interpolated, renormalised.

    Args:
        vertices: (V, 3) world positions in metres (the mesh that was rasterised).
        faces: (F, 3) integer vertex indices.
        fragments: the rasterisation.
        camera: if given, normals are rotated into its frame (OpenCV: x right, y down,
            z forward — a surface facing the camera has a negative z component); otherwise
            they are in world coordinates.
    Returns:
        (H, W, 3) unit normals, zeros on background; dtype of ``vertices``. Back faces seen
        through two-sided rasterisation keep their outward (away from camera) normal.
    """
    return scatter_masked(_masked_normals(vertices, faces, fragments, camera), fragments)


def _masked_normals(
    vertices: Tensor | np.ndarray,
    faces: Tensor | np.ndarray,
    fragments: Fragments,
    camera: PinholeCamera | None,
) -> Tensor:
    """(N, 3) unit normals at the covered pixels (order of ``image[fragments.mask]``)."""
    normals = vertex_normals(vertices, faces)
    if camera is not None:
        R = torch.as_tensor(camera.R, dtype=normals.dtype, device=normals.device)
        normals = normals @ R.T
    return F.normalize(interpolate_masked(normals, faces, fragments), dim=-1)


def render_face_labels(
    face_labels: Tensor | np.ndarray, fragments: Fragments, background: int = -1
) -> Tensor:
    """(H, W) int64 label of the visible face, ``background`` elsewhere.

    Args:
        face_labels: (F,) integer label per face (e.g. body part).
    """
    labels = torch.as_tensor(face_labels)
    if labels.ndim != 1 or labels.is_floating_point():
        raise ValueError(
            f"face_labels must be a 1-D integer array, got {labels.dtype} {tuple(labels.shape)}"
        )
    face_id = fragments.face_id
    if face_id.numel() and int(face_id.max()) >= labels.shape[0]:
        raise ValueError(
            f"fragments refer to face {int(face_id.max())} but there are {labels.shape[0]} labels"
        )
    labels = labels.to(torch.int64)
    out = torch.full_like(face_id, background)
    mask = face_id >= 0
    out[mask] = labels[face_id[mask]]
    return out


def render_vertex_labels(
    vertex_labels: Tensor | np.ndarray,
    faces: Tensor | np.ndarray,
    fragments: Fragments,
    background: int = -1,
) -> Tensor:
    """(H, W) int64 label of the visible face's corner with the largest barycentric weight
    (the nearest corner), ``background`` elsewhere.

    Args:
        vertex_labels: (V,) integer label per vertex; faces: (F, 3) vertex indices.
    """
    labels = torch.as_tensor(vertex_labels)
    if labels.ndim != 1 or labels.is_floating_point():
        raise ValueError(
            f"vertex_labels must be a 1-D integer array, got {labels.dtype} {tuple(labels.shape)}"
        )
    f = face_indices(faces, labels.shape[0])
    face_id = fragments.face_id
    if face_id.numel() and int(face_id.max()) >= f.shape[0]:
        raise ValueError(f"fragments refer to face {int(face_id.max())} but F={f.shape[0]}")
    out = torch.full_like(face_id, background)
    mask = face_id >= 0
    corner = fragments.bary[mask].argmax(dim=-1)
    vid = f[face_id[mask], corner]
    out[mask] = labels.to(torch.int64)[vid]
    return out


def render_uv(
    uv: Tensor | np.ndarray,
    face_uv_idx: Tensor | np.ndarray,
    fragments: Fragments,
    background: float = 0.0,
) -> Tensor:
    """Per-pixel texture coordinates (glTF convention, see module docstring).

    Args:
        uv: (T, 2) texture coordinates.
        face_uv_idx: (F, 3) integer indices into ``uv`` for each face corner (pass ``faces``
            when UVs are indexed like the vertices).
        fragments: the rasterisation of the F faces.
        background: value of both channels on background pixels.
    Returns:
        (H, W, 2) UVs, dtype of ``uv``; differentiable in ``uv``.
    """
    uv_t = float_tensor(uv, "uv", 2)
    idx = face_indices(face_uv_idx, uv_t.shape[0]).to(uv_t.device)
    return interpolate(uv_t[idx], idx, fragments, fill=background)


def sample_texture(texture: Tensor | np.ndarray, uv: Tensor) -> Tensor:
    """Bilinearly sample a texture at UV coordinates (glTF convention, clamp to edge).

    Args:
        texture: (H_t, W_t, C) floating image (row 0 at the top, i.e. at v = 0).
        uv: (..., 2) coordinates; texel centres at ``((col + 0.5) / W_t, (row + 0.5) / H_t)``;
            outside [0, 1] the edge texels are repeated.
    Returns:
        (..., C) samples in the texture's dtype; differentiable in ``texture`` and ``uv``.
    """
    tex = float_tensor(texture, "texture")
    if tex.ndim != 3:
        raise ValueError(f"texture must have shape (H_t, W_t, C), got {tuple(tex.shape)}")
    if uv.shape[-1:] != (2,):
        raise ValueError(f"uv must have shape (..., 2), got {tuple(uv.shape)}")
    lead = uv.shape[:-1]
    # grid_sample with align_corners=False maps -1/+1 to the outer texel edges: x = 2u - 1,
    # y = 2v - 1 (both point right / down like u and v).
    grid = uv.to(tex.dtype).reshape(1, -1, 1, 2) * 2.0 - 1.0
    src = tex.permute(2, 0, 1).unsqueeze(0)  # (1, C, H_t, W_t)
    out = F.grid_sample(src, grid, mode="bilinear", padding_mode="border", align_corners=False)
    return out[0, :, :, 0].T.reshape(*lead, tex.shape[2])


def render_textured(
    vertices: Tensor | np.ndarray,
    faces: Tensor | np.ndarray,
    fragments: Fragments,
    uv: Tensor | np.ndarray,
    face_uv_idx: Tensor | np.ndarray,
    texture: Tensor | np.ndarray,
    sh: Tensor | np.ndarray | None = None,
    background: Tensor | np.ndarray | float = 0.0,
) -> Tensor:
    """Colour image: texture (albedo) times SH Lambertian shading, over a background.

    ``colour = sample_texture(texture, uv) * max(sh_shading(world normal, sh), 0)`` on covered
    pixels (hard edges, no anti-aliasing), the background elsewhere.

    Args:
        vertices: (V, 3) world positions in metres; faces: (F, 3) vertex indices.
        fragments: the rasterisation of that mesh.
        uv: (T, 2) texture coordinates (glTF convention); face_uv_idx: (F, 3) indices into uv.
        texture: (H_t, W_t, 3) linear albedo in [0, 1].
        sh: (3, 9) or (9,) SH radiance coefficients in world coordinates
            (:mod:`monoavatar.render.shading`); None renders unlit albedo.
        background: (H, W, 3) image, (3,) colour or scalar.
    Returns:
        (H, W, 3) image in the texture's dtype; differentiable in vertices (through normals),
        uv, texture, sh and background.
    """
    tex = float_tensor(texture, "texture")
    if tex.ndim != 3 or tex.shape[2] != 3:
        raise ValueError(f"texture must have shape (H_t, W_t, 3), got {tuple(tex.shape)}")
    height, width = fragments.height, fragments.width
    bg = torch.as_tensor(background, dtype=tex.dtype, device=tex.device)
    if bg.shape not in ((), (3,), (height, width, 3)):
        raise ValueError(
            f"background must be a scalar, (3,) or ({height}, {width}, 3), got {tuple(bg.shape)}"
        )
    uv_t = float_tensor(uv, "uv", 2)
    uv_idx = face_indices(face_uv_idx, uv_t.shape[0]).to(uv_t.device)
    colour = sample_texture(tex, interpolate_masked(uv_t[uv_idx], uv_idx, fragments))  # (N, 3)
    if sh is not None:
        normals = _masked_normals(vertices, faces, fragments, None).to(tex.dtype)
        sh_t = torch.as_tensor(writable(sh), dtype=tex.dtype, device=tex.device)
        colour = colour * sh_shading(normals, sh_t).clamp_min(0.0)
    image = bg.expand(height, width, 3).clone()  # never write into the caller's background
    image[fragments.face_id >= 0] = colour
    return image


def render_over_image(
    vertices: Tensor | np.ndarray,
    faces: Tensor | np.ndarray,
    fragments: Fragments,
    uv: Tensor | np.ndarray,
    face_uv_idx: Tensor | np.ndarray,
    texture: Tensor | np.ndarray,
    image: np.ndarray,
    sh: Tensor | np.ndarray | None = None,
) -> np.ndarray:
    """The textured (and, with ``sh``, shaded) mesh drawn over ``image`` (H, W, 3) uint8, as
    (H, W, 3) uint8: the picture an optical flow to the frame starts from (analysis by
    synthesis, Paper A)."""
    background = image.astype(np.float64) / 255.0
    render = render_textured(vertices, faces, fragments, uv, face_uv_idx, texture, sh=sh,
                             background=background)  # fmt: skip
    return (np.clip(render.numpy(), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
