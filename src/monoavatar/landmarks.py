"""Keypoint conventions shared by the body models, perception and synthetic data.

Our 2D/3D body keypoints are mediapipe's 33 pose landmarks, in mediapipe's order.
"""

from __future__ import annotations

MEDIAPIPE_LANDMARKS: tuple[str, ...] = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
    "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_pinky",
    "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel",
    "right_heel", "left_foot_index", "right_foot_index",
)  # fmt: skip

#: The COCO-17 subset, as indices into MEDIAPIPE_LANDMARKS.
COCO17_IN_MEDIAPIPE: tuple[int, ...] = (
    0, 2, 5, 7, 8, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28
)  # fmt: skip


def _mirror_index(name: str) -> int:
    if name.startswith("left_"):
        return MEDIAPIPE_LANDMARKS.index("right_" + name[5:])
    if name.startswith("right_"):
        return MEDIAPIPE_LANDMARKS.index("left_" + name[6:])
    if name.endswith("_left"):
        return MEDIAPIPE_LANDMARKS.index(name[:-5] + "_right")
    if name.endswith("_right"):
        return MEDIAPIPE_LANDMARKS.index(name[:-6] + "_left")
    return MEDIAPIPE_LANDMARKS.index(name)


#: For each landmark, the index of its left/right counterpart (itself for the nose): indexing
#: keypoints with it swaps the person's left and right.
MEDIAPIPE_MIRROR: tuple[int, ...] = tuple(_mirror_index(n) for n in MEDIAPIPE_LANDMARKS)
