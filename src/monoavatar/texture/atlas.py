"""Texel atlas: which surface point every texel of a UV texture stands for, and which texels are
neighbours on the surface (across UV seams too).

UV convention (glTF 2.0, as :mod:`monoavatar.render.renders`): ``(u, v) = (0, 0)`` is the
top-left corner of the texture, v grows downwards; texel ``(col, row)`` of an ``S x S`` texture
has its centre at ``((col + 0.5) / S, (row + 0.5) / S)``. Texels are addressed by their flat
index ``row * S + col``.

The atlas is found by rasterising the mesh in UV space (vertices ``(u S, v S, 1)``, faces
``face_uv``, an identity-intrinsics camera): a texel belongs to a chart when its centre lies in
a UV triangle; its barycentrics in that triangle locate it on the surface. UV triangles that
overlap give the texel to the one with the smaller face index.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from torch import Tensor

from monoavatar.core.camera import PinholeCamera
from monoavatar.core.errors import MonoavatarError
from monoavatar.render import rasterize

__all__ = ["TexelAtlas", "TextureError", "build_atlas", "seam_edges", "texel_graph"]


class TextureError(MonoavatarError, ValueError):
    """Invalid input to a texture-stage function (shapes, dtypes, sizes)."""


def as_array(x: Tensor | np.ndarray, dtype: type | np.dtype, name: str) -> np.ndarray:
    """A numpy copy-free view of a tensor or array, cast to ``dtype``."""
    if isinstance(x, Tensor):
        x = x.detach().cpu().numpy()
    a = np.asarray(x)
    if np.issubdtype(np.dtype(dtype), np.integer) and a.size and a.dtype.kind not in "iu":
        raise TextureError(f"{name} must be integers, got dtype {a.dtype}")
    return a.astype(dtype, copy=False)


def check_mesh_uv(
    faces: Tensor | np.ndarray,
    uv: Tensor | np.ndarray,
    face_uv: Tensor | np.ndarray,
    num_vertices: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate faces (F, 3), uv (T, 2), face_uv (F, 3); return them as int64/float64 arrays."""
    f = as_array(faces, np.int64, "faces")
    t = as_array(uv, np.float64, "uv")
    fu = as_array(face_uv, np.int64, "face_uv")
    if f.ndim != 2 or f.shape[1] != 3:
        raise TextureError(f"faces must have shape (F, 3), got {f.shape}")
    if t.ndim != 2 or t.shape[1] != 2:
        raise TextureError(f"uv must have shape (T, 2), got {t.shape}")
    if fu.shape != f.shape:
        raise TextureError(f"face_uv must have the shape of faces {f.shape}, got {fu.shape}")
    if not np.isfinite(t).all():
        raise TextureError("uv contains NaN or inf")
    if fu.size and (fu.min() < 0 or fu.max() >= len(t)):
        raise TextureError(f"face_uv indexes [{fu.min()}, {fu.max()}] but there are {len(t)} UVs")
    if num_vertices is not None and f.size and (f.min() < 0 or f.max() >= num_vertices):
        raise TextureError(
            f"faces index [{f.min()}, {f.max()}] but there are {num_vertices} vertices"
        )
    return f, t, fu


@dataclass(frozen=True)
class TexelAtlas:
    """The chart texels of an ``S x S`` texture and where they lie on the mesh.

    Attributes:
        size: S, texels per side.
        texels: (N,) int64 flat indices ``row * S + col`` of the chart texels, ascending.
        face: (N,) int64 face containing each chart texel's centre.
        bary: (N, 3) float32 barycentrics of the centre w.r.t. the face's corners (the same
            corner order in ``faces`` and ``face_uv``).
        index: (S * S,) int64 position of each texel in ``texels``, -1 outside the charts.
    """

    size: int
    texels: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    index: np.ndarray

    @property
    def num_texels(self) -> int:
        return int(self.texels.size)

    @property
    def chart(self) -> np.ndarray:
        """(S, S) bool, True on chart texels."""
        return (self.index >= 0).reshape(self.size, self.size)

    def points(
        self, vertices: np.ndarray, faces: np.ndarray, which: np.ndarray | None = None
    ) -> np.ndarray:
        """(N, C) attribute of each chart texel (or of the texels at positions ``which``),
        interpolated from per-vertex values ``vertices`` (V, C) with ``faces`` (F, 3)."""
        face = self.face if which is None else self.face[which]
        bary = self.bary if which is None else self.bary[which]
        return np.asarray(np.einsum("nk,nkc->nc", bary, vertices[faces[face]]))


def build_atlas(
    uv: Tensor | np.ndarray, face_uv: Tensor | np.ndarray, size: int = 1024
) -> TexelAtlas:
    """Rasterise the UV layout: face and barycentrics of every chart texel.

    Args:
        uv: (T, 2) texture coordinates, glTF convention.
        face_uv: (F, 3) indices into ``uv`` per face corner.
        size: texture side S in texels.
    """
    if int(size) < 2:
        raise TextureError(f"texture size must be at least 2, got {size}")
    size = int(size)
    t = as_array(uv, np.float64, "uv")
    fu = as_array(face_uv, np.int64, "face_uv")
    if t.ndim != 2 or t.shape[1] != 2:
        raise TextureError(f"uv must have shape (T, 2), got {t.shape}")
    points = np.concatenate([t * size, np.ones((len(t), 1))], axis=1)
    cam = PinholeCamera(K=np.eye(3), R=np.eye(3), t=np.zeros(3), width=size, height=size)
    frags = rasterize(points, fu, cam)
    face = frags.face_id.numpy().ravel()
    texels = np.flatnonzero(face >= 0)
    index = np.full(size * size, -1, dtype=np.int64)
    index[texels] = np.arange(texels.size)
    bary = frags.bary.numpy().reshape(-1, 3)[texels].astype(np.float32)
    return TexelAtlas(size=size, texels=texels, face=face[texels], bary=bary, index=index)


def seam_edges(faces: np.ndarray, face_uv: np.ndarray) -> np.ndarray:
    """Mesh edges cut by the UV layout: two faces share the edge's vertices but not its UVs.

    Returns:
        (E_s, 2, 2) int64: for each seam edge, ``[[uv_a, uv_b], [uv_a', uv_b']]`` — the UV
        indices of the edge's two endpoints (vertex a, then vertex b) on one side and on the
        other. Edges shared by more than two faces pair their first two sides.
    """
    f = np.asarray(faces, dtype=np.int64)
    fu = np.asarray(face_uv, dtype=np.int64)
    a = f.ravel()
    b = np.roll(f, -1, axis=1).ravel()
    ua = fu.ravel()
    ub = np.roll(fu, -1, axis=1).ravel()
    swap = a > b  # orient every half-edge from its smaller vertex
    lo, hi = np.where(swap, b, a), np.where(swap, a, b)
    ulo, uhi = np.where(swap, ub, ua), np.where(swap, ua, ub)
    order = np.lexsort((hi, lo))
    lo, hi, ulo, uhi = lo[order], hi[order], ulo[order], uhi[order]
    same = (lo[1:] == lo[:-1]) & (hi[1:] == hi[:-1])
    first = np.flatnonzero(same)
    if first.size:  # keep only the first pair of a run of half-edges on one edge
        first = first[np.r_[True, first[1:] != first[:-1] + 1]]
    second = first + 1
    cut = (ulo[first] != ulo[second]) | (uhi[first] != uhi[second])
    first, second = first[cut], second[cut]
    side1 = np.stack([ulo[first], uhi[first]], axis=1)
    side2 = np.stack([ulo[second], uhi[second]], axis=1)
    return np.stack([side1, side2], axis=1)


def _inner_texels(
    atlas: TexelAtlas, points: np.ndarray, inward: np.ndarray, steps: tuple[float, ...]
) -> np.ndarray:
    """Chart-texel position (in ``atlas.texels``) at each UV point (texel units), nudged along
    the unit ``inward`` direction by the first of ``steps`` (texels) that lands in a chart;
    -1 where none does."""
    S = atlas.size
    out = np.full(len(points), -1, dtype=np.int64)
    for step in steps:
        todo = out < 0
        if not todo.any():
            break
        p = points[todo] + step * inward[todo]
        col = np.floor(p[:, 0]).astype(np.int64)
        row = np.floor(p[:, 1]).astype(np.int64)
        ok = (col >= 0) & (col < S) & (row >= 0) & (row < S)
        found = np.full(len(p), -1, dtype=np.int64)
        found[ok] = atlas.index[row[ok] * S + col[ok]]
        out[np.flatnonzero(todo)] = found
    return out


def _seam_links(
    atlas: TexelAtlas, faces: np.ndarray, uv: np.ndarray, face_uv: np.ndarray
) -> np.ndarray:
    """(L, 2) pairs of chart texels (positions in ``atlas.texels``) facing each other across
    UV seams: the same surface points seen from the two charts an edge is cut into."""
    seams = seam_edges(faces, face_uv)
    if seams.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    S = atlas.size
    # the UV centroid of a face on each side, to step into the chart from the edge
    corner_uv = uv[face_uv] * S  # (F, 3, 2)
    face_centre = corner_uv.mean(axis=1)
    # map each seam side (uv_a, uv_b) to a face that has that UV edge
    fa = face_uv.ravel()
    fb = np.roll(face_uv, -1, axis=1).ravel()
    face_of = np.repeat(np.arange(len(face_uv)), 3)
    key = np.minimum(fa, fb) * len(uv) + np.maximum(fa, fb)
    order = np.argsort(key)
    key_sorted = key[order]
    ends = []
    for side in (0, 1):
        ea, eb = seams[:, side, 0], seams[:, side, 1]
        k = np.minimum(ea, eb) * len(uv) + np.maximum(ea, eb)
        pos = np.clip(np.searchsorted(key_sorted, k), 0, len(key_sorted) - 1)
        ends.append((uv[ea] * S, uv[eb] * S, face_centre[face_of[order[pos]]]))
    length = np.maximum(
        np.linalg.norm(ends[0][1] - ends[0][0], axis=1),
        np.linalg.norm(ends[1][1] - ends[1][0], axis=1),
    )
    count = np.maximum(2, np.ceil(2.0 * length).astype(np.int64) + 1)  # ~ two samples a texel
    edge = np.repeat(np.arange(len(seams)), count)
    start = np.cumsum(count) - count
    t = (np.arange(edge.size) - start[edge]) / (count[edge] - 1)
    found = []
    for p0, p1, centre in ends:
        pts = p0[edge] + t[:, None] * (p1[edge] - p0[edge])
        inward = centre[edge] - pts
        inward /= np.maximum(np.linalg.norm(inward, axis=1, keepdims=True), 1e-12)
        found.append(_inner_texels(atlas, pts, inward, (0.5, 1.0, 1.5)))
    ok = (found[0] >= 0) & (found[1] >= 0) & (found[0] != found[1])
    pairs = np.stack([found[0][ok], found[1][ok]], axis=1)
    pairs.sort(axis=1)
    return np.unique(pairs, axis=0)


def texel_graph(
    atlas: TexelAtlas,
    faces: Tensor | np.ndarray,
    uv: Tensor | np.ndarray,
    face_uv: Tensor | np.ndarray,
    positions: Tensor | np.ndarray,
) -> sp.csr_matrix:
    """Adjacency of chart texels on the surface: image 4-neighbours within a chart, plus links
    across UV seams.

    Two image neighbours are linked only when they are also close on the surface (at most
    four texel footprints apart in 3D), so charts that touch in the UV image stay apart.
    Across a seam edge, points sampled along the edge are found in both charts it is cut into
    and the two texels are linked.

    Args:
        atlas: from :func:`build_atlas`.
        faces: (F, 3) vertex indices; uv (T, 2), face_uv (F, 3): the UV layout of the atlas.
        positions: (V, 3) vertex positions (canonical or any pose), metres.
    Returns:
        (N, N) symmetric sparse matrix of 0/1 weights over ``atlas.texels``.
    """
    f, t, fu = check_mesh_uv(faces, uv, face_uv)
    pos = as_array(positions, np.float64, "positions")
    S, N = atlas.size, atlas.num_texels
    p3 = atlas.points(pos, f)
    # metres per texel on each face: sqrt(3D area / UV area in texels)
    tri = pos[f]
    area3 = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    tuv = t[fu] * S
    d1, d2 = tuv[:, 1] - tuv[:, 0], tuv[:, 2] - tuv[:, 0]
    area_uv = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    footprint = np.sqrt(area3 / np.maximum(area_uv, 1e-12))[atlas.face]
    rows, cols = [], []
    row_of, col_of = np.divmod(atlas.texels, S)
    for dr, dc in ((0, 1), (1, 0)):
        r2, c2 = row_of + dr, col_of + dc
        inside = (r2 < S) & (c2 < S)
        j = np.full(N, -1, dtype=np.int64)
        j[inside] = atlas.index[r2[inside] * S + c2[inside]]
        i = np.flatnonzero(j >= 0)
        j = j[i]
        dist = np.linalg.norm(p3[i] - p3[j], axis=1)
        near = dist <= 4.0 * np.maximum(footprint[i], footprint[j]) + 1e-9
        rows.append(i[near])
        cols.append(j[near])
    seams = _seam_links(atlas, f, t, fu)
    rows.append(seams[:, 0])
    cols.append(seams[:, 1])
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    w = np.ones(2 * r.size)
    graph = sp.coo_matrix((w, (np.r_[r, c], np.r_[c, r])), shape=(N, N)).tocsr()
    graph.data[:] = 1.0  # duplicates (a seam pair that is also an image pair) count once
    return graph
