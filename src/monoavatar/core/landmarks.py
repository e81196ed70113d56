"""Landmark conventions shared by the body models, perception, data readers and synthetic data.

Our 2D/3D body keypoints are mediapipe's 33 pose landmarks, in mediapipe's order; faces are
mediapipe's 468-point face mesh. This module also holds OpenPose's body and face formats and
the conversions from OpenPose into our (mediapipe) order.

"Left" and "right" are the *person's* left and right in every format.

Pixel conventions differ between tools: OpenPose (like OpenCV) puts the centre of the top-left
pixel at (0, 0); we put the top-left pixel's *corner* at (0, 0) (DESIGN.md), so OpenPose
coordinates are shifted by +0.5 px on conversion. Mediapipe's normalised coordinates times the
image size are already in our convention.
"""

from __future__ import annotations

import numpy as np

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

#: The left and right hip, as indices into MEDIAPIPE_LANDMARKS.
HIP_LANDMARKS: tuple[int, int] = (23, 24)

#: The limb landmarks, shoulders to ankles (both sides), as indices into MEDIAPIPE_LANDMARKS.
LIMB_LANDMARKS: tuple[int, ...] = (11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28)


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

NUM_BODY_LANDMARKS = 33
NUM_FACE_LANDMARKS = 468

OPENPOSE_COCO18: tuple[str, ...] = (
    "nose", "neck", "right_shoulder", "right_elbow", "right_wrist", "left_shoulder",
    "left_elbow", "left_wrist", "right_hip", "right_knee", "right_ankle", "left_hip",
    "left_knee", "left_ankle", "right_eye", "left_eye", "right_ear", "left_ear",
)  # fmt: skip
"""OpenPose COCO-18 joint names in file order (the People-Snapshot ``keypoints.hdf5`` format)."""

OPENPOSE_BODY25: tuple[str, ...] = (
    "nose", "neck", "right_shoulder", "right_elbow", "right_wrist", "left_shoulder",
    "left_elbow", "left_wrist", "mid_hip", "right_hip", "right_knee", "right_ankle", "left_hip",
    "left_knee", "left_ankle", "right_eye", "left_eye", "right_ear", "left_ear",
    "left_big_toe", "left_small_toe", "left_heel", "right_big_toe", "right_small_toe",
    "right_heel",
)  # fmt: skip
"""OpenPose BODY_25 joint names in file order."""

# OpenPose name -> mediapipe name, for the joints that exist in both. Neck, mid-hip and the
# small toes have no mediapipe counterpart; mediapipe's inner/outer eye corners, mouth corners
# and hand points have no OpenPose body counterpart (they get zero confidence). The big toe is
# taken as mediapipe's "foot index" (the tip of the foot).
_OPENPOSE_TO_MEDIAPIPE_NAME = {
    "nose": "nose",
    "left_eye": "left_eye",
    "right_eye": "right_eye",
    "left_ear": "left_ear",
    "right_ear": "right_ear",
    "left_shoulder": "left_shoulder",
    "right_shoulder": "right_shoulder",
    "left_elbow": "left_elbow",
    "right_elbow": "right_elbow",
    "left_wrist": "left_wrist",
    "right_wrist": "right_wrist",
    "left_hip": "left_hip",
    "right_hip": "right_hip",
    "left_knee": "left_knee",
    "right_knee": "right_knee",
    "left_ankle": "left_ankle",
    "right_ankle": "right_ankle",
    "left_heel": "left_heel",
    "right_heel": "right_heel",
    "left_big_toe": "left_foot_index",
    "right_big_toe": "right_foot_index",
}


def _index_map(names: tuple[str, ...]) -> np.ndarray:
    """(K, 2) int pairs (source index, mediapipe index)."""
    mp_index = {n: i for i, n in enumerate(MEDIAPIPE_LANDMARKS)}
    pairs = [
        (i, mp_index[_OPENPOSE_TO_MEDIAPIPE_NAME[n]])
        for i, n in enumerate(names)
        if n in _OPENPOSE_TO_MEDIAPIPE_NAME
    ]
    return np.asarray(pairs, dtype=np.int64)


COCO18_TO_MEDIAPIPE = _index_map(OPENPOSE_COCO18)
"""(17, 2) pairs (COCO-18 index, mediapipe index) of corresponding joints (all but the neck)."""
BODY25_TO_MEDIAPIPE = _index_map(OPENPOSE_BODY25)
"""(21, 2) pairs (BODY_25 index, mediapipe index); neck, mid-hip and small toes are unmapped."""

# dlib/OpenPose 68-point face landmarks -> mediapipe face-mesh vertex. Exact for eye and mouth
# corners, nose tip and chin; the jaw line (0-16) is a view-dependent contour in the 68-point
# scheme and is matched to the mesh's contour for a frontal face only. OpenPose's points 68 and
# 69 (pupils) have no vertex among the 468.
FACE68_TO_MEDIAPIPE468: tuple[int, ...] = (
    127, 234, 93, 132, 58, 136, 150, 176, 152, 400, 379, 365, 288, 361, 323, 454, 356,  # jaw
    70, 63, 105, 66, 107,  # right eyebrow (outer -> inner)
    336, 296, 334, 293, 300,  # left eyebrow (inner -> outer)
    168, 197, 5, 4,  # nose bridge, top -> tip
    75, 97, 2, 326, 305,  # nostrils, right -> left
    33, 160, 158, 133, 153, 144,  # right eye, from the outer corner
    362, 385, 387, 263, 373, 380,  # left eye, from the inner corner
    61, 39, 37, 0, 267, 269, 291, 405, 314, 17, 84, 181,  # outer lip, from the right corner
    78, 82, 13, 312, 308, 317, 14, 87,  # inner lip, from the right corner
)  # fmt: skip
"""For each of the 68 dlib/OpenPose face landmarks, the mediapipe face-mesh vertex index."""


def openpose_to_mediapipe_body(keypoints: np.ndarray, fmt: str) -> np.ndarray:
    """Convert OpenPose body keypoints to our 33-landmark order.

    Args:
        keypoints: (..., J, 3) OpenPose x, y (pixels, OpenPose convention: pixel centres at
            integers) and confidence; J = 18 for ``fmt="coco18"``, 25 for ``fmt="body25"``.
            Joints with confidence 0 are absent.
    Returns:
        (..., 33, 3) float32 x, y in our pixel convention (+0.5 px) and confidence; landmarks
        without a counterpart, and absent joints, are (0, 0, 0).
    """
    table = {"coco18": COCO18_TO_MEDIAPIPE, "body25": BODY25_TO_MEDIAPIPE}.get(fmt)
    if table is None:
        raise ValueError(f"unknown OpenPose body format {fmt!r}; use 'coco18' or 'body25'")
    keypoints = np.asarray(keypoints, dtype=np.float64)
    expected = 18 if fmt == "coco18" else 25
    if keypoints.shape[-2:] != (expected, 3):
        raise ValueError(
            f"{fmt} keypoints must have shape (..., {expected}, 3), got {keypoints.shape}"
        )
    out = np.zeros(keypoints.shape[:-2] + (NUM_BODY_LANDMARKS, 3), dtype=np.float32)
    src = keypoints[..., table[:, 0], :]
    conf = np.nan_to_num(src[..., 2], nan=0.0).clip(0.0, 1.0)
    present = conf > 0
    out[..., table[:, 1], 0] = np.where(present, src[..., 0] + 0.5, 0.0)
    out[..., table[:, 1], 1] = np.where(present, src[..., 1] + 0.5, 0.0)
    out[..., table[:, 1], 2] = conf
    return out


def openpose_to_mediapipe_face(face: np.ndarray) -> np.ndarray:
    """Convert OpenPose face keypoints (70 or 68 points) to mediapipe face-mesh rows.

    Args:
        face: (..., 70, 3) or (..., 68, 3) x, y (OpenPose pixel convention) and confidence.
    Returns:
        (..., 468, 3) float32 x, y (our convention, +0.5 px) and confidence at the 68 mapped
        vertices (:data:`FACE68_TO_MEDIAPIPE468`); NaN at every other vertex and at points with
        zero confidence.
    """
    face = np.asarray(face, dtype=np.float64)
    if face.shape[-1] != 3 or face.shape[-2] not in (68, 70):
        raise ValueError(f"face keypoints must have shape (..., 70 or 68, 3), got {face.shape}")
    face = face[..., :68, :]
    out = np.full(face.shape[:-2] + (NUM_FACE_LANDMARKS, 3), np.nan, dtype=np.float32)
    idx = np.asarray(FACE68_TO_MEDIAPIPE468)
    conf = np.nan_to_num(face[..., 2], nan=0.0).clip(0.0, 1.0)
    values = np.stack([face[..., 0] + 0.5, face[..., 1] + 0.5, conf], axis=-1)
    values[conf <= 0] = np.nan
    out[..., idx, :] = values
    return out


def mediapipe_face_to_68(face: np.ndarray) -> np.ndarray:
    """The 68 dlib-order points of mediapipe face-mesh landmarks: (..., 468, C) -> (..., 68, C)."""
    return np.asarray(face)[..., np.asarray(FACE68_TO_MEDIAPIPE468), :]
