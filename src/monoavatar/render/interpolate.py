"""Barycentric interpolation of mesh attributes into the image (deferred shading).

OpenDR-style: the rasteriser fixes visibility (which face, which barycentrics); this module
computes per-pixel attribute values from them. The result is differentiable with respect to the
attribute values (not with respect to visibility or barycentrics).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from monoavatar.render.raster import Fragments

__all__ = ["interpolate", "interpolate_masked", "scatter_masked"]


def _faces_tensor(faces: Tensor | np.ndarray) -> Tensor:
    f = torch.as_tensor(faces)
    if f.is_floating_point() or f.dtype == torch.bool:
        raise ValueError(f"faces must be integers, got dtype {f.dtype}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {tuple(f.shape)}")
    return f.to(device="cpu", dtype=torch.int64)


def _check_attributes(attributes: Tensor, faces: Tensor | np.ndarray) -> Tensor:
    """Validate (V, C) or (F, 3, C) attributes against faces; return faces as int64."""
    if not isinstance(attributes, Tensor) or not attributes.is_floating_point():
        raise ValueError("attributes must be a floating-point torch tensor")
    f = _faces_tensor(faces)
    num_faces = f.shape[0]
    if attributes.ndim == 3:
        if attributes.shape[:2] != (num_faces, 3):
            raise ValueError(
                f"per-corner attributes must have shape (F, 3, C) with F={num_faces}, "
                f"got {tuple(attributes.shape)}"
            )
    elif attributes.ndim == 2:
        if num_faces and (int(f.min()) < 0 or int(f.max()) >= attributes.shape[0]):
            raise ValueError(
                f"faces index vertices in [{int(f.min())}, {int(f.max())}] but attributes "
                f"have {attributes.shape[0]} rows"
            )
    else:
        raise ValueError(
            f"attributes must have shape (V, C) or (F, 3, C), got {tuple(attributes.shape)}"
        )
    return f


def interpolate_masked(
    attributes: Tensor, faces: Tensor | np.ndarray, fragments: Fragments
) -> Tensor:
    """Interpolate attributes at the covered pixels only.

    Arguments as in :func:`interpolate`. Returns (N, C) values at the N pixels where
    ``fragments.mask`` is True, in row-major order — the order of ``image[fragments.mask]`` —
    so that per-pixel work (shading, texture lookups) can skip the background.
    """
    f = _check_attributes(attributes, faces)
    num_faces = f.shape[0]
    mask = fragments.face_id >= 0
    fid = fragments.face_id[mask]
    if fid.numel() and int(fid.max()) >= num_faces:
        raise ValueError(
            f"fragments refer to face {int(fid.max())} but faces has only {num_faces} rows"
        )
    device = attributes.device
    bary = fragments.bary[mask].to(dtype=attributes.dtype, device=device)
    fid = fid.to(device)
    if attributes.ndim == 2:
        corners = f.to(device)[fid]  # (N, 3)
        return (
            bary[:, 0:1] * attributes.index_select(0, corners[:, 0])
            + bary[:, 1:2] * attributes.index_select(0, corners[:, 1])
            + bary[:, 2:3] * attributes.index_select(0, corners[:, 2])
        )
    per_face = attributes.index_select(0, fid)  # (N, 3, C)
    return (bary.unsqueeze(-1) * per_face).sum(dim=1)


def scatter_masked(values: Tensor, fragments: Fragments, fill: float | Tensor = 0.0) -> Tensor:
    """Place (N, C) per-covered-pixel values (order of :func:`interpolate_masked`) into an
    (H, W, C) image whose background is ``fill`` (a scalar or a (C,) tensor). Differentiable
    in ``values`` and a tensor ``fill``."""
    mask = fragments.face_id >= 0
    if values.ndim != 2 or values.shape[0] != int(mask.sum()):
        raise ValueError(
            f"values must have shape (N, C) with N={int(mask.sum())} covered pixels, "
            f"got {tuple(values.shape)}"
        )
    channels = values.shape[1]
    fill_t = torch.as_tensor(fill, dtype=values.dtype, device=values.device)
    if fill_t.ndim not in (0, 1) or (fill_t.ndim == 1 and fill_t.shape[0] != channels):
        raise ValueError(f"fill must be a scalar or have shape ({channels},), got {fill_t.shape}")
    out = fill_t.expand(fragments.height, fragments.width, channels).contiguous()
    out[mask.to(values.device)] = values
    return out


def interpolate(
    attributes: Tensor,
    faces: Tensor | np.ndarray,
    fragments: Fragments,
    fill: float | Tensor = 0.0,
) -> Tensor:
    """Interpolate per-vertex or per-face-corner attributes at every pixel.

    Args:
        attributes: floating tensor, either
            (V, C) per vertex — corner ``k`` of face ``f`` takes ``attributes[faces[f, k]]``, or
            (F, 3, C) per face corner — e.g. ``uv[face_uv_idx]`` for UVs indexed apart from
            the vertices (then ``faces`` only fixes F).
        faces: (F, 3) integer vertex indices of the rasterised mesh.
        fragments: the rasterised mesh (:func:`monoavatar.render.raster.rasterize`).
        fill: value of background pixels: a scalar or a (C,) tensor.
    Returns:
        (H, W, C) tensor of the attributes' dtype: ``sum_k bary[k] * corner_k`` on covered
        pixels (perspective-correct), ``fill`` elsewhere. Differentiable in ``attributes``
        (and in a tensor ``fill``).
    Raises:
        ValueError: wrong shapes, faces out of range, fragments of a larger mesh.
    """
    return scatter_masked(interpolate_masked(attributes, faces, fragments), fragments, fill)
