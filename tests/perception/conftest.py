"""Fixtures for the perception tests: an isolated cache, counting fake detectors, a photo."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from monoavatar.perception import Observations, perceive_image
from monoavatar.perception.interfaces import PoseResult


@pytest.fixture(autouse=True)
def isolated_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Every test gets its own cache folder (never ~/.cache)."""
    root = tmp_path / "cache"
    monkeypatch.setenv("MONOAVATAR_CACHE", str(root))
    return root


class FakePose:
    """Finds the bright pixels (> 128) of an image: the "person". Landmarks: the nose at the top
    of the brightest blob's bounding box, hips at its bottom, everything at the centre else;
    segmentation = bright pixels. Counts its calls."""

    def __init__(self, name: str = "fake-pose", with_mask: bool = True) -> None:
        self.calls = 0
        self._name = name
        self._with_mask = with_mask

    @property
    def name(self) -> str:
        return self._name

    def detect(self, image: np.ndarray) -> PoseResult | None:
        self.calls += 1
        bright = image.mean(axis=2) > 128
        if not bright.any():
            return None
        rows, cols = np.nonzero(bright)
        kp = np.zeros((33, 3), np.float32)
        kp[:, 0] = cols.mean() + 0.5
        kp[:, 1] = rows.mean() + 0.5
        kp[:, 2] = 0.9
        kp[0, 1] = rows.min() + 1.5  # nose near the top
        kp[23:25, 1] = rows.max() - 0.5  # hips near the bottom
        mask = bright.astype(np.float32) if self._with_mask else None
        return PoseResult(keypoints=kp, segmentation=mask)


class FakeSegmenter:
    """Bright pixels are people. Counts its calls."""

    name = "fake-segmenter"

    def __init__(self) -> None:
        self.calls = 0

    def segment(self, image: np.ndarray) -> np.ndarray:
        self.calls += 1
        return (image.mean(axis=2) > 128).astype(np.float32)


class FakeFace:
    """One face: a 468-point grid around the brightest region's top. Counts its calls."""

    name = "fake-face"

    def __init__(self) -> None:
        self.calls = 0

    def detect(self, image: np.ndarray) -> list[np.ndarray]:
        self.calls += 1
        bright = image.mean(axis=2) > 128
        if not bright.any():
            return []
        rows, cols = np.nonzero(bright)
        face = np.ones((468, 3), np.float32)
        face[:, 0] = cols.mean() + np.linspace(-2, 2, 468)
        face[:, 1] = rows.min() + 3.0
        return [face]


def blob_frames(n: int, size: int = 64, empty: tuple[int, ...] = ()) -> np.ndarray:
    """(n, size, size, 3) dark frames with a bright rectangle ("person") moving right by 1 px
    per frame; frames listed in ``empty`` are all dark."""
    images = np.full((n, size, size, 3), 20, np.uint8)
    for k in range(n):
        if k not in empty:
            images[k, 10:54, 20 + k : 36 + k] = 220
    return images


@pytest.fixture
def fakes() -> tuple[FakePose, FakeSegmenter, FakeFace]:
    return FakePose(), FakeSegmenter(), FakeFace()


@pytest.fixture(scope="session")
def astronaut() -> np.ndarray:
    """A real photograph of a person (NASA, public domain), shipped inside scikit-image."""
    from skimage import data

    return np.ascontiguousarray(data.astronaut())


@pytest.fixture(scope="session")
def astronaut_observations(astronaut: np.ndarray) -> Observations:
    """Mediapipe perception of the astronaut photo (run once per session, no cache)."""
    return perceive_image(astronaut)
