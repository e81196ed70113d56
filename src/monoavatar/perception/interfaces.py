"""The small interfaces each detector sits behind, so that another can be plugged in.

All take one image: (H, W, 3) uint8 RGB, and answer in pixels with the origin at the top-left
corner of the top-left pixel. ``name`` identifies the detector *and its settings*; it is part of
the perception cache key, so two detectors that can give different answers must have different
names.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class PoseResult:
    """One person's body landmarks in one image.

    Attributes:
        keypoints: (33, 3) float32 x px, y px, confidence in [0, 1], mediapipe order.
        segmentation: (H, W) float32 person probability in [0, 1], or None when the detector
            gives no mask.
        world: (33, 4) float32 metric 3D landmarks x, y, z metres relative to the midpoint of
            the hips, camera axes (x right, y down, z forward), and confidence; None when the
            detector gives none.
    """

    keypoints: np.ndarray
    segmentation: np.ndarray | None = None
    world: np.ndarray | None = None


@runtime_checkable
class PoseDetector(Protocol):
    """Finds one person's 33 body landmarks (and possibly their mask) in an image."""

    @property
    def name(self) -> str: ...

    def detect(self, image: np.ndarray) -> PoseResult | None:
        """image: (H, W, 3) uint8 RGB → the person's landmarks, or None when nobody is found."""
        ...


@runtime_checkable
class PersonSegmenter(Protocol):
    """Segments people in an image."""

    @property
    def name(self) -> str: ...

    def segment(self, image: np.ndarray) -> np.ndarray:
        """image: (H, W, 3) uint8 RGB → (H, W) float32 person probability in [0, 1]."""
        ...


@runtime_checkable
class FaceDetector(Protocol):
    """Finds faces and their 468 face-mesh landmarks."""

    @property
    def name(self) -> str: ...

    def detect(self, image: np.ndarray) -> list[np.ndarray]:
        """image: (H, W, 3) uint8 RGB → one (468, 3) float32 array per face found: x px, y px,
        confidence in [0, 1]. An empty list when there is no face."""
        ...


@runtime_checkable
class FlowEstimator(Protocol):
    """Dense optical flow between two images."""

    @property
    def name(self) -> str: ...

    def estimate(self, image0: np.ndarray, image1: np.ndarray) -> np.ndarray:
        """image0, image1: (H, W, 3) uint8 RGB → (H, W, 2) float32 flow in pixels (dx, dy):
        the content at pixel p of ``image0`` is at p + flow[p] in ``image1``."""
        ...
