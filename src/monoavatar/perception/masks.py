"""Cleaning person masks: temporal smoothing, choosing one person, filling holes, GrabCut.

All functions take plain arrays, so they can be called on any mask: (H, W) bool masks,
(N, H, W) float32 probabilities in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


def temporal_smooth(
    probabilities: np.ndarray, frame_indices: np.ndarray, sigma: float
) -> np.ndarray:
    """Gaussian smoothing of per-frame probabilities along time.

    Weights are ``exp(-½ (Δindex / sigma)²)`` over neighbours within 3 sigma, with Δindex the
    difference of *source* frame indices, so key-frames far apart are left alone.

    Args:
        probabilities: (N, H, W) float (or uint8, any scale).
        frame_indices: (N,) source frame index of each frame, increasing.
        sigma: standard deviation in source frames; 0 returns a float32 copy.
    Returns:
        (N, H, W) float32, in the input's scale.
    """
    probabilities = np.asarray(probabilities)
    if len(probabilities) == 0:
        return probabilities.astype(np.float32)
    n = len(probabilities)
    return np.stack([smooth_frame(probabilities, frame_indices, i, sigma) for i in range(n)])


def smooth_frame(
    probabilities: np.ndarray,
    frame_indices: np.ndarray,
    i: int,
    sigma: float,
    mixable: np.ndarray | None = None,
) -> np.ndarray:
    """Frame ``i`` of :func:`temporal_smooth` alone: (N, H, W) → (H, W) float32 (so that a long
    sequence needs no second (N, H, W) float array).

    Args:
        mixable: (N,) bool, the frames that may be mixed into frame ``i`` (frame ``i`` itself
            always is); None: all. The weights are normalised over the frames mixed.
    """
    idx = np.asarray(frame_indices, dtype=np.float64)
    if sigma <= 0 or len(idx) < 2:
        return probabilities[i].astype(np.float32)
    close = np.abs(idx - idx[i]) <= 3.0 * sigma
    if mixable is not None:
        close &= np.asarray(mixable, dtype=bool)
        close[i] = True
    near = np.flatnonzero(close)
    weights = np.exp(-0.5 * ((idx[near] - idx[i]) / sigma) ** 2)
    weights /= weights.sum()
    acc = np.zeros(probabilities.shape[1:], dtype=np.float32)
    for j, wj in zip(near, weights, strict=True):
        acc += np.float32(wj) * probabilities[j].astype(np.float32)
    return acc


def landmark_motion(keypoints_a: np.ndarray, keypoints_b: np.ndarray, seen: float = 0.5) -> float:
    """How far a person moved between two frames, from their body landmarks: the 90th percentile
    of the displacement of the landmarks seen (confidence > ``seen``) in both, divided by the
    vertical extent of those landmarks in the first frame. ``inf`` with fewer than 3 such
    landmarks (motion unknown).

    Args:
        keypoints_a, keypoints_b: (K, 3) x px, y px, confidence.
    """
    a, b = np.asarray(keypoints_a, np.float64), np.asarray(keypoints_b, np.float64)
    both = (a[:, 2] > seen) & (b[:, 2] > seen)
    if int(both.sum()) < 3:
        return float("inf")
    extent = float(np.ptp(a[both, 1]))
    if extent <= 0.0:
        return float("inf")
    shift = np.linalg.norm(a[both, :2] - b[both, :2], axis=1)
    return float(np.percentile(shift, 90)) / extent


def person_score(mask: np.ndarray) -> float:
    """How much a region looks like *the* subject: ``area × exp(-2 (d / r)²)``, d the distance of
    its centroid from the image centre, r half the image diagonal (0 for an empty region)."""
    mask = np.asarray(mask, dtype=bool)
    area = int(mask.sum())
    if area == 0:
        return 0.0
    h, w = mask.shape
    rows, cols = np.nonzero(mask)
    d = np.hypot(cols.mean() + 0.5 - w / 2.0, rows.mean() + 0.5 - h / 2.0)
    return float(area * np.exp(-2.0 * (d / (0.5 * np.hypot(w, h))) ** 2))


@dataclass(frozen=True)
class PersonChoice:
    """Result of :func:`select_person`.

    Attributes:
        mask: (H, W) bool, the kept person's component.
        num_people: how many person-sized components were seen (0 for an empty mask).
        others: (H, W) bool, the other person-sized components.
    """

    mask: np.ndarray
    num_people: int
    others: np.ndarray


def select_person(
    mask: np.ndarray, other_person_fraction: float = 0.2, min_area: int = 1
) -> PersonChoice:
    """Keep one connected component of a mask: the most central and largest.

    Components of at least ``other_person_fraction`` × the largest component's area (and
    ``min_area`` pixels) count as people; among them the one with the highest
    ``area × exp(-2 (d / r)²)`` is kept (:func:`person_score`). Smaller components (specks) are
    dropped.

    Args:
        mask: (H, W) bool.
    """
    mask = np.asarray(mask, dtype=bool)
    h, w = mask.shape
    count, labels, stats, centroids = cv2.connectedComponentsWithStats(
        mask.astype(np.uint8), connectivity=8
    )
    empty = np.zeros_like(mask)
    if count <= 1:
        return PersonChoice(mask=empty, num_people=0, others=empty)
    areas = stats[1:, cv2.CC_STAT_AREA].astype(np.float64)
    threshold = max(float(min_area), other_person_fraction * areas.max())
    people = np.flatnonzero(areas >= threshold) + 1
    if len(people) == 0:
        return PersonChoice(mask=empty, num_people=0, others=empty)
    centre = np.array([w / 2.0, h / 2.0])
    radius = 0.5 * np.hypot(w, h)
    dist = np.linalg.norm(centroids[people] + 0.5 - centre, axis=1)
    score = areas[people - 1] * np.exp(-2.0 * (dist / radius) ** 2)
    best = int(people[np.argmax(score)])
    others = np.isin(labels, people[people != best])
    return PersonChoice(mask=labels == best, num_people=len(people), others=others)


def largest_component(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool → the largest 8-connected component (empty stays empty)."""
    mask = np.asarray(mask, dtype=bool)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(
        mask.astype(np.uint8), connectivity=8
    )
    if count <= 1:
        return np.zeros_like(mask)
    return np.asarray(labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA])))


def fill_holes(mask: np.ndarray, max_hole_fraction: float = 0.01) -> np.ndarray:
    """Fill background regions enclosed by the mask that are small.

    Only holes of at most ``max_hole_fraction`` × the mask's area are filled: larger enclosed
    regions (the gap between an arm on the hip and the torso) are real background. Use
    ``float("inf")`` to fill every hole.

    Args:
        mask: (H, W) bool.
    Returns:
        (H, W) bool.
    """
    mask = np.asarray(mask, dtype=bool)
    area = int(mask.sum())
    if area == 0:
        return mask.copy()
    # 4-connected background, so that diagonal gaps in an 8-connected foreground still enclose.
    count, labels, stats, _ = cv2.connectedComponentsWithStats(
        (~mask).astype(np.uint8), connectivity=4
    )
    h, w = mask.shape
    x, y = stats[1:, cv2.CC_STAT_LEFT], stats[1:, cv2.CC_STAT_TOP]
    right = x + stats[1:, cv2.CC_STAT_WIDTH]
    bottom = y + stats[1:, cv2.CC_STAT_HEIGHT]
    inside = (x > 0) & (y > 0) & (right < w) & (bottom < h)
    small = stats[1:, cv2.CC_STAT_AREA] <= max_hole_fraction * area
    holes = np.flatnonzero(inside & small) + 1
    if len(holes) == 0:
        return mask.copy()
    return mask | np.isin(labels, holes)


def region_box(region: np.ndarray, margin: int) -> tuple[slice, slice] | None:
    """The (rows, cols) slices of the bounding box of ``region`` (H, W) bool grown by
    ``margin`` pixels and clipped to the image; None when the region is empty."""
    rows = np.flatnonzero(region.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(region.any(axis=0))
    h, w = region.shape
    return (slice(max(0, int(rows[0]) - margin), min(h, int(rows[-1]) + 1 + margin)),
            slice(max(0, int(cols[0]) - margin), min(w, int(cols[-1]) + 1 + margin)))  # fmt: skip


def grabcut_refine(
    image: np.ndarray, mask: np.ndarray, band_px: int = 8, iterations: int = 3
) -> np.ndarray:
    """Refine a mask's boundary with GrabCut, deciding only pixels near the boundary.

    Pixels farther than ``band_px`` inside the mask are fixed foreground, farther than
    ``band_px`` outside fixed background; the band in between is re-labelled by GrabCut's
    colour models. Works on the mask's bounding box (plus a margin) for speed.

    Args:
        image: (H, W, 3) uint8 RGB.
        mask: (H, W) bool.
    Returns:
        (H, W) bool; the input mask when it is empty or fills the image.
    """
    mask = np.asarray(mask, dtype=bool)
    if band_px < 1 or not mask.any() or mask.all():
        return mask.copy()
    box = region_box(mask, 4 * band_px)
    assert box is not None  # the mask is not empty
    rows, cols = box
    sub = mask[rows, cols].astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band_px + 1, 2 * band_px + 1))
    inner = cv2.erode(sub, kernel, borderType=cv2.BORDER_REPLICATE).astype(bool)
    outer = cv2.dilate(sub, kernel, borderType=cv2.BORDER_REPLICATE).astype(bool)
    trimap = np.where(sub.astype(bool), cv2.GC_PR_FGD, cv2.GC_PR_BGD).astype(np.uint8)
    trimap[inner] = cv2.GC_FGD
    trimap[~outer] = cv2.GC_BGD
    has_fg = np.any((trimap == cv2.GC_FGD) | (trimap == cv2.GC_PR_FGD))
    has_bg = np.any((trimap == cv2.GC_BGD) | (trimap == cv2.GC_PR_BGD))
    if not (has_fg and has_bg):
        return mask.copy()
    crop = np.ascontiguousarray(image[rows, cols])
    bgd = np.zeros((1, 65), np.float64)
    fgd = np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)  # GrabCut's GMM initialisation uses k-means with OpenCV's RNG
    cv2.grabCut(crop, trimap, (0, 0, 0, 0), bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    out = mask.copy()
    out[rows, cols] = (trimap == cv2.GC_FGD) | (trimap == cv2.GC_PR_FGD)
    return out
