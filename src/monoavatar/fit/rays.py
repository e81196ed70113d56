"""Silhouette rays and their unposing into the canonical frame (Sec. B.3.3, Eq. B.6, Fig. B.3).

Per frame: sample the observed mask's boundary with sub-pixel positions and outward normals
(:func:`silhouette_boundary`), find the posed model's contour vertices
(:func:`contour_candidates`), match each boundary sample to the contour vertex nearest in image
position and normal direction (:func:`match_boundary`), and map each sample's camera ray into
the canonical pose with the inverse blended transform of its vertex (:func:`unpose_lines`).
:func:`silhouette_correspondences` runs this over all frames, a few at a time, so that memory
does not grow with the number of frames beyond the canonical lines themselves.

Pixel coordinates: x right, y down, origin at the top-left pixel's corner (pixel centres at
+0.5). Everything returned is NumPy float64; lines are Plücker pairs (moment m = o × n, unit
direction n, Eq. 3.11), canonical frame, metres.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields

import cv2
import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from monoavatar.body import BodyModel
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.geometry import vertex_normals
from monoavatar.core.threads import frame_pool


@dataclass(frozen=True)
class BoundarySamples:
    """Samples of an observed silhouette's boundary.

    Attributes:
        points: (P, 2) sub-pixel positions (x, y) on the mask's edge, pixels.
        normals: (P, 2) unit outward normals in the image.
    """

    points: np.ndarray
    normals: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])


@dataclass(frozen=True)
class CanonicalRays:
    """Silhouette rays matched to model vertices and unposed to the canonical frame.

    Attributes:
        vertex_ids: (N,) int64 the model vertex each ray touches.
        moment: (N, 3) Plücker moments ``m = o × n`` of the canonical lines, metres.
        direction: (N, 3) unit directions ``n`` of the canonical lines.
        plane_normal: (N, 3) unit normal of the canonical silhouette plane: the plane through
            the line that contains the silhouette's tangent, oriented away from the person
            (the ray's only direction the silhouette really constrains).
        frame: (N,) int64 index (into the frames given) of the frame each ray comes from.
        image_distance: (N,) distance in pixels between the boundary sample and its vertex's
            projection when matched (diagnostics).
    """

    vertex_ids: np.ndarray
    moment: np.ndarray
    direction: np.ndarray
    plane_normal: np.ndarray
    frame: np.ndarray
    image_distance: np.ndarray

    def __len__(self) -> int:
        return int(self.vertex_ids.shape[0])

    def closest_points(self) -> np.ndarray:
        """(N, 3) the point of each line nearest to the origin, ``n × m``."""
        return np.cross(self.direction, self.moment)

    def distances(self, vertices: np.ndarray) -> np.ndarray:
        """(N,) distance of each ray's vertex, taken from ``vertices`` (V, 3), to its line
        (Eq. B.8, ``|v × n − m|``)."""
        v = vertices[self.vertex_ids]
        return np.asarray(np.linalg.norm(np.cross(v, self.direction) - self.moment, axis=1))

    def plane_distances(self, vertices: np.ndarray) -> np.ndarray:
        """(N,) signed distance of each ray's vertex to its silhouette plane (positive
        outside the observed silhouette)."""
        v = vertices[self.vertex_ids] - self.closest_points()
        return np.asarray(np.einsum("nc,nc->n", v, self.plane_normal))

    @classmethod
    def empty(cls) -> CanonicalRays:
        """No rays."""
        z3 = np.zeros((0, 3))
        return cls(np.zeros(0, np.int64), z3, z3, z3, np.zeros(0, np.int64), np.zeros(0))

    @classmethod
    def concatenate(cls, parts: Sequence[CanonicalRays]) -> CanonicalRays:
        """The rays of all ``parts``, in order."""
        if not parts:
            return cls.empty()
        names = [f.name for f in fields(cls)]
        return cls(*(np.concatenate([getattr(p, n) for p in parts]) for n in names))

    def select(self, keep: np.ndarray) -> CanonicalRays:
        """The subset of rays given by a boolean mask or index array."""
        return CanonicalRays(
            self.vertex_ids[keep],
            self.moment[keep],
            self.direction[keep],
            self.plane_normal[keep],
            self.frame[keep],
            self.image_distance[keep],
        )


def silhouette_boundary(mask: np.ndarray, count: int, blur: float = 1.5) -> BoundarySamples:
    """Up to ``count`` samples spread evenly along all boundaries of a mask (outer contours and
    holes, e.g. the gap between an arm and the torso). Boundary pixels on the image border are
    left out: there the person is cut off, not outlined.

    Each boundary pixel is moved along its outward normal to where the mask, blurred with a
    Gaussian of ``blur`` pixels, crosses 0.5: the sub-pixel edge (a binary mask's boundary
    pixel lies half a pixel inside the edge on average, which is millimetres on the body).

    Args:
        mask: (H, W) bool person mask.
        count: maximum number of samples.
        blur: Gaussian sigma in pixels for the normals and the sub-pixel step.
    """
    if mask.ndim != 2:
        raise ValueError(f"mask must have shape (H, W), got {mask.shape}")
    m = mask.astype(np.uint8)
    contours, _ = cv2.findContours(m, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    empty = BoundarySamples(np.zeros((0, 2)), np.zeros((0, 2)))
    if not contours or count <= 0:
        return empty
    pixels = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(np.int64)
    h, w = mask.shape
    inner = (
        (pixels[:, 0] > 0) & (pixels[:, 0] < w - 1) & (pixels[:, 1] > 0) & (pixels[:, 1] < h - 1)
    )
    pixels = pixels[inner]
    if len(pixels) == 0:
        return empty
    if len(pixels) > count:
        pixels = pixels[np.linspace(0, len(pixels) - 1, count).round().astype(np.int64)]
    smooth = cv2.GaussianBlur(m.astype(np.float32), (0, 0), blur)
    gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    col, row = pixels[:, 0], pixels[:, 1]
    grad = np.stack([gx[row, col], gy[row, col]], axis=1).astype(np.float64)
    norm = np.linalg.norm(grad, axis=1)
    keep = norm > 1e-3
    if not keep.any():
        return empty
    normals = -grad[keep] / norm[keep, None]
    step = (smooth[row, col][keep].astype(np.float64) - 0.5) / norm[keep]
    points = pixels[keep] + 0.5 + np.clip(step, -1.0, 1.5)[:, None] * normals
    return BoundarySamples(points, normals)


def contour_candidates(
    vertices: np.ndarray, normals: np.ndarray, camera: PinholeCamera, max_cos: float = 0.3
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices near the contour generator of a posed mesh: those whose normal is nearly
    perpendicular to the line of sight, ``|n · (v − c)| / |v − c| < max_cos``.

    Args:
        vertices: (V, 3) posed vertices, world metres; normals: (V, 3) unit.
        camera: the camera (centre c).
    Returns:
        ids (K,), their projections (K, 2) in pixels, and their unit normals projected into
        the image (K, 2).
    """
    K, R, t = camera.K, camera.R, camera.t
    view = vertices - camera.center
    cos = np.einsum("vc,vc->v", normals, view) / np.linalg.norm(view, axis=1)
    cam = vertices @ R.T + t
    z = cam[:, 2]
    ids = np.flatnonzero((np.abs(cos) < max_cos) & (z > 1e-6))
    cam, z = cam[ids], z[ids]
    kc = cam @ K.T
    pixels = kc[:, :2] / z[:, None]
    dn = normals[ids] @ R.T  # normals in camera axes
    dpix = (dn @ K.T)[:, :2] / z[:, None] - pixels * (dn[:, 2] / z)[:, None]
    length = np.linalg.norm(dpix, axis=1)
    ok = length > 1e-12
    return ids[ok], pixels[ok], dpix[ok] / length[ok, None]


def match_boundary(
    samples: BoundarySamples,
    pixels: np.ndarray,
    directions: np.ndarray,
    max_distance: float,
    normal_weight: float = 8.0,
    min_dot: float = 0.5,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Match boundary samples to contour candidates: nearest in (x, y, λ n_x, λ n_y).

    Args:
        samples: observed boundary samples.
        pixels, directions: (K, 2) candidate projections and projected unit normals.
        max_distance: pixels; samples with no candidate this close are left unmatched.
        normal_weight: λ, pixels per unit of normal difference.
        min_dot: minimum cosine between the sample's and the candidate's normals.
    Returns:
        sample indices (M,), candidate indices (M,), image distances (M,) in pixels.
    """
    none = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if len(samples) == 0 or len(pixels) == 0:
        return none
    tree = cKDTree(np.hstack([pixels, normal_weight * directions]))
    query = np.hstack([samples.points, normal_weight * samples.normals])
    bound = np.hypot(max_distance, normal_weight * np.sqrt(2.0 * (1.0 - min_dot)))
    _, idx = tree.query(query, distance_upper_bound=bound)
    found = np.flatnonzero(idx < len(pixels))
    cand = idx[found]
    dist = np.linalg.norm(samples.points[found] - pixels[cand], axis=1)
    dots = np.einsum("nc,nc->n", samples.normals[found], directions[cand])
    ok = (dist <= max_distance) & (dots >= min_dot)
    return found[ok].astype(np.int64), cand[ok].astype(np.int64), dist[ok]


def unpose_lines(
    body: BodyModel,
    origin: np.ndarray,
    directions: np.ndarray,
    plane_normals: np.ndarray,
    vertex_ids: np.ndarray,
    transforms: Tensor | np.ndarray,
    correctives: Tensor | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map posed rays, and planes through them, into the canonical pose by the inverse blended
    transform of the vertex each ray touches, minus its pose corrective (Eq. B.6), in float64.

    Args:
        origin: (3,) or (N, 3) ray origins, world metres; directions: (N, 3).
        plane_normals: (N, 3) normals of planes through the rays, world.
        vertex_ids: (N,) vertices; transforms: (J, 4, 4) rest → posed transforms of the frame;
        correctives: (V, 3) pose-dependent offsets of the frame, or None.
    Returns:
        Plücker moments (N, 3) and unit directions (N, 3) of the canonical lines, and the
        canonical unit plane normals (N, 3) (``Lᵀ n``, L the blended linear part).
    """
    tf = np.asarray(torch.as_tensor(transforms).detach().cpu().double().numpy())
    ids = torch.as_tensor(vertex_ids, dtype=torch.long)
    weights = body.skin_weights[ids].detach().cpu().double().numpy()
    blended = (weights @ tf[:, :3, :].reshape(len(tf), 12)).reshape(-1, 3, 4)
    linear, shift = blended[..., :3], blended[..., 3]
    inverse = np.linalg.inv(linear)
    o_c = np.einsum("nij,nj->ni", inverse, origin - shift)
    if correctives is not None:
        o_c = o_c - correctives[ids].detach().cpu().double().numpy()
    d_c = np.einsum("nij,nj->ni", inverse, directions)
    d_c /= np.linalg.norm(d_c, axis=1, keepdims=True)
    p_c = np.einsum("nji,nj->ni", linear, plane_normals)
    p_c /= np.linalg.norm(p_c, axis=1, keepdims=True)
    return np.cross(o_c, d_c), d_c, p_c


def frame_shift(
    points: np.ndarray,
    plane_normals: np.ndarray,
    centre: np.ndarray,
    axes: np.ndarray,
    sigma: float,
    iterations: int = 3,
) -> np.ndarray:
    """The world translation Δt (3,) within the span of ``axes`` (2, 3) (the camera's image
    axes: a shift along the line of sight would trade off against the body's size) that best
    moves posed contour points onto their silhouette planes (planes through the camera
    centre ``c``): robust (Geman-McClure, scale ``sigma`` metres) least squares of
    ``n · (x + Δt − c)``."""
    r0 = np.einsum("nc,nc->n", plane_normals, points - centre)
    g = plane_normals @ axes.T  # (N, 2)
    coef = np.zeros(2)
    for _ in range(iterations):
        r = r0 + g @ coef
        w = (sigma * sigma / (sigma * sigma + r * r)) ** 2
        A = (g * w[:, None]).T @ g
        if np.linalg.cond(A) > 1e8:
            break
        coef = np.linalg.solve(A, -(g * w[:, None]).T @ r0)
    return np.asarray(coef @ axes)


def pixel_directions(camera: PinholeCamera, k_inv: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2) pixels → (N, 3) unit world directions of their camera rays (``k_inv`` = K⁻¹)."""
    homo = np.hstack([points, np.ones((len(points), 1))])
    d = homo @ k_inv.T @ camera.R  # Rᵀ d_cam for row vectors
    return np.asarray(d / np.linalg.norm(d, axis=1, keepdims=True))


def _silhouette_planes(camera: PinholeCamera, points: np.ndarray, normals: np.ndarray):
    """World unit normals (N, 3) of the planes through the camera centre that contain the
    image lines through ``points`` perpendicular to ``normals`` (outward oriented)."""
    lines = np.hstack([normals, -np.einsum("nc,nc->n", normals, points)[:, None]])
    n = lines @ camera.K @ camera.R  # Rᵀ Kᵀ l for row vectors
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def silhouette_correspondences(
    body: BodyModel,
    canonical: Tensor,
    transforms: Tensor,
    samples: Sequence[BoundarySamples],
    camera: PinholeCamera,
    *,
    rotations: Tensor | None = None,
    max_distance: float | np.ndarray = 20.0,
    max_cos: float = 0.3,
    normal_weight: float = 8.0,
    min_dot: float = 0.5,
    shift_sigma: float | None = None,
    chunk: int = 8,
    workers: int = 1,
) -> tuple[CanonicalRays, np.ndarray]:
    """Pose a canonical mesh into every frame, match the observed boundary samples to its
    contour vertices and unpose the matched rays (the correspondence step of Sec. B.3.3).

    With ``shift_sigma``, each frame's pose is first corrected by the world translation that
    best aligns its matched contour with the silhouette (:func:`frame_shift`), and the rays are
    unposed with the corrected pose: this absorbs translation errors of the given poses (or a
    root joint that sits elsewhere than in the skeleton the poses were estimated for).

    Args:
        body: the body model (skinning weights, faces, pose correctives).
        canonical: (V, 3) canonical vertices (shape + offsets), metres.
        transforms: (F, J, 4, 4) rest → posed joint transforms of the F frames.
        samples: F boundary samples, one per frame.
        camera: the camera of all frames.
        rotations: (F, J, 3, 3) joint rotations, only for models with pose correctives.
        max_distance: matching radius in pixels, scalar or (F,).
        max_cos, normal_weight, min_dot: see :func:`contour_candidates`, :func:`match_boundary`.
        shift_sigma: robust scale (metres) of the per-frame translation correction, or
            None for no correction.
        chunk: frames posed at once (bounds memory).
        workers: threads that match the frames of a chunk side by side (the result does
            not depend on it).
    Returns:
        :class:`CanonicalRays` over all frames, and the (F, 3) world translations by which
        the frames were corrected (zeros without ``shift_sigma``).
    """
    n_frames = transforms.shape[0]
    if len(samples) != n_frames:
        raise ValueError(f"{len(samples)} sample sets for {n_frames} frames")
    radius = np.broadcast_to(np.asarray(max_distance, dtype=np.float64), (n_frames,))
    weights = body.skin_weights.to(canonical.dtype)
    rest_normals = vertex_normals(canonical, body.faces)
    centre = camera.center
    shifts = np.zeros((n_frames, 3))
    k_inv = np.linalg.inv(camera.K)
    tf_all = transforms.detach().cpu().double().numpy()
    parts: list[CanonicalRays] = []

    def match(f: int, posed: np.ndarray, normals: np.ndarray, corr: Tensor | None
              ) -> CanonicalRays | None:  # fmt: skip
        """Frame f's rays, matched on its posed mesh (V, 3) with normals (V, 3), unposed;
        sets ``shifts[f]``."""
        s = samples[f]
        ids, pix, dirs = contour_candidates(posed, normals, camera, max_cos)
        si, ci, dist = match_boundary(s, pix, dirs, float(radius[f]), normal_weight, min_dot)
        if len(si) == 0:
            return None
        vids = ids[ci]
        rays = pixel_directions(camera, k_inv, s.points[si])
        planes = _silhouette_planes(camera, s.points[si], s.normals[si])
        if shift_sigma is not None:
            shifts[f] = frame_shift(posed[vids], planes, centre, camera.R[:2], shift_sigma)
        # posing then shifting by Δt equals unposing rays shifted by −Δt
        m, n, p = unpose_lines(body, centre - shifts[f], rays, planes, vids, tf_all[f], corr)
        return CanonicalRays(vids, m, n, p, np.full(len(vids), f, np.int64), dist)

    with frame_pool(workers) as pool:
        for start in range(0, n_frames, chunk):
            stop = min(start + chunk, n_frames)
            tf = transforms[start:stop].to(canonical.dtype)
            rest = canonical[None].expand(stop - start, -1, -1)
            correctives = None
            if rotations is not None:
                correctives = body.pose_correctives(rotations[start:stop].to(canonical.dtype))
                if correctives is not None:
                    rest = rest + correctives
            with torch.no_grad():
                # blended transforms once for points and normals; the normals are rotated by
                # the blended linear part (exact for rigid parts, close enough to find
                # contours)
                blend = torch.einsum("vj,bjmn->bvmn", weights, tf[:, :, :3, :])
                posed = (blend[..., :3] @ rest.unsqueeze(-1)).squeeze(-1) + blend[..., 3]
                normals = (blend[..., :3] @ rest_normals.unsqueeze(-1)).squeeze(-1)
                normals = normals / normals.norm(dim=-1, keepdim=True).clamp_min(1e-12)
            posed_np = posed.double().numpy()
            normals_np = normals.double().numpy()
            corr = [None] * (stop - start) if correctives is None else list(correctives)
            found = pool.map(match, range(start, stop), posed_np, normals_np, corr)
            parts.extend(r for r in found if r is not None)
    return CanonicalRays.concatenate(parts), shifts
