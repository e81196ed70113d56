from __future__ import annotations

import numpy as np
import pytest

from monoavatar.io import Frames, FrameSelection


def test_selection_all_by_default() -> None:
    np.testing.assert_array_equal(FrameSelection().select(np.arange(5) * 0.1), np.arange(5))


def test_selection_step_keyframes_and_range() -> None:
    times = np.arange(11) * 0.5  # 0 .. 5 s
    np.testing.assert_array_equal(FrameSelection(step=4).select(times), [0, 4, 8])
    np.testing.assert_array_equal(FrameSelection(num_keyframes=3).select(times), [0, 5, 10])
    np.testing.assert_array_equal(FrameSelection(num_keyframes=1).select(times), [0])
    np.testing.assert_array_equal(
        FrameSelection(start_s=1.0, end_s=2.0).select(times), [2, 3, 4]
    )
    np.testing.assert_array_equal(
        FrameSelection(start_s=1.0, end_s=3.0, step=2).select(times), [2, 4, 6]
    )
    np.testing.assert_array_equal(FrameSelection(end_s=0.0).select(times), [0])
    # an index range, then the time range and the key-frames within it
    np.testing.assert_array_equal(FrameSelection(first=3, stop=6).select(times), [3, 4, 5])
    np.testing.assert_array_equal(FrameSelection(first=8).select(times), [8, 9, 10])
    np.testing.assert_array_equal(FrameSelection(stop=2).select(times), [0, 1])
    np.testing.assert_array_equal(FrameSelection(first=2, stop=9, end_s=2.0).select(times),
                                  [2, 3, 4])  # fmt: skip
    np.testing.assert_array_equal(FrameSelection(first=2, num_keyframes=2).select(times),
                                  [2, 10])  # fmt: skip


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"step": 0}, "step must be an integer >= 1"),
        ({"step": 1.5}, "step must be an integer >= 1"),
        ({"num_keyframes": 0}, "num_keyframes must be an integer >= 1"),
        ({"num_keyframes": 3, "step": 2}, "either step or num_keyframes"),
        ({"start_s": -1.0}, "start_s must be finite and >= 0"),
        ({"end_s": float("nan")}, "end_s must be finite"),
        ({"start_s": 2.0, "end_s": 1.0}, "is before start_s"),
        ({"first": -1}, "first must be an integer >= 0"),
        ({"stop": 2.5}, "stop must be an integer >= 0"),
        ({"first": 4, "stop": 4}, "must be after first"),
    ],
)
def test_selection_rejects_bad_values(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        FrameSelection(**kwargs)  # type: ignore[arg-type]


def test_frames_from_images_and_properties() -> None:
    images = np.zeros((3, 4, 5, 3), np.uint8)
    frames = Frames.from_images(images, fps=10.0)
    assert len(frames) == 3 and frames.height == 4 and frames.width == 5
    np.testing.assert_allclose(frames.timestamps, [0.0, 0.1, 0.2])
    single = Frames.from_images(images[0])
    assert len(single) == 1 and np.isnan(single.timestamps[0]) and single.fps is None


def test_frames_validation() -> None:
    with pytest.raises(ValueError, match=r"\(N, H, W, 3\) uint8"):
        Frames.from_images(np.zeros((2, 4, 4, 3), np.float32))
    with pytest.raises(ValueError, match="2 images but 3 timestamps"):
        Frames(np.zeros((2, 4, 4, 3), np.uint8), np.zeros(3), np.arange(2))
    with pytest.raises(ValueError, match="strictly increasing"):
        Frames(np.zeros((2, 4, 4, 3), np.uint8), np.zeros(2), np.array([3, 1]))
    with pytest.raises(ValueError, match="fps"):
        Frames(np.zeros((1, 4, 4, 3), np.uint8), np.zeros(1), np.zeros(1), fps=0.0)


def test_digest_depends_on_content_and_indices() -> None:
    images = np.random.default_rng(0).integers(0, 255, (2, 6, 6, 3), dtype=np.uint8)
    a = Frames.from_images(images)
    assert a.digest == Frames.from_images(images.copy()).digest
    changed = images.copy()
    changed[1, 3, 3, 0] ^= 1
    assert a.digest != Frames.from_images(changed).digest
    shifted = Frames(images, np.zeros(2), np.array([0, 2]))
    assert a.digest != shifted.digest


def test_subset_and_resize() -> None:
    images = np.random.default_rng(0).integers(0, 255, (4, 40, 80, 3), dtype=np.uint8)
    frames = Frames.from_images(images, fps=5.0)
    sub = frames.subset([1, 3])
    np.testing.assert_array_equal(sub.indices, [1, 3])
    np.testing.assert_array_equal(sub.images, images[[1, 3]])
    small = frames.resized(40)
    assert small.images.shape == (4, 20, 40, 3)
    assert frames.resized(100) is frames
