"""Perception against ground truth: mask IoU, keypoint error relative to the person's height,
and left/right swaps, per frame (for tests and ``benchmarks/perception_accuracy.py``).

Person height, the scale of the keypoint errors: the number of image rows the ground-truth mask
spans (top row to bottom row, inclusive), in pixels. It is the person's extent on the image
as seen, so a raised arm or a bent knee changes it a little; in a turn-around it varies by a few
per cent with the view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from monoavatar.core.landmarks import (
    COCO17_IN_MEDIAPIPE,
    MEDIAPIPE_LANDMARKS,
    MEDIAPIPE_MIRROR,
    NUM_BODY_LANDMARKS,
)
from monoavatar.eval.image import silhouette_iou
from monoavatar.perception.observations import Observations

#: Left/right pairs checked for swaps, by body part (mediapipe indices of the *left* landmark).
SWAP_GROUPS: dict[str, tuple[int, ...]] = {
    "head": (2, 7),  # eyes, ears
    "arms": (11, 13, 15),  # shoulders, elbows, wrists
    "legs": (23, 25, 27),  # hips, knees, ankles
}


@dataclass(frozen=True)
class PerceptionAccuracy:
    """Per-frame accuracy of perception against ground truth.

    Attributes:
        mask_iou: (N,) IoU of the person mask with the true mask (0 for a frame where no
            person was found but the truth has one).
        person_height: (N,) px, rows spanned by the true mask (0 for an empty true mask).
        joints: (J,) mediapipe indices of the evaluated landmarks.
        keypoint_error: (N, J) px, distance of each detected landmark from the true one; NaN
            where the truth has no such landmark or no person was detected.
        visible: (N, J) bool, the landmark is visible in the truth (not occluded).
        detected: (N,) bool, perception found a person.
        swapped: (N, G) bool, per :data:`SWAP_GROUPS` group (order of ``swap_groups``): the
            detection fits the truth at least twice as well with that group's left and right
            exchanged (summed distance over its pairs, occluded landmarks included). The factor
            keeps side views out, where left and right project a few pixels apart and either
            assignment fits about as well.
        swap_groups: (G,) names of the groups.
    """

    mask_iou: np.ndarray
    person_height: np.ndarray
    joints: np.ndarray
    keypoint_error: np.ndarray
    visible: np.ndarray
    detected: np.ndarray
    swapped: np.ndarray
    swap_groups: tuple[str, ...]

    @property
    def joint_names(self) -> list[str]:
        return [MEDIAPIPE_LANDMARKS[j] for j in self.joints]

    @property
    def relative_error(self) -> np.ndarray:
        """(N, J) keypoint error as a fraction of the person's height (NaN as above)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            height = np.where(self.person_height > 0, self.person_height, np.nan)
            return np.asarray(self.keypoint_error / height[:, None])

    def _evaluated(self, occluded: bool) -> np.ndarray:
        ok = np.isfinite(self.keypoint_error) & (self.person_height[:, None] > 0)
        return ok if occluded else ok & self.visible

    def keypoint_errors(self, relative: bool = False, occluded: bool = False) -> np.ndarray:
        """(K,) the evaluated errors pooled over frames and joints: visible true landmarks only
        (``occluded=False``) or all; px, or fractions of the height (``relative=True``)."""
        values = self.relative_error if relative else self.keypoint_error
        return np.asarray(values[self._evaluated(occluded)])

    def swap_rate(self, group: str | None = None) -> float:
        """Fraction of the frames with a detection where ``group`` (or any group) is swapped."""
        if not self.detected.any():
            return float("nan")
        swapped = self.swapped[self.detected]
        if group is None:
            return float(swapped.any(axis=1).mean())
        return float(swapped[:, self.swap_groups.index(group)].mean())

    def summary(self) -> dict[str, float]:
        """Headline figures: IoU median / mean / min, keypoint error median in px and in per
        cent of the height (visible landmarks; and all landmarks), swap rates in per cent."""
        px = self.keypoint_errors()
        rel = self.keypoint_errors(relative=True)
        rel_all = self.keypoint_errors(relative=True, occluded=True)

        def med(a: np.ndarray) -> float:
            return float(np.median(a)) if a.size else float("nan")

        out = {
            "frames": float(len(self.mask_iou)),
            "detected": float(self.detected.sum()),
            "iou_median": med(self.mask_iou),
            "iou_mean": float(np.mean(self.mask_iou)),
            "iou_min": float(np.min(self.mask_iou)),
            "height_px_median": med(self.person_height),
            "keypoint_error_px_median": med(px),
            "keypoint_error_pct_median": 100.0 * med(rel),
            "keypoint_error_pct_mean": 100.0 * float(np.mean(rel)) if rel.size else float("nan"),
            "keypoint_error_pct_p90": (
                100.0 * float(np.percentile(rel, 90)) if rel.size else float("nan")
            ),
            "keypoint_error_pct_median_all": 100.0 * med(rel_all),
            "swap_pct_any": 100.0 * self.swap_rate(),
        }
        for group in self.swap_groups:
            out[f"swap_pct_{group}"] = 100.0 * self.swap_rate(group)
        return out


def mask_height(masks: np.ndarray) -> np.ndarray:
    """(N, H, W) bool → (N,) float64 rows spanned by each mask (0 when empty)."""
    rows = np.asarray(masks, dtype=bool).any(axis=2)
    out = np.zeros(len(rows))
    for i, r in enumerate(rows):
        hit = np.flatnonzero(r)
        if hit.size:
            out[i] = hit[-1] - hit[0] + 1
    return out


def perception_accuracy(
    observations: Observations,
    true_masks: np.ndarray,
    true_keypoints: np.ndarray,
    joints: tuple[int, ...] = COCO17_IN_MEDIAPIPE,
) -> PerceptionAccuracy:
    """Compare perception with ground truth.

    Args:
        observations: perception of N frames.
        true_masks: (N, H, W) bool true person masks.
        true_keypoints: (N, 33, 3) true landmarks, x px, y px, visibility (1 visible, 0
            occluded); all-zero rows are landmarks the truth lacks.
        joints: mediapipe indices to evaluate (default the COCO-17 subset).
    """
    n = len(observations)
    true_masks = np.asarray(true_masks, dtype=bool)
    true_keypoints = np.asarray(true_keypoints, dtype=np.float64)
    if true_masks.shape != observations.masks.shape:
        raise ValueError(
            f"true_masks must have shape {observations.masks.shape}, got {true_masks.shape}"
        )
    if true_keypoints.shape != (n, NUM_BODY_LANDMARKS, 3):
        raise ValueError(
            f"true_keypoints must have shape {(n, NUM_BODY_LANDMARKS, 3)}, "
            f"got {true_keypoints.shape}"
        )
    idx = np.asarray(joints, dtype=np.int64)
    detected = ~observations.no_person
    iou = np.array([silhouette_iou(observations.masks[i], true_masks[i]) for i in range(n)])
    pred = observations.keypoints[..., :2].astype(np.float64)
    exists = np.any(true_keypoints != 0.0, axis=2)  # (N, 33)
    dist = np.linalg.norm(pred - true_keypoints[..., :2], axis=2)  # (N, 33)
    error = np.where(exists & detected[:, None], dist, np.nan)[:, idx]
    visible = (true_keypoints[..., 2] > 0.5)[:, idx]

    mirror = np.asarray(MEDIAPIPE_MIRROR, dtype=np.int64)
    crossed = np.linalg.norm(pred[:, mirror] - true_keypoints[..., :2], axis=2)  # (N, 33)
    names = tuple(SWAP_GROUPS)
    swapped = np.zeros((n, len(names)), dtype=bool)
    for g, name in enumerate(names):
        left = np.asarray(SWAP_GROUPS[name], dtype=np.int64)
        pair = np.concatenate([left, mirror[left]])
        ok = exists[:, pair]
        count = ok.sum(axis=1)
        straight = np.where(ok, dist[:, pair], 0.0).sum(axis=1)
        across = np.where(ok, crossed[:, pair], 0.0).sum(axis=1)
        swapped[:, g] = detected & (count > 0) & (across < 0.5 * straight)
    return PerceptionAccuracy(
        mask_iou=iou,
        person_height=mask_height(true_masks),
        joints=idx,
        keypoint_error=error,
        visible=visible,
        detected=detected,
        swapped=swapped,
        swap_groups=names,
    )
