"""The face against the face-mesh landmarks detected in the frames (Paper C, Sec. C.3.2).

The body's face points are the shipped :class:`~monoavatar.body.face_map.FaceMap`'s; a frame's
face error is how far they project from the 468 detected landmarks, as a fraction of the
detected outer eye corners' distance (so a close-up and a full-body frame compare): the
measure the face term of the detailed reconstruction has to lower.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from monoavatar.body import BodyModel
from monoavatar.body.face_map import FaceMap
from monoavatar.core.camera import PinholeCamera

__all__ = ["EYE_CORNERS", "face_errors", "relative_face_error"]

#: The face mesh's outer eye corners (the person's right, then left): the error's unit.
EYE_CORNERS = (33, 263)


def relative_face_error(projected: np.ndarray, detected: np.ndarray) -> np.ndarray:
    """(N, 468, 2) projected face points and (N, 468, 3) detected landmarks (x px, y px,
    confidence; NaN where no face was found) → (N,) the median over the landmarks of the
    pixel distance, over the detected outer eye corners' distance; NaN for frames without a
    detected face."""
    found = np.isfinite(detected[..., :2]).all(axis=(1, 2))
    out = np.full(len(detected), np.nan)
    if found.any():
        d = detected[found, :, :2].astype(np.float64)
        eyes = np.linalg.norm(d[:, EYE_CORNERS[0]] - d[:, EYE_CORNERS[1]], axis=-1)
        err = np.linalg.norm(projected[found] - d, axis=-1)
        out[found] = np.median(err, axis=1) / np.maximum(eyes, 1e-9)
    return out


def face_errors(body: BodyModel, face_map: FaceMap, vertices: Tensor, camera: PinholeCamera,
                detected: np.ndarray) -> np.ndarray:  # fmt: skip
    """(N, V, 3) posed vertices (world, metres) seen by ``camera``, (N, 468, 3) detected
    landmarks → (N,) :func:`relative_face_error`."""
    with torch.no_grad():
        projected, _ = camera.project(face_map.points(vertices, body.faces))
    return relative_face_error(projected.double().numpy(), np.asarray(detected))
