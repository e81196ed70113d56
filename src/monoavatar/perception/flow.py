"""Dense optical flow between consecutive frames (OpenCV DIS or DeepFlow).

Flow convention: ``flow[row, col] = (dx, dy)`` in pixels, forward: the content at pixel centre
p = (col + 0.5, row + 0.5) of the first image is at p + (dx, dy) in the second.

DIS (the default) is fast; DeepFlow is much slower and more accurate
(``benchmarks/bench_perception.py`` measures both).
"""

from __future__ import annotations

from typing import Any, Literal

import cv2
import numpy as np

from monoavatar.perception.interfaces import FlowEstimator
from monoavatar.perception.masks import region_box
from monoavatar.perception.mediapipe_backend import check_image

FlowMethod = Literal["dis", "deepflow"]

_DIS_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}


def _grey(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(check_image(image), cv2.COLOR_RGB2GRAY)


class DISFlow:
    """OpenCV's Dense Inverse Search flow (Kroeger et al. 2016).

    Args:
        preset: "ultrafast", "fast" or "medium" (OpenCV's presets; slower is more accurate).
    """

    def __init__(self, preset: str = "medium") -> None:
        if preset not in _DIS_PRESETS:
            raise ValueError(f"DIS preset must be one of {sorted(_DIS_PRESETS)}, got {preset!r}")
        self._preset = preset
        self._dis: Any = cv2.DISOpticalFlow.create(_DIS_PRESETS[preset])

    @property
    def name(self) -> str:
        return f"opencv-{cv2.__version__}-dis-{self._preset}"

    def estimate(self, image0: np.ndarray, image1: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB × 2 → (H, W, 2) float32 forward flow, pixels."""
        a, b = _grey(image0), _grey(image1)
        if a.shape != b.shape:
            raise ValueError(f"flow needs images of one size, got {a.shape} and {b.shape}")
        return np.asarray(self._dis.calc(a, b, None), dtype=np.float32)

    def estimate_near(self, image0: np.ndarray, image1: np.ndarray, region: np.ndarray,
                      margin: int = 32) -> np.ndarray:  # fmt: skip
        """Forward flow where it is needed: computed on the bounding box of ``region`` grown by
        ``margin`` pixels (the whole image when that box covers it), zero outside the box.

        Args:
            image0, image1: (H, W, 3) uint8 RGB.
            region: (H, W) bool, the pixels whose flow is wanted.
            margin: pixels of context around the region's box (more than the longest flow
                wanted, so that the patches at its edge still see their match).
        Returns:
            (H, W, 2) float32 forward flow, pixels.
        """
        region = np.asarray(region, dtype=bool)
        h, w = np.asarray(image0).shape[:2]
        if region.shape != (h, w):
            raise ValueError(f"region must have shape {(h, w)}, got {region.shape}")
        out = np.zeros((h, w, 2), np.float32)
        box = region_box(region, margin)
        if box is None:
            return out
        rows, cols = box
        out[rows, cols] = self.estimate(np.ascontiguousarray(image0[rows, cols]),
                                        np.ascontiguousarray(image1[rows, cols]))  # fmt: skip
        return out


class DeepFlow:
    """OpenCV-contrib's DeepFlow (Weinzaepfel et al. 2013): slower, more accurate."""

    def __init__(self) -> None:
        self._flow: Any = cv2.optflow.createOptFlow_DeepFlow()

    @property
    def name(self) -> str:
        return f"opencv-{cv2.__version__}-deepflow"

    def estimate(self, image0: np.ndarray, image1: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB × 2 → (H, W, 2) float32 forward flow, pixels."""
        a, b = _grey(image0), _grey(image1)
        if a.shape != b.shape:
            raise ValueError(f"flow needs images of one size, got {a.shape} and {b.shape}")
        return np.asarray(self._flow.calc(a, b, None), dtype=np.float32)


def flow_estimator_name(method: FlowMethod = "dis") -> str:
    """The name :func:`make_flow_estimator` (``method``) would have, without making it."""
    if method == "dis":
        return f"opencv-{cv2.__version__}-dis-medium"
    if method == "deepflow":
        return f"opencv-{cv2.__version__}-deepflow"
    raise ValueError(f"flow method must be 'dis' or 'deepflow', got {method!r}")


def make_flow_estimator(method: FlowMethod = "dis") -> FlowEstimator:
    """A flow estimator by name: ``"dis"`` (DIS, medium preset) or ``"deepflow"``."""
    if method == "dis":
        return DISFlow("medium")
    if method == "deepflow":
        return DeepFlow()
    raise ValueError(f"flow method must be 'dis' or 'deepflow', got {method!r}")


def estimate_flow(
    image0: np.ndarray, image1: np.ndarray, method: FlowMethod = "dis"
) -> np.ndarray:
    """Forward flow from ``image0`` to ``image1``: (H, W, 3) uint8 RGB × 2 → (H, W, 2) float32."""
    return make_flow_estimator(method).estimate(image0, image1)


def flow_sequence(images: np.ndarray, estimator: FlowEstimator) -> np.ndarray:
    """Flow between each pair of consecutive images: (N, H, W, 3) → (N-1, H, W, 2) float32."""
    n, h, w = images.shape[:3]
    out = np.empty((max(n - 1, 0), h, w, 2), dtype=np.float32)
    for t in range(n - 1):
        out[t] = estimator.estimate(images[t], images[t + 1])
    return out
