"""Energy terms of pose fitting (Sec. B.3.2), as small pure functions of tensors.

Image-space residuals are in pixels divided by a per-frame scale (the person's height in
pixels), so that weights do not depend on the image size or on how far away the person stands.
All functions are batched over frames (leading dimension B) and differentiable in the model
quantities (projected points, poses); observations are constants.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor
from torch.nn import functional


def geman_mcclure(squared: Tensor, sigma: float) -> Tensor:
    """Geman-McClure robust penalty ρ(r) = σ² r² / (σ² + r²) of squared residuals r²
    (bounded by σ² for outliers, ≈ r² for small residuals)."""
    s2 = sigma * sigma
    return s2 * squared / (s2 + squared)


def keypoint_energy(
    projected: Tensor, observed: Tensor, scale: Tensor, sigma: float = 0.1
) -> Tensor:
    """Confidence-weighted robust 2D keypoint term.

    Args:
        projected: (B, K, 2) model keypoints projected to pixels.
        observed: (B, K, 3) detections: x px, y px, confidence (0 = absent).
        scale: (B,) normalising length in pixels (person height).
        sigma: Geman-McClure scale in units of ``scale``.
    Returns:
        (B,) Σ_k c_k ρ(|p_k − o_k| / scale) / Σ_k c_k (0 where no keypoint is present).
    """
    conf = observed[..., 2]
    r2 = ((projected - observed[..., :2]) ** 2).sum(-1) / scale[:, None] ** 2
    total = conf.sum(-1)
    return (conf * geman_mcclure(r2, sigma)).sum(-1) / total.clamp_min(1e-9)


@dataclass(frozen=True)
class SilhouetteTargets:
    """Precomputed per-frame silhouette data (constants during optimisation).

    Attributes:
        outside: (B, L, H, W) distance, in pixels of level 0, from each pixel to the observed
            mask (0 inside it), at L Gaussian-pyramid levels resampled to full size.
        boundary: (B, P, 2) pixel positions of observed mask boundary samples (padded).
        boundary_valid: (B, P) bool, which boundary samples are real.
        scale: (B,) person height in pixels.
    """

    outside: Tensor
    boundary: Tensor
    boundary_valid: Tensor
    scale: Tensor


def mask_pyramid_distances(mask: np.ndarray, levels: int = 4) -> np.ndarray:
    """Distance transforms of the complement of a mask on a Gaussian pyramid (Eq. B.4).

    Level l is the mask blurred and halved l times, thresholded at 0.5; its distance map is
    measured in level-0 pixels and resampled to full size, so the levels can be summed. The
    coarse levels smooth away thin structures and small detection errors (robustness to local
    minima); level 0 keeps the detail. Returns (levels, H, W) float32.
    """
    h, w = mask.shape
    current = mask.astype(np.float32)
    out = np.empty((levels, h, w), np.float32)
    for level in range(levels):
        binary = (current >= 0.5).astype(np.uint8)
        dist = cv2.distanceTransform(1 - binary, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        factor = 2**level
        # a coarse pixel's centre lies (factor - 1) / 2 fine pixels inside its edge
        dist = np.maximum(dist * factor - (factor - 1) / 2, 0.0)
        out[level] = cv2.resize(dist, (w, h), interpolation=cv2.INTER_LINEAR)
        current = np.asarray(cv2.pyrDown(current), dtype=np.float32)
    return out


def boundary_samples(mask: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """Up to ``count`` pixel-centre positions (x, y) on the mask's outer boundary, evenly
    spread along the contours. Returns (P, 2) float32, P ≤ count."""
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)  # fmt: skip
    if not contours:
        return np.zeros((0, 2), np.float32)
    points = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(np.float32) + 0.5
    if len(points) > count:
        start = rng.integers(0, len(points) // count + 1)
        points = points[np.linspace(start, len(points) - 1, count).astype(int)]
    return points


def silhouette_targets(
    masks: np.ndarray, levels: int = 4, boundary_count: int = 400, seed: int = 0
) -> SilhouetteTargets:
    """Build :class:`SilhouetteTargets` for masks (B, H, W) bool."""
    rng = np.random.default_rng(seed)
    outside = np.stack([mask_pyramid_distances(m, levels) for m in masks])
    samples = [boundary_samples(m, boundary_count, rng) for m in masks]
    count = max(1, max(len(s) for s in samples))
    boundary = np.zeros((len(masks), count, 2), np.float32)
    valid = np.zeros((len(masks), count), bool)
    heights = np.ones(len(masks), np.float32)
    for i, (m, s) in enumerate(zip(masks, samples, strict=True)):
        boundary[i, : len(s)] = s
        valid[i, : len(s)] = True
        rows = np.flatnonzero(m.any(axis=1))
        if len(rows):
            heights[i] = rows[-1] - rows[0] + 1
    return SilhouetteTargets(
        outside=torch.from_numpy(outside),
        boundary=torch.from_numpy(boundary),
        boundary_valid=torch.from_numpy(valid),
        scale=torch.from_numpy(heights),
    )


def sample_image(image: Tensor, points: Tensor) -> Tensor:
    """Bilinear samples of (B, C, H, W) images at (B, N, 2) pixel positions (x, y; pixel centre
    at +0.5), border-clamped. Returns (B, C, N); differentiable in ``points``."""
    _, _, h, w = image.shape
    grid = torch.stack([points[..., 0] / w * 2 - 1, points[..., 1] / h * 2 - 1], dim=-1)
    out = functional.grid_sample(image, grid[:, :, None, :].to(image.dtype),
                                 mode="bilinear", padding_mode="border", align_corners=False)
    return out[..., 0]  # fmt: skip


def outside_energy(projected: Tensor, targets: SilhouetteTargets,
                   points_valid: Tensor | None = None) -> Tensor:  # fmt: skip
    """Model points that fall outside the observed mask (the w_o I_rn C part of Eq. B.4):
    mean over points and pyramid levels of (distance to the mask / scale)². ``points_valid``
    (B, N) bool: only those points count (None: all). (B,)."""
    dist = sample_image(targets.outside, projected)  # (B, L, N)
    squared = (dist / targets.scale[:, None, None]) ** 2
    if points_valid is None:
        return squared.mean(dim=(1, 2))
    w = points_valid.to(projected.dtype)[:, None, :]
    return (squared * w).sum(dim=(1, 2)) / (w.sum(dim=(1, 2)) * dist.shape[1]).clamp_min(1.0)


def coverage_energy(projected: Tensor, targets: SilhouetteTargets, sigma: float = 0.1,
                    points_valid: Tensor | None = None) -> Tensor:  # fmt: skip
    """Observed mask the model misses (the w_i (1 − I_rn) C̄ part of Eq. B.4): each observed
    boundary sample's distance to the nearest projected model point, robustly penalised,
    averaged over samples. Differentiable through the nearest model point. ``points_valid``
    (B, N) bool: only those model points can be the nearest (None: all). (B,)."""
    boundary = targets.boundary.to(projected.dtype)  # (B, P, 2)
    index = nearest_points(boundary, projected, points_valid)  # (B, P), not differentiated
    points = torch.gather(projected, 1, index.unsqueeze(-1).expand(-1, -1, 2))
    nearest = ((boundary - points) ** 2).sum(-1) / targets.scale[:, None] ** 2
    valid = targets.boundary_valid.to(projected.dtype)
    return (geman_mcclure(nearest, sigma) * valid).sum(-1) / valid.sum(-1).clamp_min(1.0)


def nearest_points(queries: Tensor, points: Tensor, points_valid: Tensor | None = None) -> Tensor:
    """Index of the nearest point to each query, exactly (a k-d tree per frame, in float64).

    Args:
        queries: (B, P, D); points: (B, M, D), M ≥ 1.
        points_valid: (B, M) bool, which points may be chosen (None: all); a frame without a
            valid point gets index 0.
    Returns:
        (B, P) int64 indices into the points.
    """
    q = queries.detach().double().cpu().numpy()
    x = points.detach().double().cpu().numpy()
    keep = None if points_valid is None else points_valid.cpu().numpy()
    out = np.zeros(q.shape[:2], np.int64)
    for k in range(len(q)):
        ids = np.arange(x.shape[1]) if keep is None else np.flatnonzero(keep[k])
        if len(ids) == 0 or q.shape[1] == 0:
            continue
        tree = cKDTree(x[k, ids], leafsize=32, balanced_tree=False, compact_nodes=False)
        out[k] = ids[tree.query(q[k])[1]]
    return torch.from_numpy(out).to(queries.device)


def correspondence_energy(
    projected: Tensor, targets: Tensor, valid: Tensor, scale: Tensor, sigma: float = 1.0,
    normals: Tensor | None = None,
) -> Tensor:
    """Model points pulled to 2D correspondences (from optical flow; Eq. A.1 and the E_match of
    Eq. C.13 written on points instead of pixels): mean over the valid points of the robust
    ρ(|p − c| / scale). projected, targets (B, N, 2) pixels; valid (B, N) bool; scale (B,)
    pixels. With unit ``normals`` (B, N, 2) only the offset along them counts, ``(p − c) · n``
    (a point on an outline matched to the observed edge: point-to-line, free to slide along
    it). Returns (B,) (0 where no point is valid)."""
    if normals is None:
        r2 = ((projected - targets) ** 2).sum(-1) / scale[:, None] ** 2
    else:
        r2 = ((projected - targets) * normals).sum(-1) ** 2 / scale[:, None] ** 2
    w = valid.to(projected.dtype)
    return (w * geman_mcclure(r2, sigma)).sum(-1) / w.sum(-1).clamp_min(1.0)


def gaussian_prior_energy(pose: Tensor, mean: Tensor, precision: Tensor) -> Tensor:
    """Single-mode Gaussian pose prior: Mahalanobis (θ − μ)ᵀ Σ⁻¹ (θ − μ) over the body joints'
    axis-angle parameters. pose (B, D), mean (D,), precision (D, D). Returns (B,)."""
    d = pose - mean
    return torch.einsum("bi,ij,bj->b", d, precision, d)


def hinge_limit_energy(pose: Tensor, limits: Sequence[tuple[int, int, float, float]]) -> Tensor:
    """Soft joint limits: Σ relu(lo − θ)² + relu(θ − hi)² over (joint, axis, lo, hi) tuples
    (radians) of axis-angle poses (B, J, 3). Returns (B,)."""
    total = torch.zeros(pose.shape[0], dtype=pose.dtype, device=pose.device)
    for joint, axis, lo, hi in limits:
        angle = pose[:, joint, axis]
        total = total + torch.relu(lo - angle) ** 2 + torch.relu(angle - hi) ** 2
    return total


def small_rotation_vector(rotation: Tensor) -> Tensor:
    """Rotation vector of rotations (..., 3, 3) near the identity, ``vee(R − Rᵀ) / 2``: equal
    to the axis times sin(angle), so exact to first order and smooth everywhere (no
    singularity at zero, unlike the exact logarithm's gradient)."""
    skew = 0.5 * (rotation - rotation.transpose(-1, -2))
    return torch.stack([skew[..., 2, 1], skew[..., 0, 2], skew[..., 1, 0]], dim=-1)


def smoothness_energy(
    root: Tensor,
    body: Tensor,
    translation: Tensor,
    history: tuple[Tensor, Tensor, Tensor] | None = None,
    translation_scale: float = 0.1,
) -> Tensor:
    """Temporal smoothness of a window of B consecutive frames after H fitted ones.

    The body joints should change little from frame to frame (first differences of their
    axis-angle parameters, radians); the root orientation and translation should keep their
    velocity (second differences: a person turning around turns steadily). Translations are
    in units of ``translation_scale`` metres.

    Args:
        root: (B, 3, 3) root rotations; body: (B, J − 1, 3) axis-angle; translation: (B, 3).
        history: the H previous frames' (roots (H, 3, 3), body (H, J − 1, 3), translations
            (H, 3)), constants; H = 0, 1 or more.
    Returns:
        (B,) energy of each new frame (terms that need frames before the sequence start are 0).
    """
    if history is not None and history[0].shape[0] > 0:
        roots = torch.cat([history[0], root])
        bodies = torch.cat([history[1], body])
        trans = torch.cat([history[2], translation])
        h = history[0].shape[0]
    else:
        roots, bodies, trans, h = root, body, translation, 0
    zero = root.new_zeros(1)
    # first differences of the body joints: entry i is the term of frame i
    dbody = torch.cat([zero, ((bodies[1:] - bodies[:-1]) ** 2).sum(dim=(1, 2))])
    # angular velocity between consecutive frames (world axes) and translation velocity
    omega = small_rotation_vector(roots[1:] @ roots[:-1].transpose(-1, -2))  # (T-1, 3)
    velocity = (trans[1:] - trans[:-1]) / translation_scale
    parts = [zero]
    if len(omega):  # frame 1 has no acceleration yet: a weak velocity term
        parts.append(0.1 * ((omega[:1] ** 2).sum(-1) + (velocity[:1] ** 2).sum(-1)))
        parts.append(((omega[1:] - omega[:-1]) ** 2).sum(-1)
                     + ((velocity[1:] - velocity[:-1]) ** 2).sum(-1))  # fmt: skip
    motion = torch.cat(parts)
    return dbody[h:] + motion[h:]


def segment_distance(points: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """Distance from points (..., 3) to segments a→b (..., 3)."""
    ab = b - a
    t = (((points - a) * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-12)).clamp(0.0, 1.0)
    return (points - (a + t[..., None] * ab)).norm(dim=-1)


def penetration_energy(points: Tensor, a: Tensor, b: Tensor, radius: float | Tensor) -> Tensor:
    """Self-penetration avoidance with capsules: points (B, N, 3) (e.g. on the forearms) closer
    than ``radius`` metres to the segment a→b (B, 3) (e.g. the spine) are pushed out;
    Σ relu(radius − d)² in cm². Returns (B,)."""
    d = segment_distance(points, a[:, None], b[:, None])
    return ((torch.relu(radius - d) * 100.0) ** 2).sum(-1)
