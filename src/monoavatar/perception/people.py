"""Per-image helpers of perception: the head box and face landmarks, which detected face belongs
to the person, and the search for a second person (a bystander) in a frame."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cv2
import numpy as np

from monoavatar.perception.interfaces import (
    FaceDetector,
    PoseDetector,
    PoseResult,
)
from monoavatar.perception.masks import (
    person_score,
)

_VISIBLE = 0.5  # keypoint confidence above which a landmark counts as seen

if TYPE_CHECKING:
    from monoavatar.perception.pipeline import PerceptionSettings


def head_box(keypoints: np.ndarray) -> tuple[float, float, float] | None:
    """A square box around the head from body landmarks: (centre x, centre y, side) in px.

    Uses the face landmarks 0-10 (nose, eyes, ears, mouth) seen with confidence > 0.2: side =
    max(3 × their extent, 0.9 × shoulder width, 48 px). None with fewer than 2 such points.
    """
    head = keypoints[:11]
    seen = head[head[:, 2] > 0.2, :2]
    if len(seen) < 2:
        return None
    extent = float(np.ptp(seen, axis=0).max())
    side = max(3.0 * extent, 48.0)
    if keypoints[11, 2] > 0.2 and keypoints[12, 2] > 0.2:
        side = max(side, 0.9 * float(np.linalg.norm(keypoints[11, :2] - keypoints[12, :2])))
    cx, cy = seen.mean(axis=0)
    return float(cx), float(cy), side


def detect_face(
    image: np.ndarray,
    detector: FaceDetector,
    keypoints: np.ndarray | None = None,
    crop_size: int = 256,
) -> list[np.ndarray]:
    """Face landmarks of the faces in ``image``, looking around the head when body landmarks
    are given (faces in full-body shots are too small for the face detector otherwise).

    Args:
        image: (H, W, 3) uint8 RGB.
        keypoints: (33, 3) body landmarks of the person, or None to search the whole image.
        crop_size: side in pixels the head crop is resampled to.
    Returns:
        (468, 3) float32 arrays (x px, y px, confidence) in ``image``'s pixel coordinates.
    """
    box = head_box(keypoints) if keypoints is not None else None
    if box is None:
        return [f.astype(np.float32) for f in detector.detect(image)]
    cx, cy, side = box
    x0, y0 = cx - side / 2.0, cy - side / 2.0
    a = side / crop_size  # source pixels per crop pixel
    # crop pixel centre j + 0.5 ↔ source x0 + (j + 0.5) a; OpenCV puts pixel centres at integers
    M = np.array([[a, 0.0, x0 + 0.5 * a - 0.5], [0.0, a, y0 + 0.5 * a - 0.5]])
    crop = cv2.warpAffine(
        image, M, (crop_size, crop_size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
    )
    faces = []
    for f in detector.detect(crop):
        out = np.asarray(f, dtype=np.float32).copy()
        out[:, 0] = x0 + out[:, 0] * a
        out[:, 1] = y0 + out[:, 1] * a
        faces.append(out)
    return faces


def choose_face(
    faces: list[np.ndarray], keypoints: np.ndarray | None, mask: np.ndarray
) -> np.ndarray | None:
    """The face belonging to the kept person: nearest the body's nose, mostly inside the mask."""
    h, w = mask.shape
    grown = cv2.dilate(mask.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    good = []
    for f in faces:
        col = np.clip(np.floor(f[:, 0]).astype(np.int64), 0, w - 1)
        row = np.clip(np.floor(f[:, 1]).astype(np.int64), 0, h - 1)
        inside = (f[:, 0] >= 0) & (f[:, 0] < w) & (f[:, 1] >= 0) & (f[:, 1] < h)
        if np.mean(inside & grown[row, col]) >= 0.5:
            good.append(f)
    if not good:
        return None
    if keypoints is not None and keypoints[0, 2] > 0.1:
        target = keypoints[0, :2]
    else:
        target = np.array([w / 2.0, h / 2.0])
    dist = [np.linalg.norm(np.nanmean(f[:, :2], axis=0) - target) for f in good]
    return good[int(np.argmin(dist))]


def keypoints_belong_elsewhere(keypoints: np.ndarray, mask: np.ndarray, others: np.ndarray
                                ) -> bool:
    """Whether more confidently seen landmarks fall on other people than on ``mask``."""
    h, w = mask.shape
    seen = keypoints[keypoints[:, 2] > _VISIBLE, :2]
    inside = (seen[:, 0] >= 0) & (seen[:, 0] < w) & (seen[:, 1] >= 0) & (seen[:, 1] < h)
    seen = seen[inside]
    if len(seen) == 0:
        return False
    col, row = seen[:, 0].astype(np.int64), seen[:, 1].astype(np.int64)
    return int(others[row, col].sum()) > int(mask[row, col].sum())


def hide_people(image: np.ndarray, others: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """``image`` with the ``others`` regions (grown by 2 % of the diagonal) painted with the
    median background colour, so that a detector sees only the kept person."""
    h, w = others.shape
    r = max(1, round(0.02 * math.hypot(h, w)))
    kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    grown = cv2.dilate(others.astype(np.uint8), kernel).astype(bool) & ~keep
    background = ~(grown | keep)
    fill = np.median(image[background], axis=0) if background.any() else np.full(3, 127.0)
    out = image.copy()
    out[grown] = fill.astype(np.uint8)
    return out


def person_region(result: PoseResult, shape: tuple[int, int], threshold: float) -> np.ndarray:
    """(H, W) bool region of a detected person: its mask, else the hull of its landmarks."""
    if result.segmentation is not None:
        return np.asarray(result.segmentation >= threshold)
    region = np.zeros(shape, np.uint8)
    seen = result.keypoints[result.keypoints[:, 2] > _VISIBLE, :2]
    if len(seen) >= 3:
        hull = cv2.convexHull(np.round(seen - 0.5).astype(np.int32))
        cv2.fillConvexPoly(region, np.asarray(hull, dtype=np.int32), (1,))
        r = max(1, round(0.05 * math.hypot(*shape)))
        kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
        return np.asarray(cv2.dilate(region, kernel), dtype=bool)
    return region.astype(bool)


def second_person(
    image: np.ndarray,
    first: PoseResult,
    pose: PoseDetector,
    settings: PerceptionSettings,
    min_area: int,
) -> tuple[PoseResult, bool]:
    """Look for another person with the first one hidden. Returns the detection to keep (the
    more central and larger) and whether a second person was found.

    A second detection counts when its region covers at least ``other_person_fraction`` of the
    first's area, barely overlaps the first (< 20 % of the smaller of the two: a region that
    takes in the painted-over first person is the detector seeing the paint and the clutter
    around it, not someone else), and most of its confidently seen landmarks lie outside the
    first person.
    """
    shape = (int(image.shape[0]), int(image.shape[1]))
    first_region = person_region(first, shape, settings.mask_threshold)
    if int(first_region.sum()) < min_area:
        return first, False
    other = pose.detect(hide_people(image, first_region, np.zeros(shape, dtype=bool)))
    if other is None:
        return first, False
    other_region = person_region(other, shape, settings.mask_threshold)
    area, other_area = int(first_region.sum()), int(other_region.sum())
    if other_area < max(min_area, settings.other_person_fraction * area):
        return first, False
    if int((other_region & first_region).sum()) > 0.2 * min(area, other_area):
        return first, False
    if fraction_inside(other.keypoints, first_region) > 0.5:
        return first, False
    if person_score(other_region) > person_score(first_region):
        return other, True
    return first, True


def fraction_inside(keypoints: np.ndarray, region: np.ndarray) -> float:
    """Fraction of the confidently seen landmarks that lie inside ``region``."""
    h, w = region.shape
    seen = keypoints[keypoints[:, 2] > _VISIBLE, :2]
    inside = (seen[:, 0] >= 0) & (seen[:, 0] < w) & (seen[:, 1] >= 0) & (seen[:, 1] < h)
    if not inside.any():
        return 0.0
    pts = seen[inside].astype(np.int64)
    return float(region[pts[:, 1], pts[:, 0]].mean())
