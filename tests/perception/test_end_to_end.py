"""A real video through reading and perception: rotation applied, landmarks on the person,
and the second run answered from the cache without making any detector."""

from __future__ import annotations

from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from monoavatar.io import FrameSelection, read_frames, resolve_camera
from monoavatar.perception import PerceptionSettings, perceive
from monoavatar.perception import pipeline as pipeline_module


def _portrait_video(path: Path, photo: np.ndarray, n: int = 4) -> None:
    """The photo panning slowly, stored sideways with a 'rotate 90° clockwise' display matrix,
    as a phone records portrait video."""
    size = 256
    base = cv2.resize(photo, (size, size), interpolation=cv2.INTER_AREA)
    container = av.open(str(path), "w")
    stream = container.add_stream("libx264", rate=30)
    stream.width, stream.height, stream.pix_fmt = size, size, "yuv420p"
    stream.options = {"crf": "12", "threads": "1"}
    stream.set_display_rotation(-90)
    for k in range(n):
        M = np.array([[1, 0, 2.0 * k], [0, 1, 0]], dtype=np.float64)
        shifted = cv2.warpAffine(base, M, (size, size), borderMode=cv2.BORDER_REFLECT)
        stored = np.ascontiguousarray(np.rot90(shifted, k=1))  # sensor orientation
        for packet in stream.encode(av.VideoFrame.from_ndarray(stored, format="rgb24")):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
    container.close()


def test_video_to_observations(tmp_path: Path, astronaut: np.ndarray,
                               monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "portrait.mp4"
    _portrait_video(path, astronaut)
    frames = read_frames(path, FrameSelection(step=1))
    assert frames.images.shape == (4, 256, 256, 3)
    camera = resolve_camera(frames.width, frames.height)
    settings = PerceptionSettings(flow="dis")
    obs = perceive(frames, camera, settings)
    assert not obs.no_person.any() and obs.face_found.all()
    nose, hips = obs.keypoints[:, 0], obs.keypoints[:, 23:25]
    assert np.all(nose[:, 1] < hips[:, :, 1].min(axis=1))  # upright: rotation was applied
    assert obs.masks.mean() > 0.3
    assert obs.flow is not None and obs.flow.shape == (3, 256, 256, 2)
    person = obs.masks[0, 40:220, 40:200]
    assert np.median(obs.flow[0, 40:220, 40:200][person][:, 0]) == pytest.approx(2.0, abs=0.3)

    def no_detectors(*args: object, **kwargs: object) -> None:
        raise AssertionError("perception ran again instead of using the cache")

    monkeypatch.setattr(pipeline_module, "default_detectors", no_detectors)
    monkeypatch.setattr(pipeline_module, "make_flow_estimator", no_detectors)
    again = perceive(read_frames(path), camera, settings)
    np.testing.assert_array_equal(again.masks, obs.masks)
    np.testing.assert_array_equal(again.keypoints, obs.keypoints)
    assert again.flow is not None
    np.testing.assert_array_equal(again.flow, obs.flow)
