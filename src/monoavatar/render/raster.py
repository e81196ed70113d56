"""Triangle rasterisation on the CPU: face ids, perspective-correct barycentrics, depth.

Conventions (:mod:`monoavatar.core.camera`):

- OpenCV camera: x right, y down, z forward; ``x_cam = R @ x_world + t``; metres.
- Pixel coordinates have their origin at the top-left *corner* of the top-left pixel; a pixel
  is covered when its *centre* ``(col + 0.5, row + 0.5)`` lies inside (or on the boundary of)
  the projected triangle. Triangles are two-sided unless ``RasterSettings.cull_backfaces``.
- Visibility is a z-buffer on camera-space z; exact depth ties go to the smaller face index.
- Triangles with any vertex at ``z <= near`` are culled whole (no near-plane clipping), as are
  triangles with zero projected area.

Rasterisation is not differentiable (visibility is a step function). Following OpenDR's
deferred approach, gradients flow through :func:`monoavatar.render.interpolate.interpolate`
with the fragments held fixed.

Two implementations share one contract: :func:`rasterize`, vectorised over triangles grouped
by bounding-box size, and :func:`_rasterize_reference`, a plain per-triangle loop kept as the
slow, obviously-correct reference for tests.

Watertightness: the edge function of an edge is evaluated with its two endpoints in a
canonical (lexicographic) order and negated where needed, so the two triangles sharing an
edge see exactly opposite values at every pixel centre and a centre on the edge is never
missed by both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from monoavatar.core.camera import PinholeCamera

__all__ = ["Fragments", "RasterSettings", "fragments_from_face_ids", "rasterize"]

# Bounding-box side lengths (pixels) that triangles are grouped into; a triangle whose box is
# w x h pixels is evaluated on the smallest listed size >= w times the smallest >= h.
_BUCKET_SIZES = np.array([1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128], dtype=np.int64)
# Groups whose padded box is larger than this many pixels are evaluated one triangle at a time
# on its exact box.
_LARGE_BOX = 128 * 128
# Number of (face, pixel) candidates evaluated at once: small enough to stay in cache.
_CHUNK = 1 << 14


@dataclass(frozen=True)
class RasterSettings:
    """Options of :func:`rasterize`.

    Attributes:
        near: near-plane distance in metres (> 0); a triangle with any vertex at camera
            ``z <= near`` is culled whole.
        cull_backfaces: drop triangles whose geometric normal ``(v1 - v0) x (v2 - v0)``
            points away from the camera (faces seen from behind).
    """

    near: float = 1e-2
    cull_backfaces: bool = False

    def __post_init__(self) -> None:
        if not np.isfinite(self.near) or self.near <= 0:
            raise ValueError(f"near must be a positive finite distance, got {self.near}")


@dataclass(frozen=True)
class Fragments:
    """What a camera sees of a mesh, per pixel (the hand-off from rasteriser to shaders).

    All fields are CPU tensors; H, W are ``camera.height``, ``camera.width``.

    Attributes:
        face_id: (H, W) int64 index of the visible face, -1 for background.
        bary: (H, W, 3) float32 perspective-correct barycentric coordinates of the pixel centre
            with respect to the face's vertices ``faces[face_id]`` (sum to 1; zeros for
            background).
        depth: (H, W) float32 camera-space z of the visible surface in metres (``inf`` for
            background).
    """

    face_id: Tensor
    bary: Tensor
    depth: Tensor

    @property
    def height(self) -> int:
        return int(self.face_id.shape[0])

    @property
    def width(self) -> int:
        return int(self.face_id.shape[1])

    @property
    def mask(self) -> Tensor:
        """(H, W) bool, True where a face is visible."""
        return self.face_id >= 0


# -- input handling ------------------------------------------------------------------------


def _as_vertices(vertices: Tensor | np.ndarray) -> np.ndarray:
    if isinstance(vertices, Tensor):
        v = vertices.detach().cpu().to(torch.float64).numpy()
    else:
        v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape (V, 3), got {tuple(v.shape)}")
    if not np.isfinite(v).all():
        raise ValueError("vertices contain NaN or inf")
    return v


def _as_faces(faces: Tensor | np.ndarray, num_vertices: int) -> np.ndarray:
    if isinstance(faces, Tensor):
        if faces.is_floating_point() or faces.dtype == torch.bool:
            raise ValueError(f"faces must be an integer tensor, got dtype {faces.dtype}")
        f = faces.detach().cpu().numpy().astype(np.int64, copy=False)
    else:
        f = np.asarray(faces)
        if f.size and not np.issubdtype(f.dtype, np.integer):
            raise ValueError(f"faces must be integers, got dtype {f.dtype}")
        f = f.astype(np.int64, copy=False)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {tuple(f.shape)}")
    if f.size and (f.min() < 0 or f.max() >= num_vertices):
        raise ValueError(
            f"faces index vertices out of range: indices span [{f.min()}, {f.max()}] "
            f"but there are {num_vertices} vertices"
        )
    return f


def _check_camera(camera: PinholeCamera) -> None:
    if not isinstance(camera, PinholeCamera):
        raise ValueError(f"camera must be a PinholeCamera, got {type(camera).__name__}")


def _to_camera_and_pixels(v_world: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    """(V, 3) world points → (V, 3) rows ``(px, py, z)``: pixel coordinates and camera z.

    Pixel coordinates are meaningless (but finite) for points with z <= 0; callers cull those.
    """
    cam = v_world @ camera.R.T + camera.t
    z = cam[:, 2]
    safe_z = np.where(z > 0, z, 1.0)
    uvw = cam @ camera.K.T
    out = np.empty_like(cam)
    out[:, 0] = uvw[:, 0] / safe_z
    out[:, 1] = uvw[:, 1] / safe_z
    out[:, 2] = z
    return out


def _empty_fragments(height: int, width: int) -> Fragments:
    return Fragments(
        face_id=torch.from_numpy(np.full((height, width), -1, dtype=np.int64)),
        bary=torch.from_numpy(np.zeros((height, width, 3), dtype=np.float32)),
        depth=torch.from_numpy(np.full((height, width), np.inf, dtype=np.float32)),
    )


# -- fast path ------------------------------------------------------------------------------


@dataclass(frozen=True)
class _FaceSetup:
    """Per-face quantities of the T faces that survive culling, sorted by box-size group.

    Edge k is the edge opposite corner k. Its edge function at a pixel centre (x, y) is
    ``E_k = dx[k] * (y - py[k]) - dy[k] * (x - px[k])``, >= 0 inside the triangle; ``(px, py)``
    is the lexicographically smaller endpoint and ``(dx, dy)`` the vector to the other one,
    negated where needed (exact), so faces sharing an edge compute exactly opposite values.

    Attributes:
        face: (T,) int64 indices into the input faces.
        px, py, dx, dy: (3, T) float64, pixels.
        invz: (3, T) float64 inverse camera z of the corners (1 / metres).
        x0, y0: (T,) int64 first column / row of the box of candidate pixel centres.
        w, h: (T,) int64 box size in pixels (>= 1).
    """

    face: np.ndarray
    px: np.ndarray
    py: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    invz: np.ndarray
    x0: np.ndarray
    y0: np.ndarray
    w: np.ndarray
    h: np.ndarray


def _setup_faces(
    pz: np.ndarray, faces: np.ndarray, width: int, height: int, settings: RasterSettings
) -> tuple[_FaceSetup, np.ndarray]:
    """Cull faces; compute edge functions and boxes of candidate pixels of the rest.

    Returns the setup, sorted by group, and each face's group key (T,) from :func:`_box_key`.
    """
    xs, ys, zs = (np.ascontiguousarray(pz[:, j]) for j in range(3))
    corners = [np.ascontiguousarray(faces[:, k]) for k in range(3)]
    z = [zs[c] for c in corners]
    keep = (z[0] > settings.near) & (z[1] > settings.near) & (z[2] > settings.near)
    x = [xs[c] for c in corners]
    y = [ys[c] for c in corners]
    area2 = (x[1] - x[0]) * (y[2] - y[0]) - (x[2] - x[0]) * (y[1] - y[0])
    # A back face (normal (v1 - v0) x (v2 - v0) pointing away from the camera) has area2 > 0
    # in these pixel coordinates (x right, y down).
    keep &= area2 < 0 if settings.cull_backfaces else area2 != 0
    # Pixel centres col + 0.5 in [xmin, xmax]  <=>  col in [ceil(xmin - .5), floor(xmax - .5)].
    x_lo = np.maximum(np.ceil(np.minimum(np.minimum(x[0], x[1]), x[2]) - 0.5), 0.0)
    x_hi = np.minimum(np.floor(np.maximum(np.maximum(x[0], x[1]), x[2]) - 0.5), width - 1.0)
    y_lo = np.maximum(np.ceil(np.minimum(np.minimum(y[0], y[1]), y[2]) - 0.5), 0.0)
    y_hi = np.minimum(np.floor(np.maximum(np.maximum(y[0], y[1]), y[2]) - 0.5), height - 1.0)
    keep &= (x_hi >= x_lo) & (y_hi >= y_lo)
    idx = np.flatnonzero(keep)
    x_lo, y_lo = x_lo[idx].astype(np.int64), y_lo[idx].astype(np.int64)
    w = x_hi[idx].astype(np.int64) - x_lo + 1
    h = y_hi[idx].astype(np.int64) - y_lo + 1
    # Sort by padded box size so that each group of faces is a contiguous slice.
    key = _box_key(w, h)
    order = np.argsort(key, kind="stable")
    idx, key = idx[order], key[order]
    x = [a[idx] for a in x]
    y = [a[idx] for a in y]
    orient = np.where(area2[idx] > 0, 1.0, -1.0)
    P = np.empty((2, 3, idx.size))
    D = np.empty((2, 3, idx.size))
    for k in range(3):
        a, b = (k + 1) % 3, (k + 2) % 3
        swap = (x[a] > x[b]) | ((x[a] == x[b]) & (y[a] > y[b]))
        P[0, k] = np.where(swap, x[b], x[a])
        P[1, k] = np.where(swap, y[b], y[a])
        sign = np.where(swap, -orient, orient)
        D[0, k] = (np.where(swap, x[a], x[b]) - P[0, k]) * sign
        D[1, k] = (np.where(swap, y[a], y[b]) - P[1, k]) * sign
    setup = _FaceSetup(
        face=idx,
        px=P[0],
        py=P[1],
        dx=D[0],
        dy=D[1],
        invz=1.0 / np.stack([a[idx] for a in z]),
        x0=x_lo[order],
        y0=y_lo[order],
        w=w[order],
        h=h[order],
    )
    return setup, key


def _box_key(w: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(T,) group key of boxes w x h: indices of the padded sizes in ``_BUCKET_SIZES``
    (index ``len(_BUCKET_SIZES)`` means larger than every size)."""
    n = len(_BUCKET_SIZES)
    return np.searchsorted(_BUCKET_SIZES, w) * (n + 1) + np.searchsorted(_BUCKET_SIZES, h)


# A group of faces evaluated together: (start, stop) rows of the sorted setup, box width and
# height in pixels, and a row offset (for slabs of one large face).
_Group = tuple[int, int, int, int, int]


def _groups(setup: _FaceSetup, key: np.ndarray) -> list[_Group]:
    """Cut the sorted faces into groups sharing a padded box, each of bounded size."""
    n = len(_BUCKET_SIZES)
    if key.size == 0:
        return []
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    ends = np.r_[starts[1:], key.size]
    groups: list[_Group] = []
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        iw, ih = divmod(int(key[s]), n + 1)
        if iw < n and ih < n and _BUCKET_SIZES[iw] * _BUCKET_SIZES[ih] <= _LARGE_BOX:
            gw, gh = int(_BUCKET_SIZES[iw]), int(_BUCKET_SIZES[ih])
            step = max(1, _CHUNK // (gw * gh))
            groups.extend((c, min(c + step, e), gw, gh, 0) for c in range(s, e, step))
        else:  # large faces: one at a time on their exact box, in slabs of rows
            for r in range(s, e):
                w, h = int(setup.w[r]), int(setup.h[r])
                slab = max(1, _CHUNK // w)
                groups.extend((r, r + 1, w, min(slab, h - y), y) for y in range(0, h, slab))
    return groups


def _edge_function(
    s: _FaceSetup, k: int, rows: slice | np.ndarray, cx: np.ndarray, cy: np.ndarray
) -> np.ndarray:
    """Edge function k (>= 0 inside) of faces ``rows`` at pixel centres ``(cx, cy)``.

    The one formula every edge test uses: ``dx * (cy - py) - dy * (cx - px)``, broadcasting
    the (T,) face quantities against (..., T) centres. Evaluated identically for every face,
    so two faces sharing an edge get exactly opposite values.
    """
    a = cy - s.py[k, rows]
    a *= s.dx[k, rows]
    b = cx - s.px[k, rows]
    b *= s.dy[k, rows]
    a -= b
    return a


def _group_fragments(
    s: _FaceSetup, group: _Group, width: int, height: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fragments of one group: flat pixel index (N,), face row in ``s`` (N,), 1/z (N,)."""
    start, stop, gw, gh, y_shift = group
    off_x = np.tile(np.arange(gw, dtype=np.int64), gh)  # (K,)
    off_y = np.repeat(np.arange(y_shift, y_shift + gh, dtype=np.int64), gw)
    sl = slice(start, stop)
    # (K, T) pixel centres: candidates along axis 0, faces along the contiguous axis 1.
    cx = off_x[:, None] + (s.x0[sl] + 0.5)[None, :]
    cy = off_y[:, None] + (s.y0[sl] + 0.5)[None, :]
    e = [_edge_function(s, k, sl, cx, cy) for k in range(3)]
    inside = np.minimum(e[0], e[1])
    np.minimum(inside, e[2], out=inside)
    flat = np.flatnonzero(inside >= 0)
    kk, tt = np.divmod(flat, stop - start)
    tt += start
    col = s.x0[tt] + off_x[kk]
    row = s.y0[tt] + off_y[kk]
    e0, e1, e2 = (a.ravel()[flat] for a in e)
    total = e0 + e1 + e2
    invz = (e0 * s.invz[0, tt] + e1 * s.invz[1, tt] + e2 * s.invz[2, tt]) / np.where(
        total > 0, total, np.inf
    )
    ok = (col < width) & (row < height) & (total > 0)
    return (row * width + col)[ok], tt[ok], invz[ok]


def _resolve(pz: np.ndarray, faces: np.ndarray, face_id: np.ndarray) -> Fragments:
    """Complete :class:`Fragments` from a face-id image.

    face_id: (H, W) int64 winning face per pixel, -1 for background (becomes the result's
    ``face_id``). Barycentrics and depth are computed in float64 from the faces' corners.
    """
    height, width = face_id.shape
    bary = np.zeros((height, width, 3), dtype=np.float32)
    depth = np.full((height, width), np.inf, dtype=np.float32)
    pixel = np.flatnonzero(face_id >= 0)
    corner = faces[face_id.ravel()[pixel]]  # (N, 3)
    cx = (pixel % width) + 0.5
    cy = (pixel // width) + 0.5
    # Corner positions relative to the pixel centre.
    x = [pz[corner[:, k], 0] - cx for k in range(3)]
    y = [pz[corner[:, k], 1] - cy for k in range(3)]
    z = [pz[corner[:, k], 2] for k in range(3)]
    # Screen-space barycentrics: signed areas of the sub-triangles opposite each corner.
    lam = np.empty((3, pixel.size))
    for k in range(3):
        a, b = (k + 1) % 3, (k + 2) % 3
        lam[k] = x[a] * y[b] - x[b] * y[a]
    lam /= lam.sum(axis=0)
    np.clip(lam, 0.0, None, out=lam)  # centres on an edge may round slightly below 0
    for k in range(3):
        lam[k] /= z[k]
    invz = lam.sum(axis=0)
    lam /= invz
    bary.reshape(-1, 3)[pixel] = lam.T
    depth.reshape(-1)[pixel] = 1.0 / invz
    return Fragments(
        face_id=torch.from_numpy(face_id),
        bary=torch.from_numpy(bary),
        depth=torch.from_numpy(depth),
    )


def rasterize(
    vertices: Tensor | np.ndarray,
    faces: Tensor | np.ndarray,
    camera: PinholeCamera,
    settings: RasterSettings | None = None,
) -> Fragments:
    """Rasterise a triangle mesh seen by a pinhole camera.

    Args:
        vertices: (V, 3) world coordinates in metres (tensor or array; gradients are not
            tracked — see :func:`monoavatar.render.interpolate.interpolate`).
        faces: (F, 3) integer vertex indices.
        camera: the camera; the image is ``camera.height`` x ``camera.width`` pixels.
        settings: near plane and back-face culling; defaults to :class:`RasterSettings()`.
    Returns:
        :class:`Fragments` with (H, W) face ids, (H, W, 3) perspective-correct barycentrics
        and (H, W) camera-z depth in metres.
    Raises:
        ValueError: wrong shapes or dtypes, non-finite vertices, faces out of range.
    """
    settings = settings or RasterSettings()
    _check_camera(camera)
    v = _as_vertices(vertices)
    f = _as_faces(faces, v.shape[0])
    height, width = camera.height, camera.width
    if f.shape[0] == 0:
        return _empty_fragments(height, width)
    pz = _to_camera_and_pixels(v, camera)
    setup, key = _setup_faces(pz, f, width, height, settings)
    parts = [_group_fragments(setup, g, width, height) for g in _groups(setup, key)]
    if not parts:
        return _empty_fragments(height, width)
    pixel = np.concatenate([p[0] for p in parts])
    face = setup.face[np.concatenate([p[1] for p in parts])]
    invz = np.concatenate([p[2] for p in parts])
    # z-buffer: keep the largest 1/z per pixel, then the smallest face index among exact ties.
    best = np.full(height * width, -np.inf)
    np.maximum.at(best, pixel, invz)
    win = invz == best[pixel]
    pixel, face = pixel[win], face[win]
    none = np.iinfo(np.int64).max
    face_id = np.full(height * width, none)
    np.minimum.at(face_id, pixel, face)
    face_id[face_id == none] = -1
    return _resolve(pz, f, face_id.reshape(height, width))


def fragments_from_face_ids(
    vertices: Tensor | np.ndarray,
    faces: Tensor | np.ndarray,
    camera: PinholeCamera,
    face_id: np.ndarray,
) -> Fragments:
    """The :class:`Fragments` :func:`rasterize` gives for these vertices, faces and camera,
    from its ``face_id`` image alone (H, W) int64 (-1: background): the barycentrics and
    depths computed again, without the visibility search (for a mesh rasterised before at the
    same vertices, e.g. with only its face ids kept)."""
    _check_camera(camera)
    v = _as_vertices(vertices)
    f = _as_faces(faces, v.shape[0])
    face_id = np.asarray(face_id, dtype=np.int64)
    if face_id.shape != (camera.height, camera.width):
        raise ValueError(f"face_id must have shape ({camera.height}, {camera.width}), got "
                         f"{face_id.shape}")  # fmt: skip
    if face_id.size and face_id.max() >= f.shape[0]:
        raise ValueError(f"face_id indexes {face_id.max()} but there are {f.shape[0]} faces")
    return _resolve(_to_camera_and_pixels(v, camera), f, face_id)


# -- slow reference -------------------------------------------------------------------------


def _rasterize_reference(
    vertices: Tensor | np.ndarray,
    faces: Tensor | np.ndarray,
    camera: PinholeCamera,
    settings: RasterSettings | None = None,
) -> Fragments:
    """Per-triangle loop with a float64 z-buffer: slow, obviously correct; same contract as
    :func:`rasterize`. For tests only."""
    settings = settings or RasterSettings()
    _check_camera(camera)
    v = _as_vertices(vertices)
    f = _as_faces(faces, v.shape[0])
    H, W = camera.height, camera.width
    face_id = np.full((H, W), -1, dtype=np.int64)
    bary = np.zeros((H, W, 3))
    depth = np.full((H, W), np.inf)
    cam = v @ camera.R.T + camera.t
    cols, rows = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    for i, (a, b, c) in enumerate(f):
        za, zb, zc = cam[a, 2], cam[b, 2], cam[c, 2]
        if min(za, zb, zc) <= settings.near:
            continue
        pa, pb, pc = (camera.K @ (cam[j] / cam[j, 2]) for j in (a, b, c))
        area2 = (pb[0] - pa[0]) * (pc[1] - pa[1]) - (pc[0] - pa[0]) * (pb[1] - pa[1])
        if area2 == 0 or (settings.cull_backfaces and area2 > 0):
            continue
        x_lo = max(int(np.floor(min(pa[0], pb[0], pc[0]))) - 1, 0)
        x_hi = min(int(np.ceil(max(pa[0], pb[0], pc[0]))) + 1, W)
        y_lo = max(int(np.floor(min(pa[1], pb[1], pc[1]))) - 1, 0)
        y_hi = min(int(np.ceil(max(pa[1], pb[1], pc[1]))) + 1, H)
        if x_lo >= x_hi or y_lo >= y_hi:
            continue
        X = cols[y_lo:y_hi, x_lo:x_hi]
        Y = rows[y_lo:y_hi, x_lo:x_hi]
        # Screen-space barycentrics as ratios of signed areas.
        la = ((pb[0] - X) * (pc[1] - Y) - (pc[0] - X) * (pb[1] - Y)) / area2
        lb = ((pc[0] - X) * (pa[1] - Y) - (pa[0] - X) * (pc[1] - Y)) / area2
        lc = 1.0 - la - lb
        inside = (la >= 0) & (lb >= 0) & (lc >= 0)
        z = 1.0 / (la / za + lb / zb + lc / zc)
        closer = inside & (z < depth[y_lo:y_hi, x_lo:x_hi])
        yy, xx = np.nonzero(closer)
        yy, xx = yy + y_lo, xx + x_lo
        zz = z[closer]
        depth[yy, xx] = zz
        face_id[yy, xx] = i
        bary[yy, xx] = np.stack(
            [la[closer] * zz / za, lb[closer] * zz / zb, lc[closer] * zz / zc], axis=-1
        )
    return Fragments(
        face_id=torch.from_numpy(face_id),
        bary=torch.from_numpy(bary.astype(np.float32)),
        depth=torch.from_numpy(depth.astype(np.float32)),
    )
