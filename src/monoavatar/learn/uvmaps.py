"""Maps in UV space (Paper E, Sec. E.4): per-vertex attributes of the once-subdivided body
rasterised into the UV atlas, and maps sampled back onto the mesh's vertices.

The maps of Tex2Shape are images in the body's UV layout: a vector displacement map (the
clothed surface minus the body, canonical frame, metres) and a normal map (the clothed
surface's normals, canonical frame). Our synthetic subjects are displacements of the same
subdivided mesh (:mod:`monoavatar.synth.subjects`), so their maps are exact: every texel is
the barycentric interpolation of vertex values inside one fine triangle.

Conventions: UVs in the glTF convention (origin top-left, v down); texel (row, col) covers
``[col, col+1) x [row, row+1)`` in units of ``1/S``; maps are (S, S, C) float32 arrays, zero
outside the charts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from monoavatar.body import BodyModel
from monoavatar.body.subdivide import Subdivision, subdivide
from monoavatar.core.errors import MonoavatarError
from monoavatar.core.geometry import vertex_normals
from monoavatar.texture.atlas import TexelAtlas, build_atlas
from monoavatar.texture.fill import dilate_texture

__all__ = [
    "DISPLACEMENT_SCALE",
    "UVLayout",
    "displacement_targets",
    "from_normal_frame",
    "rasterise_vertex_values",
    "sample_vertex_values",
    "texel_frames",
    "to_normal_frame",
    "uv_layout",
]

DISPLACEMENT_SCALE = 0.05
"""Metres per unit of the network's displacement channels (clothing and hair lie within
about ±0.05 m of the body)."""


class UVMapError(MonoavatarError, ValueError):
    """A map or per-vertex array of the wrong shape for the layout."""


@dataclass(frozen=True)
class UVLayout:
    """The once-subdivided body mesh and its texel atlas at ``S x S``.

    Attributes:
        subdivision: the fine mesh's connectivity, UVs and skinning weights.
        atlas: chart texels of the fine mesh's UV layout.
        num_coarse: V, vertices of the body model (the first V fine vertices).
    """

    subdivision: Subdivision
    atlas: TexelAtlas
    num_coarse: int

    @property
    def size(self) -> int:
        return self.atlas.size

    @property
    def num_vertices(self) -> int:
        """V_f, vertices of the fine mesh."""
        return int(self.subdivision.weights.shape[0])

    @property
    def chart(self) -> np.ndarray:
        """(S, S) bool, texels inside the charts."""
        return self.atlas.chart


def uv_layout(body: BodyModel, size: int = 256) -> UVLayout:
    """The layout of ``body`` subdivided once, rasterised at ``size`` texels per side."""
    sub = subdivide(body.faces, body.uv, body.face_uv, body.skin_weights)
    atlas = build_atlas(sub.uv, sub.face_uv, size)
    return UVLayout(subdivision=sub, atlas=atlas, num_coarse=body.num_vertices)


def rasterise_vertex_values(layout: UVLayout, values: np.ndarray) -> np.ndarray:
    """(S, S, C) float32 map of per-fine-vertex values (V_f, C), barycentrically interpolated
    at each chart texel's centre; 0 outside the charts."""
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 2 or v.shape[0] != layout.num_vertices:
        raise UVMapError(f"values: expected ({layout.num_vertices}, C), got {v.shape}")
    faces = layout.subdivision.faces.numpy()
    S = layout.size
    out = np.zeros((S * S, v.shape[1]), np.float32)
    out[layout.atlas.texels] = layout.atlas.points(v, faces)
    return out.reshape(S, S, v.shape[1])


def sample_vertex_values(layout: UVLayout, image: np.ndarray, coarse: bool = False
                         ) -> np.ndarray:  # fmt: skip
    """Per-vertex values (V_f, C) — or (V, C) of the coarse vertices with ``coarse`` — read
    bilinearly from a map (S', S', C) at each vertex's UVs. A vertex on a UV seam has several
    UVs; it gets the mean of its samples. The map is first grown beyond its charts (by
    :func:`monoavatar.texture.fill.dilate_texture`), so texels outside them do not leak in.
    Any S' works: UVs are resolution-free."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 3 or img.shape[0] != img.shape[1]:
        raise UVMapError(f"map: expected (S, S, C), got {img.shape}")
    S = img.shape[0]
    chart = layout.chart
    if S != layout.size:
        idx = np.minimum(((np.arange(S) + 0.5) * layout.size / S).astype(np.int64),
                         layout.size - 1)  # fmt: skip
        chart = chart[idx][:, idx]
    grown = dilate_texture(img, chart, 4)
    sub = layout.subdivision
    uv = sub.uv.double().numpy()
    faces = sub.faces.numpy().ravel()
    face_uv = sub.face_uv.numpy().ravel()
    # every (vertex, uv) corner pair, once
    pairs = np.unique(np.stack([faces, face_uv], 1), axis=0)
    if coarse:
        pairs = pairs[pairs[:, 0] < layout.num_coarse]
    samples = _bilinear(grown, uv[pairs[:, 1], 0] * S - 0.5, uv[pairs[:, 1], 1] * S - 0.5)
    n = layout.num_coarse if coarse else layout.num_vertices
    total = np.zeros((n, samples.shape[1]))
    count = np.zeros(n)
    np.add.at(total, pairs[:, 0], samples)
    np.add.at(count, pairs[:, 0], 1.0)
    if (count == 0).any():
        raise UVMapError(f"{int((count == 0).sum())} vertices have no UVs")
    return total / count[:, None]


def _bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(N, C) bilinear samples of (S, S, C) at texel coordinates x, y (N,) (texel centres at
    integers), clamped at the border."""
    S = image.shape[0]
    x = np.clip(x, 0, S - 1)
    y = np.clip(y, 0, S - 1)
    x0 = np.minimum(np.floor(x).astype(np.int64), S - 2)
    y0 = np.minimum(np.floor(y).astype(np.int64), S - 2)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    im = image.astype(np.float64)
    top = im[y0, x0] * (1 - fx) + im[y0, x0 + 1] * fx
    bottom = im[y0 + 1, x0] * (1 - fx) + im[y0 + 1, x0 + 1] * fx
    return np.asarray(top * (1 - fy) + bottom * fy)


def displacement_targets(layout: UVLayout, base: torch.Tensor, surface: torch.Tensor
                         ) -> np.ndarray:  # fmt: skip
    """The maps a network learns, (S, S, 6) float32: channels 0–2 the vector displacement
    ``(surface − base) / DISPLACEMENT_SCALE`` and 3–5 the unit normals of ``surface``, both in
    the canonical frame.

    Args:
        base: (V_f, 3) fine canonical vertices of the body alone, metres.
        surface: (V_f, 3) fine canonical vertices of the clothed surface, metres.
    """
    if base.shape != surface.shape or base.shape != (layout.num_vertices, 3):
        raise UVMapError(f"base {tuple(base.shape)} and surface {tuple(surface.shape)} must "
                         f"both be ({layout.num_vertices}, 3)")  # fmt: skip
    disp = (surface - base).double().numpy() / DISPLACEMENT_SCALE
    normals = vertex_normals(surface.double(), layout.subdivision.faces).numpy()
    return rasterise_vertex_values(layout, np.concatenate([disp, normals], axis=1))


def texel_frames(layout: UVLayout, fine_vertices: np.ndarray) -> np.ndarray:
    """(S, S, 3, 3) float32 orthonormal frame of the surface ``fine_vertices`` (V_f, 3) at each
    chart texel, canonical frame; rows: the outward unit normal ``n``, a tangent ``t1`` (the
    body's up axis +y with its normal part removed; +x where the normal is nearly vertical) and
    ``t2 = n × t1``. Zero outside the charts."""
    v = torch.as_tensor(np.asarray(fine_vertices, np.float64))
    if v.shape != (layout.num_vertices, 3):
        raise UVMapError(f"vertices: expected ({layout.num_vertices}, 3), got {tuple(v.shape)}")
    n = rasterise_vertex_values(layout, vertex_normals(v, layout.subdivision.faces).numpy())
    n = n.astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    ref = np.where(np.abs(n[..., 1:2]) < 0.9, [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    t1 = ref - (ref * n).sum(-1, keepdims=True) * n
    t1 /= np.maximum(np.linalg.norm(t1, axis=-1, keepdims=True), 1e-12)
    frames = np.stack([n, t1, np.cross(n, t1)], axis=-2)
    frames[~layout.chart] = 0.0
    return frames.astype(np.float32)


def to_normal_frame(disp: np.ndarray, frames: np.ndarray, tangential_scale: float
                    ) -> np.ndarray:  # fmt: skip
    """(..., 3) displacement components along the texels' frames (S, S, 3, 3) of
    :func:`texel_frames`: ``(d·n, s d·t1, s d·t2)`` with ``s = tangential_scale``, so an L1
    loss on them weighs tangential error by ``s``. ``disp`` is (S, S, 3) or (N, S, S, 3)."""
    local = np.einsum("...ij,...j->...i", frames, disp)
    local[..., 1:] *= tangential_scale
    return local.astype(disp.dtype, copy=False)


def from_normal_frame(local: np.ndarray, frames: np.ndarray, tangential_scale: float
                      ) -> np.ndarray:  # fmt: skip
    """The canonical displacement (..., 3) back from :func:`to_normal_frame`'s components."""
    unscaled = np.array(local, dtype=np.float64)
    unscaled[..., 1:] /= tangential_scale
    return np.einsum("...ji,...j->...i", frames.astype(np.float64), unscaled).astype(local.dtype)
