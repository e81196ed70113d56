"""Observations of rendered test scenes: masks and keypoints as given, no face landmarks, one
person in every frame, frames at 30 fps."""

from __future__ import annotations

import numpy as np

from monoavatar.core.camera import PinholeCamera
from monoavatar.perception.observations import Observations


def scene_observations(masks: np.ndarray, keypoints: np.ndarray,
                       camera: PinholeCamera) -> Observations:  # fmt: skip
    """masks (N, H, W) bool, keypoints (N, 33, 3) x, y, confidence → :class:`Observations`."""
    n = len(masks)
    return Observations(
        masks=masks,
        keypoints=keypoints,
        face=np.full((n, 468, 3), np.nan, np.float32),
        no_person=np.zeros(n, bool),
        multiple_people=np.zeros(n, bool),
        camera=camera,
        frame_indices=np.arange(n),
        timestamps=np.arange(n) / 30.0,
    )
