"""Texture from back-projection: the median of the most orthogonal views (Sec. B.3.4).

"To create the texture, we warp our estimated canonical model back to each frame, back-project
the image color to all visible vertices, and finally generate a texture image by calculating
the median of the most orthogonal texels from all views." Here per texel rather than per vertex:

1. every chart texel of the UV layout is a point on the mesh (:mod:`monoavatar.texture.atlas`);
2. in each key frame the posed mesh is rasterised; a texel is *visible* when the rasteriser shows
   its own face at its projection, or a surface within ``depth_tolerance`` of its depth; samples
   near the person mask's border or near depth discontinuities of the render (where a small
   misalignment of the fitted body picks up the background or an occluder) are dropped;
3. each visible texel gets the bilinearly sampled image colour and the cosine between its
   (smooth) normal and the direction to the camera; optionally the colour is divided by the
   SH shading of that normal (the texture is then albedo);
4. per texel the ``top_k`` views with the largest cosine are kept and the texel is set to their
   per-channel median (robust to a view that is occluded or misregistered); or, with
   ``method="graphcut"``, each texel takes one view's colour, chosen by semantic graph cuts
   (:mod:`monoavatar.texture.graphcut`);
5. texels never seen are filled harmonically over the surface (across UV seams,
   :mod:`monoavatar.texture.fill`), and the charts are dilated so mipmaps do not bleed;
6. registration (``register_rounds``): a key-frame pose a few degrees off puts a colour edge a
   pixel or two away from where the other views put it, and the median blurs or doubles it.
   The texture of step 5 is rendered into every key frame (over the frame itself), the optical
   flow from that render to the frame (OpenCV DIS) tells where each texel's colour lies in the
   frame, and steps 2-5 run again sampling there. The views then agree with each other (not
   necessarily with a surface they cannot see); flow longer than ``max_flow`` is ignored.

Conventions: OpenCV cameras (:class:`monoavatar.core.camera.PinholeCamera`), pixel centres at
``(col + 0.5, row + 0.5)``, metres; glTF UVs; colours linear in [0, 1] (frames as uint8).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from monoavatar.core.camera import PinholeCamera
from monoavatar.core.threads import frame_pool
from monoavatar.perception.flow import DISFlow
from monoavatar.render import (
    Fragments,
    fragments_from_face_ids,
    rasterize,
    render_over_image,
    sh_shading,
    vertex_normals,
)
from monoavatar.texture.atlas import (
    TexelAtlas,
    TextureError,
    as_array,
    build_atlas,
    check_mesh_uv,
    texel_graph,
)
from monoavatar.texture.fill import dilate_texture, harmonic_fill
from monoavatar.texture.graphcut import GraphCutSettings, merge_views

__all__ = ["TextureSettings", "UVTexture", "build_texture", "sampling_size"]


METHODS = ("median", "graphcut")


@dataclass(frozen=True)
class TextureSettings:
    """Options of :func:`build_texture`.

    Attributes:
        size: side of the returned texture in texels.
        sample_size: side of the texture grid the views are sampled on; the result is resized
            to ``size``. None picks it from the data: the smallest grid whose texels are
            ``texels_per_pixel`` times finer than the frames' pixels on the surface, at most
            ``size`` (a 540-pixel frame of a whole standing person gives about 340; sampling
            finer costs time and adds no detail the frames do not have).
        texels_per_pixel: see ``sample_size``.
        top_k: views per texel whose median is taken (the most orthogonal ones).
        min_cos: views seeing a texel at a cosine (normal · direction to the camera) below this
            are ignored.
        depth_tolerance: metres; a texel whose projection shows another face still counts as
            visible when that surface is this close to the texel's depth.
        mask_margin: pixels; samples closer than this to the border of the person mask (or
            outside it) are dropped.
        edge_margin: pixels; samples within this distance of an occlusion boundary of the
            rendered mesh (a depth jump between neighbouring pixels, both on the mesh) are
            dropped: a slightly misplaced body would take the occluder's colour there.
        edge_depth: metres; the smallest depth jump that is an occlusion boundary (larger jumps
            are needed where an oblique surface changes depth that much across one pixel).
        shading_floor: when dividing out shading, shading values are clamped to at least this.
        fill: harmonically fill texels never seen (otherwise they stay black).
        dilation: texels to grow the texture beyond the chart borders.
        register_rounds: rounds of flow registration (step 6 of the module docstring): the
            texture so far is rendered into every key frame, the optical flow from that render
            to the frame says where each texel's colour really lies, and the views are
            sampled again there. 0 samples each view where the fitted pose projects it.
        max_flow: pixels; registration flow longer than this is not trusted (the sample keeps
            its projected position).
        mirror_radius: metres; see ``mirror_vertices`` of :func:`build_texture`.
        workers: threads that sample frames side by side (rasterising, registration flow and
            sampling; the samples are added to the median in frame order, so the texture
            depends on the count only through rounding, see
            :func:`monoavatar.core.threads.frame_pool`).
        method: how the views are merged in the last round: ``"median"`` (step 4) or
            ``"graphcut"``, one view per texel with seams on semantic boundaries
            (:mod:`monoavatar.texture.graphcut`, Sec. C.3.4); registration rounds use the
            median either way.
        graphcut: options of the graph-cut merge.
    """

    size: int = 1024
    sample_size: int | None = None
    texels_per_pixel: float = 1.25
    top_k: int = 9
    min_cos: float = 0.4
    depth_tolerance: float = 0.01
    mask_margin: int = 2
    edge_margin: int = 2
    edge_depth: float = 0.03
    shading_floor: float = 0.05
    fill: bool = True
    dilation: int = 8
    register_rounds: int = 1
    max_flow: float = 8.0
    workers: int = 2
    mirror_radius: float = 0.01
    method: str = "median"
    graphcut: GraphCutSettings = field(default_factory=GraphCutSettings)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise TextureError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.size < 2:
            raise TextureError(f"size must be at least 2, got {self.size}")
        if self.sample_size is not None and self.sample_size < 2:
            raise TextureError(f"sample_size must be at least 2, got {self.sample_size}")
        if not self.texels_per_pixel > 0:
            raise TextureError(f"texels_per_pixel must be positive, got {self.texels_per_pixel}")
        if self.top_k < 1:
            raise TextureError(f"top_k must be at least 1, got {self.top_k}")
        if not -1.0 <= self.min_cos < 1.0:
            raise TextureError(f"min_cos must lie in [-1, 1), got {self.min_cos}")
        for name in ("depth_tolerance", "edge_depth", "shading_floor"):
            if not getattr(self, name) > 0:
                raise TextureError(f"{name} must be positive, got {getattr(self, name)}")
        if not self.max_flow > 0:
            raise TextureError(f"max_flow must be positive, got {self.max_flow}")
        for name in ("mask_margin", "edge_margin", "dilation", "register_rounds"):
            if getattr(self, name) < 0:
                raise TextureError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.workers < 1:
            raise TextureError(f"workers must be at least 1, got {self.workers}")


@dataclass(frozen=True)
class UVTexture:
    """A texture built from views (glTF UV layout, S x S texels).

    Attributes:
        image: (S, S, 3) uint8 texture: albedo when shading was divided out (``albedo``),
            else the observed (shaded) colour. Linear values, like the frames.
        coverage: (S, S) bool, texels seen in at least one view.
        chart: (S, S) bool, texels inside the UV charts (the rest is dilation / padding).
        views: (S, S) int16 number of views whose median gave the texel (0 = filled).
        best_cos: (S, S) float32 cosine of the most orthogonal view (0 where unseen).
        albedo: whether the SH shading was divided out.
        sample_size: side of the grid the views were sampled on; the image was resized from it
            bilinearly, and the four maps above by nearest texel.
    """

    image: np.ndarray
    coverage: np.ndarray
    chart: np.ndarray
    views: np.ndarray
    best_cos: np.ndarray
    albedo: bool
    sample_size: int

    @property
    def size(self) -> int:
        return int(self.image.shape[0])

    def as_float(self) -> np.ndarray:
        """(S, S, 3) float32 in [0, 1], as :func:`monoavatar.render.render_textured` expects."""
        return self.image.astype(np.float32) / 255.0


# -- inputs -----------------------------------------------------------------------------------


def _cameras(camera: PinholeCamera | Sequence[PinholeCamera], n: int) -> list[PinholeCamera]:
    if isinstance(camera, PinholeCamera):
        return [camera] * n
    cams = list(camera)
    if len(cams) != n or not all(isinstance(c, PinholeCamera) for c in cams):
        raise TextureError(f"camera must be a PinholeCamera or {n} of them, got {len(cams)}")
    return cams


def _lighting(sh: Tensor | np.ndarray | None, n: int) -> np.ndarray | None:
    if sh is None:
        return None
    s = as_array(sh, np.float64, "sh")
    if s.shape == (3, 9):
        s = np.broadcast_to(s, (n, 3, 9))
    if s.shape != (n, 3, 9):
        raise TextureError(f"sh must have shape (3, 9) or ({n}, 3, 9), got {s.shape}")
    return s


def _check_frames(
    vertices: np.ndarray, images: np.ndarray, masks: np.ndarray, cams: list[PinholeCamera]
) -> None:
    n = vertices.shape[0]
    if images.ndim != 4 or images.shape[0] != n or images.shape[3] != 3:
        raise TextureError(f"images must have shape ({n}, H, W, 3), got {images.shape}")
    if images.dtype != np.uint8:
        raise TextureError(f"images must be uint8, got {images.dtype}")
    if masks.shape != images.shape[:3]:
        raise TextureError(f"masks must have shape {images.shape[:3]}, got {masks.shape}")
    if masks.dtype != np.bool_:
        raise TextureError(f"masks must be boolean, got {masks.dtype}")
    for i, cam in enumerate(cams):
        if (cam.height, cam.width) != images.shape[1:3]:
            raise TextureError(
                f"frame {i}: camera is {cam.width}x{cam.height} but the image is "
                f"{images.shape[2]}x{images.shape[1]}"
            )


# -- one view ---------------------------------------------------------------------------------


def _occlusion_edges(depth: np.ndarray, focal: float, settings: TextureSettings) -> np.ndarray:
    """(H, W) bool: pixels next to a depth jump between two surfaces (not the background).

    A jump between 4-neighbours counts when it exceeds both ``edge_depth`` and what a surface
    inclined at ``acos(min_cos)`` to the view would show across one pixel.
    """
    surface = np.isfinite(depth)
    d = np.where(surface, depth, 0.0)
    min_cos = min(max(settings.min_cos, 0.05), 0.99)
    slope = np.sqrt(1.0 - min_cos**2) / min_cos  # tan of the most oblique accepted view
    edges = np.zeros(depth.shape, bool)
    for axis in (0, 1):
        a = [slice(None)] * 2
        b = [slice(None)] * 2
        a[axis], b[axis] = slice(1, None), slice(None, -1)
        both = surface[tuple(a)] & surface[tuple(b)]
        jump = np.abs(d[tuple(a)] - d[tuple(b)])
        limit = np.maximum(
            settings.edge_depth, slope * np.minimum(d[tuple(a)], d[tuple(b)]) / focal
        )
        hit = both & (jump > limit)
        edges[tuple(a)] |= hit
        edges[tuple(b)] |= hit
    return edges


def _boundary_distance(
    mask: np.ndarray, depth: np.ndarray, focal: float, settings: TextureSettings
) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float32 distances in pixels from each pixel to the nearest pixel outside the
    person mask, and to the nearest occlusion boundary of the rendered mesh."""
    import cv2

    inside = np.pad(mask.astype(np.uint8), 1)  # the image border counts as outside
    d_mask = cv2.distanceTransform(inside, cv2.DIST_L2, 3)[1:-1, 1:-1]
    edges = _occlusion_edges(depth, focal, settings)
    if edges.any():
        d_edge = cv2.distanceTransform((~edges).astype(np.uint8), cv2.DIST_L2, 3)
    else:
        d_edge = np.full(mask.shape, np.inf, np.float32)
    return d_mask, d_edge


def _bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(N, C) float32 bilinear samples of an (H, W, C) float32 image at pixel coordinates
    (x, y) (pixel centres at +0.5; the border is repeated)."""
    import cv2

    n = x.size
    if n == 0:
        return np.zeros((0, image.shape[2]), np.float32)
    width = 4096  # cv2.remap wants maps narrower than 32767
    rows = -(-n // width)
    mx = np.zeros(rows * width, np.float32)
    my = np.zeros(rows * width, np.float32)
    mx[:n] = x - 0.5
    my[:n] = y - 0.5
    out = cv2.remap(image, mx.reshape(rows, width), my.reshape(rows, width), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)  # fmt: skip
    return np.asarray(out.reshape(rows * width, -1)[:n], dtype=np.float32)


@dataclass(frozen=True)
class _Views:
    """What one frame contributes: texel positions (M,), cosines (M,), colours (M, 3)."""

    texel: np.ndarray
    cos: np.ndarray
    colour: np.ndarray


def _view_samples(
    atlas: TexelAtlas,
    corners: np.ndarray,
    faces: np.ndarray,
    vertices: np.ndarray,
    image: np.ndarray,
    mask: np.ndarray,
    camera: PinholeCamera,
    sh: np.ndarray | None,
    settings: TextureSettings,
    flow: np.ndarray | None = None,
    frags: Fragments | None = None,
) -> _Views:
    """Back-project one frame onto the chart texels (see the module docstring).

    ``corners`` (N, 3) are the vertex indices of each chart texel's face. Projected positions,
    depths, cosines and shading are computed at the vertices and interpolated linearly to the
    texels (exact up to the perspective division within one triangle, a sub-texel effect for
    triangles a few pixels wide). With ``flow`` (H, W, 2), pixels, a texel projected to p is
    sampled at p + flow(p) (visibility is still decided at p, by the render); it must then
    also lie inside the mask by ``mask_margin``. ``frags``: the rasterisation of ``vertices``
    by ``camera``, when the caller has it already.
    """
    if frags is None:
        frags = rasterize(vertices, faces, camera)
    face_id = frags.face_id.numpy().ravel()
    depth = frags.depth.numpy()
    focal = float(np.sqrt(camera.K[0, 0] * camera.K[1, 1]))
    d_mask, d_edge = _boundary_distance(mask, depth, focal, settings)
    reliable = ((d_mask > settings.mask_margin) & (d_edge > settings.edge_margin)).ravel()
    depth = depth.ravel()
    H, W = camera.height, camera.width

    normals = vertex_normals(torch.tensor(vertices), torch.tensor(faces))
    n_np = normals.numpy()
    cam = vertices @ camera.R.T + camera.t
    z = cam[:, 2]
    to_cam = camera.center - vertices
    cos = np.einsum("vc,vc->v", n_np, to_cam) / np.maximum(np.linalg.norm(to_cam, axis=1), 1e-12)
    zs = np.where(z > 1e-3, z, 1e-3)
    pix = cam @ camera.K.T
    channels = [pix[:, 0] / zs, pix[:, 1] / zs, z, cos]
    if sh is not None:
        shading = sh_shading(normals, torch.tensor(sh, dtype=normals.dtype)).numpy()
        channels += list(np.maximum(shading, settings.shading_floor).T)
    per_vertex = np.stack(channels, axis=1).astype(np.float32)
    # faces that can contribute: in front of the camera, some corner seen obliquely enough
    usable = (cos[faces].max(axis=1) > settings.min_cos) & (z[faces].min(axis=1) > 1e-3)
    cand = np.flatnonzero(usable[atlas.face])
    vals = np.einsum("nk,nkc->nc", atlas.bary[cand], per_vertex[corners[cand]])
    x, y, zt, ct = vals[:, 0], vals[:, 1], vals[:, 2], vals[:, 3]
    col = np.floor(x).astype(np.int64)
    row = np.floor(y).astype(np.int64)
    keep = (ct > settings.min_cos) & (col >= 0) & (col < W) & (row >= 0) & (row < H)
    idx = np.flatnonzero(keep)
    p = row[idx] * W + col[idx]
    own = face_id[p] == atlas.face[cand[idx]]
    near = np.abs(depth[p] - zt[idx]) <= settings.depth_tolerance
    idx = idx[(own | near) & reliable[p]]
    sx, sy = x[idx], y[idx]
    if flow is not None:
        shift = _bilinear(flow, sx, sy)
        sx, sy = sx + shift[:, 0], sy + shift[:, 1]
        inside = _bilinear(d_mask[..., None], sx, sy)[:, 0] > settings.mask_margin
        idx, sx, sy = idx[inside], sx[inside], sy[inside]
    colour = _bilinear(image.astype(np.float32) * np.float32(1.0 / 255.0), sx, sy)
    if sh is not None:
        colour /= vals[idx, 4:7]
    return _Views(texel=cand[idx], cos=ct[idx], colour=colour)


# -- the most orthogonal views ----------------------------------------------------------------


class _TopK:
    """Per texel, the ``k`` views with the largest cosine seen so far (streaming)."""

    def __init__(self, num_texels: int, k: int) -> None:
        self.cos = np.full((k, num_texels), -np.inf, dtype=np.float32)
        self.colour = np.zeros((k, num_texels, 3), dtype=np.float32)

    def add(self, views: _Views) -> None:
        t = views.texel
        if t.size == 0:
            return
        slot = np.argmin(self.cos[:, t], axis=0)
        better = views.cos > self.cos[slot, t]
        t, slot = t[better], slot[better]
        self.cos[slot, t] = views.cos[better]
        self.colour[slot, t] = views.colour[better]

    def median(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-channel median over the filled slots: (N, 3) colours (0 where none) and (N,)
        counts."""
        valid = np.isfinite(self.cos)  # (k, N)
        count = valid.sum(axis=0)
        vals = np.where(valid[..., None], self.colour, np.inf)
        vals.sort(axis=0)  # the filled slots first, ascending per channel
        lo = np.clip((count - 1) // 2, 0, None)
        hi = np.clip(count // 2, 0, None)
        cols = np.arange(vals.shape[1])
        med = 0.5 * (vals[lo, cols] + vals[hi, cols])
        med[count == 0] = 0.0
        return med, count


# -- public -----------------------------------------------------------------------------------


def sampling_size(
    vertices: np.ndarray,
    faces: np.ndarray,
    uv: np.ndarray,
    face_uv: np.ndarray,
    cameras: Sequence[PinholeCamera],
    settings: TextureSettings,
) -> int:
    """The texture grid to sample views on: ``settings.sample_size`` if set, else the side at
    which one texel spans ``1 / texels_per_pixel`` of the surface a frame pixel covers (at the
    median depth of the mesh, facing the camera), clipped to [64, ``settings.size``].

    Args:
        vertices: (F, V, 3) posed meshes; faces, uv, face_uv: the mesh and its UV layout;
        cameras: one per frame.
    """
    if settings.sample_size is not None:
        return min(settings.sample_size, settings.size)
    tri = vertices[0][faces]
    area3 = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    tuv = uv[face_uv]
    d1, d2 = tuv[:, 1] - tuv[:, 0], tuv[:, 2] - tuv[:, 0]
    area_uv = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    ok = area_uv > 0
    if not ok.any():
        return settings.size
    # metres per unit of UV, the median over the texture's area
    scale = np.sqrt(area3[ok] / area_uv[ok])
    order = np.argsort(scale)
    cum = np.cumsum(area_uv[ok][order])
    metres_per_uv = float(scale[order][np.searchsorted(cum, 0.5 * cum[-1])])
    pixel = []
    for v, cam in zip(vertices, cameras, strict=True):
        z = v @ cam.R[2] + cam.t[2]
        z = z[z > 0]
        if z.size:
            pixel.append(float(np.median(z)) / float(np.sqrt(cam.K[0, 0] * cam.K[1, 1])))
    if not pixel:
        return settings.size
    side = settings.texels_per_pixel * metres_per_uv / float(np.median(pixel))
    return int(np.clip(np.ceil(side), 64, settings.size))


def build_texture(
    vertices: Tensor | np.ndarray,
    faces: Tensor | np.ndarray,
    uv: Tensor | np.ndarray,
    face_uv: Tensor | np.ndarray,
    images: np.ndarray,
    masks: np.ndarray,
    camera: PinholeCamera | Sequence[PinholeCamera],
    sh: Tensor | np.ndarray | None = None,
    settings: TextureSettings | None = None,
    progress: bool = False,
    mirror_vertices: Tensor | np.ndarray | None = None,
    front_back: np.ndarray | None = None,
) -> UVTexture:
    """Build a texture from key frames: median of the most orthogonal views, seams filled.

    Args:
        vertices: (F, V, 3) the avatar posed into each key frame, world coordinates, metres.
        faces: (Fc, 3) vertex indices.
        uv: (T, 2) texture coordinates (glTF convention); face_uv: (Fc, 3) indices into uv.
        images: (F, H, W, 3) uint8 key frames (linear colour).
        masks: (F, H, W) bool person masks.
        camera: the camera of all frames, or one per frame.
        sh: SH lighting (world frame) to divide out, (3, 9) for all frames or (F, 3, 9);
            None keeps the observed colours (the texture then has the lighting baked in).
            :func:`monoavatar.texture.lighting.estimate_sh` estimates it.
        settings: :class:`TextureSettings`; defaults used when None.
        progress: show a progress bar over the frames.
        mirror_vertices: (V, 3) the avatar's canonical vertices (left–right symmetric about
            x = 0): with them, texels never seen take the colour of the seen texel nearest
            their mirror image (x → −x) when one lies within ``settings.mirror_radius``
            metres, before the harmonic fill (a single photo sees one side of a turned body).
        front_back: (V,) bool, with ``mirror_vertices``: the vertices whose texels still unseen
            after that then take the colour of their front–back mirror image (z → −z) — a
            garment's back is most like its front; leave the face out.
    Returns:
        :class:`UVTexture` of ``settings.size`` texels.
    Raises:
        TextureError: inconsistent shapes, dtypes or sizes.
    """
    settings = settings or TextureSettings()
    verts = as_array(vertices, np.float64, "vertices")
    if verts.ndim != 3 or verts.shape[2] != 3 or verts.shape[0] < 1:
        raise TextureError(f"vertices must have shape (F, V, 3) with F >= 1, got {verts.shape}")
    if not np.isfinite(verts).all():
        raise TextureError("vertices contain NaN or inf")
    f, t, fu = check_mesh_uv(faces, uv, face_uv, verts.shape[1])
    imgs = np.asarray(images)
    msks = np.asarray(masks)
    n_frames = verts.shape[0]
    cams = _cameras(camera, n_frames)
    _check_frames(verts, imgs, msks, cams)
    lighting = _lighting(sh, n_frames)
    work = sampling_size(verts, f, t, fu, cams, settings)
    atlas = build_atlas(t, fu, work)

    corners = f[atlas.face].astype(np.int32)
    graph = None
    image = np.zeros((work, work, 3), np.float32)  # the texture so far; round 0 fills it

    # each frame's visible faces, (pixel, face) int32, kept from round 0 for the registration
    # rounds (same vertices: only the barycentrics and depths are computed again)
    seen_faces: list[tuple[np.ndarray, np.ndarray] | None] = [None] * n_frames

    def frame_views(i: int, so_far: Tensor | None) -> tuple[_Views, float]:
        """Frame i's samples, registered by the flow from ``so_far`` rendered (step 6), and
        the frame's silhouette error ``1 − IoU`` (rendered mesh vs person mask)."""
        sh_i = None if lighting is None else lighting[i]
        kept = seen_faces[i]
        if kept is None:
            frags = rasterize(verts[i], f, cams[i])
            if settings.register_rounds > 0:
                ids = frags.face_id.numpy().ravel()
                pixel = np.flatnonzero(ids >= 0).astype(np.int32)
                seen_faces[i] = (pixel, ids[pixel].astype(np.int32))
        else:
            face_id = np.full(cams[i].height * cams[i].width, -1, np.int64)
            face_id[kept[0]] = kept[1]
            frags = fragments_from_face_ids(verts[i], f, cams[i],
                                            face_id.reshape(cams[i].height, cams[i].width))
        flow = None
        if so_far is not None:  # step 6: where the texture so far lies in this frame
            render = render_over_image(verts[i], f, frags, t, fu, so_far, imgs[i], sh=sh_i)
            flow = DISFlow("medium").estimate_near(render, imgs[i], frags.face_id.numpy() >= 0)
            flow[np.linalg.norm(flow, axis=2) > settings.max_flow] = 0.0
        views = _view_samples(atlas, corners, f, verts[i], imgs[i], msks[i], cams[i], sh_i,
                              settings, flow, frags)  # fmt: skip
        drawn = frags.face_id.numpy() >= 0
        union = int((drawn | msks[i]).sum())
        return views, 1.0 - int((drawn & msks[i]).sum()) / max(union, 1)

    for r in range(settings.register_rounds + 1):
        top = _TopK(atlas.num_texels, settings.top_k)
        so_far = None if r == 0 else torch.as_tensor(image, dtype=torch.float64)
        label = "texture" if r == 0 else f"texture: registration {r}"
        dense = settings.method == "graphcut" and r == settings.register_rounds
        if dense:  # every view of every texel, for the graph cut
            cos_all = np.zeros((n_frames, atlas.num_texels), np.float32)
            colour_all = np.zeros((n_frames, atlas.num_texels, 3), np.float16)
            silhouette = np.zeros(n_frames)
        # the frames are sampled side by side (``workers`` threads) and added in frame order
        with frame_pool(settings.workers) as pool:
            views_of = pool.map(partial(frame_views, so_far=so_far), range(n_frames))
            for i, (views, err) in enumerate(tqdm(views_of, total=n_frames, desc=label,
                                                  unit="frame", disable=not progress)):  # fmt: skip
                top.add(views)
                if dense:
                    cos_all[i, views.texel] = np.maximum(views.cos, 1e-6)
                    colour_all[i, views.texel] = views.colour
                    silhouette[i] = err
        colour, count = top.median()
        seen = count > 0
        if dense:
            if graph is None:
                graph = texel_graph(atlas, f, t, fu, verts[0])
            merged, _ = merge_views(colour_all, cos_all, silhouette, graph, settings.graphcut)
            colour = np.where(seen[:, None], merged, colour)
            del cos_all, colour_all
        if mirror_vertices is not None and seen.any() and not seen.all():
            canonical = as_array(mirror_vertices, np.float64, "mirror_vertices")
            points = atlas.points(canonical, f)
            colour, seen = _mirror(points, colour, seen, settings.mirror_radius)
            if front_back is not None:
                allowed = np.asarray(front_back, bool)[f[atlas.face]].all(axis=1)
                colour, seen = _mirror(points, colour, seen, settings.mirror_radius,
                                       axis=2, allowed=allowed)  # fmt: skip
        if settings.fill and seen.any() and not seen.all():
            if graph is None:
                graph = texel_graph(atlas, f, t, fu, verts[0])
            colour = harmonic_fill(graph, colour, seen)
        valid = np.zeros(work * work, bool)
        valid[atlas.texels] = seen | settings.fill
        image = dilate_texture(
            _scatter(atlas, colour, np.float32), valid.reshape(work, work), settings.dilation
        )
    best = np.where(count > 0, top.cos.max(axis=0), 0.0).astype(np.float32)
    if not settings.fill:  # unseen chart texels stay black
        image[atlas.chart & ~_scatter(atlas, seen, np.bool_)] = 0.0
    maps = {
        "coverage": _scatter(atlas, count > 0, np.bool_),
        "chart": atlas.chart,
        "views": _scatter(atlas, count, np.int16),
        "best_cos": _scatter(atlas, best, np.float32),
    }
    if work != settings.size:
        image, maps = _resize(image, maps, settings.size)
    return UVTexture(
        image=(np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8),
        coverage=maps["coverage"],
        chart=maps["chart"],
        views=maps["views"],
        best_cos=maps["best_cos"],
        albedo=lighting is not None,
        sample_size=work,
    )


def _mirror(points: np.ndarray, colour: np.ndarray, seen: np.ndarray, radius: float,
            axis: int = 0, allowed: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Unseen texels (``seen`` False; and ``allowed``, (N,) bool, when given) whose mirror
    image through the plane ``points[:, axis] = 0`` of their canonical point (N, 3) lies within
    ``radius`` metres of a seen texel take that texel's colour (N, 3); returns the colours
    and the texels now known. (With ``axis=2`` the nearest seen texel is searched in the
    plane x, y only, as a body's back and front are not at mirrored depths.)"""
    from scipy.spatial import cKDTree

    known = np.flatnonzero(seen)
    unknown = np.flatnonzero(~seen if allowed is None else ~seen & allowed)
    flip = np.ones(3)
    flip[axis] = -1.0
    if axis == 2:  # front ↔ back: match on (x, y) among texels on the other side
        side = points[:, 2] >= 0
        out, now = colour.copy(), seen.copy()
        for front in (True, False):
            src = known[side[known] == front]
            dst = unknown[side[unknown] != front]
            if len(src) == 0 or len(dst) == 0:
                continue
            dist, nearest = cKDTree(points[src, :2]).query(points[dst, :2],
                                                           distance_upper_bound=radius)
            hit = np.isfinite(dist)
            out[dst[hit]] = colour[src[nearest[hit]]]
            now[dst[hit]] = True
        return out, now
    mirrored = points[unknown] * flip
    dist, nearest = cKDTree(points[known]).query(mirrored, distance_upper_bound=radius)
    hit = np.isfinite(dist)
    out = colour.copy()
    out[unknown[hit]] = colour[known[nearest[hit]]]
    now = seen.copy()
    now[unknown[hit]] = True
    return out, now


def _scatter(atlas: TexelAtlas, values: np.ndarray, dtype: type) -> np.ndarray:
    """Per-chart-texel values (N, ...) → an (S, S, ...) image, zeros elsewhere."""
    S = atlas.size
    out: np.ndarray = np.zeros((S * S, *values.shape[1:]), dtype=dtype)
    out[atlas.texels] = values
    return out.reshape(S, S, *values.shape[1:])


def _resize(
    image: np.ndarray, maps: dict[str, np.ndarray], size: int
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Resize the (dilated) texture bilinearly and the per-texel maps by nearest texel."""
    import cv2

    # cv2.resize with INTER_LINEAR uses the same texel-centre convention as the UVs
    out = np.asarray(cv2.resize(image, (size, size), interpolation=cv2.INTER_LINEAR))
    src = image.shape[0]
    idx = np.minimum(((np.arange(size) + 0.5) * src / size).astype(np.int64), src - 1)
    return out, {k: v[idx][:, idx] for k, v in maps.items()}
