from __future__ import annotations

import math
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from monoavatar.core.camera import PinholeCamera
from monoavatar.io import Frames, default_camera
from monoavatar.perception import (
    Detectors,
    DISFlow,
    MultiplePeopleWarning,
    NoPersonError,
    NoPersonWarning,
    Observations,
    PerceptionSettings,
    PoseResult,
    PrecomputedPerception,
    perceive,
    perceive_image,
)
from tests.perception.conftest import FakeFace, FakePose, FakeSegmenter, blob_frames


def _entries(root: Path) -> list[Path]:
    folder = root / "perception"
    return sorted(folder.iterdir()) if folder.is_dir() else []


def test_result_shapes_and_content(fakes: tuple[FakePose, FakeSegmenter, FakeFace]) -> None:
    pose, _, face = fakes
    frames = Frames.from_images(blob_frames(4), fps=30.0)
    obs = perceive(frames, detectors=Detectors(pose=pose, face=face))
    assert obs.masks.shape == (4, 64, 64) and obs.masks.dtype == bool
    assert obs.keypoints.shape == (4, 33, 3) and obs.keypoints.dtype == np.float32
    assert obs.face.shape == (4, 468, 3)
    assert not obs.no_person.any() and not obs.multiple_people.any()
    assert obs.face_found.all()
    np.testing.assert_array_equal(obs.frame_indices, frames.indices)
    np.testing.assert_allclose(obs.timestamps, frames.timestamps)
    for k in range(4):
        expected = np.zeros((64, 64), bool)
        expected[10:54, 20 + k : 36 + k] = True
        np.testing.assert_array_equal(obs.masks[k], expected)
    assert obs.camera.K.tolist() == default_camera(64, 64).K.tolist()
    assert obs.keypoint_source == "fake-pose"
    assert obs.flow is None


def test_progress_bar_counts_the_frames(fakes: tuple[FakePose, FakeSegmenter, FakeFace],
                                        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    pose, _, face = fakes
    frames = Frames.from_images(blob_frames(5))
    perceive(frames, detectors=Detectors(pose=pose, face=face), use_cache=False, progress=True)
    err = capsys.readouterr().err
    assert "perception: 100%" in err and "5/5" in err
    perceive(frames, detectors=Detectors(pose=pose, face=face), use_cache=False)
    assert "perception" not in capsys.readouterr().err  # off by default


def test_second_run_skips_the_detectors(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace], isolated_cache: Path
) -> None:
    pose, _, face = fakes
    frames = Frames.from_images(blob_frames(3))
    first = perceive(frames, detectors=Detectors(pose=pose, face=face))
    assert pose.calls == 6 and face.calls == 3  # pose twice a frame: the second-person search
    entries = _entries(isolated_cache)
    assert len(entries) == 1 and entries[0].suffix == ".npz"
    # same content, new objects: the cache is keyed by content, not identity
    again = perceive(Frames.from_images(blob_frames(3)), detectors=Detectors(pose=pose, face=face))
    assert pose.calls == 6 and face.calls == 3
    np.testing.assert_array_equal(again.masks, first.masks)
    np.testing.assert_array_equal(again.keypoints, first.keypoints)
    np.testing.assert_array_equal(again.face, first.face)
    # the camera is attached, not cached
    cam = PinholeCamera.from_focal(99.0, 64, 64)
    assert perceive(frames, cam, detectors=Detectors(pose=pose, face=face)).camera is cam
    assert pose.calls == 6


def test_cache_key_covers_settings_content_and_detectors(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace], isolated_cache: Path
) -> None:
    pose, _, face = fakes
    dets = Detectors(pose=pose, face=face)
    frames = Frames.from_images(blob_frames(2))
    perceive(frames, detectors=dets)
    perceive(frames, settings=PerceptionSettings(mask_threshold=0.6), detectors=dets)
    assert pose.calls == 8
    changed = blob_frames(2)
    changed[1, 0, 0, 0] += 1
    perceive(Frames.from_images(changed), detectors=dets)
    assert pose.calls == 12
    other = FakePose(name="fake-pose-v2")
    perceive(frames, detectors=Detectors(pose=other, face=face))
    assert other.calls == 4
    assert len(_entries(isolated_cache)) == 4
    perceive(frames, detectors=dets, use_cache=False)
    assert pose.calls == 16 and len(_entries(isolated_cache)) == 4


def test_cache_location(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace], isolated_cache: Path, tmp_path: Path
) -> None:
    pose, _, _ = fakes
    frames = Frames.from_images(blob_frames(1))
    perceive(frames, detectors=Detectors(pose=pose))
    assert len(_entries(isolated_cache)) == 1
    perceive(frames, detectors=Detectors(pose=pose), cache_dir=tmp_path / "elsewhere")
    assert pose.calls == 4
    assert len(_entries(tmp_path / "elsewhere")) == 1


def test_damaged_cache_entry_is_recomputed(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace], isolated_cache: Path
) -> None:
    pose, _, _ = fakes
    frames = Frames.from_images(blob_frames(2))
    first = perceive(frames, detectors=Detectors(pose=pose))
    (entry,) = _entries(isolated_cache)
    entry.write_bytes(entry.read_bytes()[:100])  # e.g. a disk filled up by another program
    with pytest.warns(UserWarning, match="ignoring unreadable cache entry"):
        again = perceive(frames, detectors=Detectors(pose=pose))
    assert pose.calls == 8
    np.testing.assert_array_equal(again.masks, first.masks)
    Observations.load(entry)  # rewritten whole
    assert [p.name for p in entry.parent.iterdir() if p.name.endswith(".tmp")] == []


class CrashingPose(FakePose):
    """Fails on its third call (a detector error half-way through a sequence)."""

    def detect(self, image: np.ndarray) -> PoseResult | None:
        if self.calls == 2:
            raise RuntimeError("detector crashed")
        return super().detect(image)


def test_a_failure_half_way_writes_nothing(isolated_cache: Path) -> None:
    frames = Frames.from_images(blob_frames(4))
    with pytest.raises(RuntimeError, match="detector crashed"):
        perceive(frames, detectors=Detectors(pose=CrashingPose()))
    assert [p for p in isolated_cache.rglob("*") if p.is_file()] == []
    obs = perceive(frames, detectors=Detectors(pose=FakePose()))  # and nothing stale is read
    assert not obs.no_person.any()


def test_frames_without_a_person_are_listed(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace],
) -> None:
    pose, _, face = fakes
    images = blob_frames(5, empty=(1, 3))
    frames = Frames(images, np.arange(5) / 10.0, np.array([0, 10, 20, 30, 40]))
    with pytest.warns(NoPersonWarning, match=r"no person found in 2 of 5 .*\[10, 30\]"):
        obs = perceive(frames, detectors=Detectors(pose=pose, face=face))
    np.testing.assert_array_equal(obs.no_person, [False, True, False, True, False])
    np.testing.assert_array_equal(obs.person_frames, [0, 2, 4])
    assert not obs.masks[[1, 3]].any()
    assert obs.masks[[0, 2, 4]].any(axis=(1, 2)).all()
    assert np.all(obs.keypoints[[1, 3]] == 0) and np.isnan(obs.face[[1, 3]]).all()


def test_too_few_frames_with_a_small_person_say_it_is_small(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace],
) -> None:
    pose, _, _ = fakes
    images = np.full((4, 64, 64, 3), 20, np.uint8)
    images[0, 30:40, 30:36] = 220  # a distant person, 10 of 64 rows tall, in one frame
    with pytest.raises(NoPersonError, match=r"spans only 16 % of the image height.*film closer"):
        perceive(Frames.from_images(images), detectors=Detectors(pose=pose))
    with pytest.raises(NoPersonError) as e:  # a person of ordinary size: no such hint
        ordinary = Frames.from_images(blob_frames(4, empty=(0, 1, 2)))
        perceive(ordinary, detectors=Detectors(pose=pose))
    assert "image height" not in str(e.value)


def test_too_few_frames_with_a_person_stop(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace],
) -> None:
    pose, _, _ = fakes
    frames = Frames.from_images(blob_frames(4, empty=(0, 1, 2)))
    with pytest.raises(NoPersonError, match=r"found in only 1 of 4 frame\(s\), at least 2") as e:
        perceive(frames, detectors=Detectors(pose=pose))
    assert e.value.frames == [0, 1, 2] and e.value.required == 2
    # a lower threshold continues, with a warning
    with pytest.warns(NoPersonWarning):
        obs = perceive(
            frames, settings=PerceptionSettings(min_person_fraction=0.25),
            detectors=Detectors(pose=pose),
        )
    assert obs.no_person.sum() == 3
    # the decision is taken again on a cached result
    with pytest.raises(NoPersonError):
        perceive(frames, detectors=Detectors(pose=pose))
    # nobody anywhere always stops
    with pytest.raises(NoPersonError, match="found in only 0 of 2"):
        perceive(
            Frames.from_images(blob_frames(2, empty=(0, 1))),
            settings=PerceptionSettings(min_person_fraction=0.0),
            detectors=Detectors(pose=pose),
        )


class LeftmostPose(FakePose):
    """A detector that finds the bright blob furthest left (not the most central one): its
    landmarks spread over the blob's bounding box, its mask (when asked) that blob only."""

    def detect(self, image: np.ndarray) -> PoseResult | None:
        self.calls += 1
        bright = (image.mean(axis=2) > 128).astype(np.uint8)
        count, labels, stats, _ = cv2.connectedComponentsWithStats(bright)
        if count <= 1:
            return None
        blob = 1 + int(np.argmin(stats[1:, cv2.CC_STAT_LEFT]))
        x, y, w, h = stats[blob, :4]
        kp = np.zeros((33, 3), np.float32)
        kp[:, 0] = x + 0.5 + (w - 1) * (np.arange(33) % 2)  # left and right edges
        kp[:, 1] = y + 0.5 + (h - 1) * np.linspace(0, 1, 33)
        kp[:, 2] = 0.9
        mask = (labels == blob).astype(np.float32) if self._with_mask else None
        return PoseResult(keypoints=kp, segmentation=mask)


def test_several_people_keep_the_central_largest() -> None:
    images = np.full((1, 80, 120, 3), 20, np.uint8)
    images[0, 10:75, 50:80] = 220  # the subject, central and large
    images[0, 25:65, 2:16] = 220  # a bystander at the left edge
    pose, face = LeftmostPose(with_mask=False), FakeFace()
    dets = Detectors(pose=pose, segmenter=FakeSegmenter(), face=face)
    with pytest.warns(MultiplePeopleWarning, match=r"several people in 1 frame.*\[0\]"):
        obs = perceive(Frames.from_images(images), detectors=dets)
    assert obs.multiple_people[0]
    assert obs.masks[0, 40, 60] and not obs.masks[0, 40, 8]
    assert obs.masks[0].sum() == 65 * 30
    # the detector first found the bystander; it ran again with the bystander hidden
    assert pose.calls == 2
    assert 50 <= obs.keypoints[0, 0, 0] <= 80


class DropoutSegmenter(FakeSegmenter):
    """Bright pixels are people, except that on its third call the lower legs drop out (a
    segmentation flicker: the image itself is unchanged)."""

    def segment(self, image: np.ndarray) -> np.ndarray:
        prob = super().segment(image)
        if self.calls == 3:
            prob[40:54] = 0.0
        return prob


def test_temporal_smoothing_removes_flicker(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace],
) -> None:
    pose, _, _ = fakes
    frames = Frames.from_images(blob_frames(5))  # the person moves 1 px (2 % of its height)
    smooth = perceive(frames, detectors=Detectors(pose=pose, segmenter=DropoutSegmenter()))
    assert smooth.masks[2, 40:54, 24:36].all()
    # (GrabCut off: it would grow the cut-off legs back by its band from the image's edges)
    raw = perceive(frames, settings=PerceptionSettings(temporal_sigma=0.0, grabcut=False),
                   detectors=Detectors(pose=pose, segmenter=DropoutSegmenter()))
    assert not raw.masks[2, 40:54].any()
    # key-frames far apart in the source are not mixed
    far = Frames(frames.images, np.zeros(5), np.arange(5) * 100)
    sparse = perceive(far, settings=PerceptionSettings(grabcut=False),
                      detectors=Detectors(pose=pose, segmenter=DropoutSegmenter()))
    assert not sparse.masks[2, 40:54].any()


class WideSegmenter(FakeSegmenter):
    """Bright pixels are people, and the 3 px around them too (a segmentation network's
    mask that reaches past the outline)."""

    def segment(self, image: np.ndarray) -> np.ndarray:
        prob = super().segment(image)
        return cv2.dilate(prob, np.ones((7, 7), np.uint8))


def test_grabcut_by_default_brings_a_wide_mask_back_to_the_outline(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace],
) -> None:
    pose, _, _ = fakes
    rng = np.random.default_rng(0)
    images = blob_frames(3).astype(np.int16)
    images = np.clip(images + rng.integers(-15, 16, images.shape), 0, 255).astype(np.uint8)
    frames = Frames.from_images(images)
    truth = blob_frames(3).mean(axis=3) > 128
    wide = perceive(frames, settings=PerceptionSettings(grabcut=False),
                    detectors=Detectors(pose=pose, segmenter=WideSegmenter()))
    assert wide.masks.sum() > 1.3 * truth.sum()  # the dilated mask as it came
    refined = perceive(frames, detectors=Detectors(pose=pose, segmenter=WideSegmenter()))
    assert PerceptionSettings().grabcut
    np.testing.assert_array_equal(refined.masks, truth)


def test_temporal_smoothing_skips_frames_with_motion(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace],
) -> None:
    """A person moving fast (here 12 px per frame, 28 % of their height) is not smoothed: mixing
    would cut their moving edges off. Without the motion gate, it would."""
    pose, segmenter, _ = fakes
    images = np.full((4, 64, 64, 3), 20, np.uint8)
    for k in range(4):
        images[k, 10:54, 8 + 12 * k : 24 + 12 * k] = 220
    frames = Frames.from_images(images)
    obs = perceive(frames, detectors=Detectors(pose=pose, segmenter=segmenter))
    np.testing.assert_array_equal(obs.masks, images.mean(axis=3) > 128)
    with pytest.warns(MultiplePeopleWarning):  # mixing even splits the moving person in two
        ungated = perceive(frames, settings=PerceptionSettings(temporal_max_motion=math.inf,
                                                               grabcut=False),
                           detectors=Detectors(pose=pose, segmenter=segmenter))
    assert ungated.masks[1].sum() < obs.masks[1].sum()
    with pytest.raises(ValueError, match="temporal_max_motion must be >= 0"):
        PerceptionSettings(temporal_max_motion=-1.0)


def test_separate_segmenter_is_used(fakes: tuple[FakePose, FakeSegmenter, FakeFace]) -> None:
    _, segmenter, _ = fakes
    pose = FakePose(with_mask=False)
    obs = perceive(Frames.from_images(blob_frames(2)),
                   detectors=Detectors(pose=pose, segmenter=segmenter))
    assert segmenter.calls == 2 and obs.masks.any(axis=(1, 2)).all()
    with pytest.raises(ValueError, match="needs a pose detector"):
        perceive(Frames.from_images(blob_frames(1)), detectors=Detectors(face=FakeFace()))


def test_precomputed_inputs_replace_detectors(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace],
) -> None:
    pose, _, face = fakes
    frames = Frames.from_images(blob_frames(3))
    keypoints = np.zeros((3, 33, 3), np.float32)
    keypoints[:, 0] = (28.0, 12.0, 0.8)
    keypoints[1] = 0.0  # OpenPose saw nobody in frame 1
    masks = blob_frames(3)[..., 0] > 128
    pre = PrecomputedPerception(keypoints=keypoints, masks=masks, keypoint_source="openpose-x")
    with pytest.warns(NoPersonWarning, match=r"\[1\]"):
        obs = perceive(frames, precomputed=pre, detectors=Detectors(pose=pose, face=face))
    assert pose.calls == 0 and face.calls == 2
    assert obs.keypoint_source == "openpose-x"
    np.testing.assert_array_equal(obs.keypoints[[0, 2]], keypoints[[0, 2]])
    np.testing.assert_array_equal(obs.masks[[0, 2]], masks[[0, 2]])
    np.testing.assert_array_equal(obs.no_person, [False, True, False])
    face_given = np.full((3, 468, 3), np.nan, np.float32)
    face_given[:, 5] = (1.0, 2.0, 0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NoPersonWarning)
        with_face = perceive(
            frames,
            precomputed=PrecomputedPerception(keypoints=keypoints, masks=masks, face=face_given),
            detectors=Detectors(pose=pose, face=face),
        )
    assert face.calls == 2
    np.testing.assert_array_equal(with_face.face[0, 5], [1.0, 2.0, 0.5])
    with pytest.raises(ValueError, match=r"precomputed masks must have shape \(3, 64, 64\)"):
        perceive(frames, precomputed=PrecomputedPerception(masks=masks[:2]))


def test_flow_is_computed_and_cached_separately(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace], isolated_cache: Path
) -> None:
    pose, _, _ = fakes

    class CountingFlow(DISFlow):
        calls = 0

        def estimate(self, image0: np.ndarray, image1: np.ndarray) -> np.ndarray:
            CountingFlow.calls += 1
            return super().estimate(image0, image1)

    images = blob_frames(4)
    texture = np.random.default_rng(0).integers(130, 256, (44, 16, 1), dtype=np.uint8)
    texture = cv2.GaussianBlur(np.repeat(texture, 3, axis=2), (0, 0), 1.0)
    for k in range(4):
        images[k, 10:54, 20 + k : 36 + k] = texture  # a textured person moving right 1 px
    frames = Frames.from_images(images)
    perceive(frames, detectors=Detectors(pose=pose))
    flow_settings = PerceptionSettings(flow="dis")
    obs = perceive(frames, settings=flow_settings,
                   detectors=Detectors(pose=pose, flow=CountingFlow()))
    assert pose.calls == 8  # perception came from the cache; only flow ran
    assert CountingFlow.calls == 3
    assert obs.flow is not None and obs.flow.shape == (3, 64, 64, 2)
    # the blob moves right by one pixel per frame
    assert np.median(obs.flow[:, 14:50, 24:34, 0]) == pytest.approx(1.0, abs=0.1)
    assert np.median(obs.flow[:, 14:50, 24:34, 1]) == pytest.approx(0.0, abs=0.1)
    again = perceive(frames, settings=flow_settings,
                     detectors=Detectors(pose=pose, flow=CountingFlow()))
    assert CountingFlow.calls == 3
    assert again.flow is not None
    np.testing.assert_array_equal(again.flow, obs.flow)
    single = perceive(Frames.from_images(blob_frames(1)), settings=flow_settings,
                      detectors=Detectors(pose=pose))
    assert single.flow is not None and single.flow.shape == (0, 64, 64, 2)


def test_inputs_are_validated(fakes: tuple[FakePose, FakeSegmenter, FakeFace]) -> None:
    pose, _, _ = fakes
    frames = Frames.from_images(blob_frames(1))
    with pytest.raises(ValueError, match="camera is for 32x32 images, frames are 64x64"):
        perceive(frames, PinholeCamera.from_focal(10.0, 32, 32), detectors=Detectors(pose=pose))
    with pytest.raises(ValueError, match="no frames"):
        perceive(Frames.from_images(np.zeros((0, 4, 4, 3), np.uint8)))
    with pytest.raises(ValueError, match="segmenter must be"):
        PerceptionSettings(segmenter="sam")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"mask_threshold must be in \(0, 1\)"):
        PerceptionSettings(mask_threshold=1.0)
    with pytest.raises(TypeError):
        PerceptionSettings(mask_treshold=0.4)  # type: ignore[call-arg]


def test_perceive_image(fakes: tuple[FakePose, FakeSegmenter, FakeFace],
                        isolated_cache: Path) -> None:
    pose, _, _ = fakes
    obs = perceive_image(blob_frames(1)[0], detectors=Detectors(pose=pose))
    assert len(obs) == 1 and obs.masks[0].sum() == 44 * 16
    assert _entries(isolated_cache) == []  # no cache for single images by default


def test_observations_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    face = np.full((2, 468, 3), np.nan, np.float32)
    face[1, :10] = rng.random((10, 3))
    obs = Observations(
        masks=rng.random((2, 5, 7)) > 0.5,
        keypoints=rng.random((2, 33, 3)).astype(np.float32),
        face=face,
        no_person=np.array([True, False]),
        multiple_people=np.array([False, True]),
        camera=PinholeCamera.from_focal(10.0, 7, 5),
        frame_indices=np.array([3, 9]),
        timestamps=np.array([0.1, 0.3]),
        flow=rng.random((1, 5, 7, 2)).astype(np.float32),
        keypoint_source="test",
        world_keypoints=np.where(np.arange(2)[:, None, None] == 0, np.nan,
                                 rng.random((2, 33, 4))).astype(np.float32),
    )
    path = tmp_path / "obs.npz"
    obs.save(path)
    back = Observations.load(path)
    for name in ("masks", "keypoints", "face", "no_person", "multiple_people",
                 "frame_indices", "timestamps", "flow", "world_keypoints"):
        np.testing.assert_array_equal(getattr(back, name), getattr(obs, name))
    np.testing.assert_array_equal(back.camera.K, obs.camera.K)
    assert back.keypoint_source == "test" and back.image_size == (5, 7)
    np.testing.assert_array_equal(back.face_found, [False, True])
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(ValueError, match=r"junk\.npz: not an observations file"):
        Observations.load(tmp_path / "junk.npz")


def test_observations_validation() -> None:
    cam = PinholeCamera.from_focal(10.0, 7, 5)
    good = {
        "masks": np.zeros((2, 5, 7), bool),
        "keypoints": np.zeros((2, 33, 3)),
        "face": np.zeros((2, 468, 3)),
        "no_person": np.zeros(2, bool),
        "multiple_people": np.zeros(2, bool),
        "camera": cam,
        "frame_indices": np.arange(2),
        "timestamps": np.zeros(2),
    }
    Observations(**good)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"keypoints must have shape \(2, 33, 3\)"):
        Observations(**{**good, "keypoints": np.zeros((2, 18, 3))})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="camera is for 7x5 images, masks are 8x5"):
        Observations(**{**good, "masks": np.zeros((2, 5, 8), bool)})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"flow must have shape \(1, 5, 7, 2\)"):
        Observations(**{**good, "flow": np.zeros((2, 5, 7, 2))})  # type: ignore[arg-type]


def test_a_second_detection_over_the_hidden_person_is_no_second_person() -> None:
    """With the subject painted over, a detector may find a large "person" in the paint and
    the background clutter around it (e.g. over synth's clutter backgrounds): its region takes in
    the subject's, so it is not counted; a detection beside the subject is."""
    from monoavatar.perception.interfaces import PoseResult
    from monoavatar.perception.people import second_person

    h, w = 80, 120
    image = np.full((h, w, 3), 20, np.uint8)
    first_mask = np.zeros((h, w), np.float32)
    first_mask[30:60, 50:60] = 1.0  # 300 px
    keypoints = np.zeros((33, 3), np.float32)
    keypoints[:, :2] = (55, 45)
    keypoints[:, 2] = 1.0
    first = PoseResult(keypoints, first_mask)

    class Once:
        def __init__(self, mask: np.ndarray, at: tuple[float, float]) -> None:
            kp = np.zeros((33, 3), np.float32)
            kp[:, :2], kp[:, 2] = at, 1.0
            self.result = PoseResult(kp, mask)

        def detect(self, image: np.ndarray) -> PoseResult:
            return self.result

    settings = PerceptionSettings(check_several_people=True)
    engulfing = np.zeros((h, w), np.float32)
    engulfing[5:75, 20:110] = 1.0  # 6300 px, the subject's 300 inside: 5 % of it
    kept, found = second_person(image, first, Once(engulfing, (25, 10)), settings, 50)  # type: ignore[arg-type]
    assert kept is first and not found
    beside = np.zeros((h, w), np.float32)
    beside[30:62, 80:92] = 1.0  # 384 px, no overlap
    kept, found = second_person(image, first, Once(beside, (86, 46)), settings, 50)  # type: ignore[arg-type]
    assert found


def test_second_person_search_keeps_the_central_largest() -> None:
    images = np.full((1, 80, 120, 3), 20, np.uint8)
    images[0, 10:75, 50:80] = 220  # the subject
    images[0, 25:65, 2:16] = 220  # a bystander the detector finds first
    pose = LeftmostPose(with_mask=False)  # landmarks only: the region is their hull
    settings = PerceptionSettings(check_several_people=True)
    with pytest.warns(MultiplePeopleWarning):
        obs = perceive(Frames.from_images(images), settings=settings,
                       detectors=Detectors(pose=pose, segmenter=FakeSegmenter()))
    assert obs.multiple_people[0]
    assert 50 <= obs.keypoints[0, 0, 0] <= 80  # the subject's landmarks were kept
    assert obs.masks[0, 40, 60] and not obs.masks[0, 40, 8]
    # one person: the second search finds nobody and nothing is reported
    alone = images.copy()
    alone[0, :, :20] = 20
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        obs = perceive(Frames.from_images(alone), settings=settings,
                       detectors=Detectors(pose=FakePose()))
    assert not obs.multiple_people[0]


def test_each_mask_waits_for_the_frames_its_smoothing_reads() -> None:
    from monoavatar.perception.pipeline import _reach

    # source indices 0 1 2 5 6 10, sigma 1: frame 0 reads up to index 3 (frame 2), ...
    np.testing.assert_array_equal(_reach(np.array([0, 1, 2, 5, 6, 10]), 1.0), [2, 2, 3, 4, 4, 5])
    np.testing.assert_array_equal(_reach(np.array([0, 4, 8]), 0.0), [0, 1, 2])


def test_the_masks_do_not_depend_on_the_worker_threads(
    fakes: tuple[FakePose, FakeSegmenter, FakeFace],
) -> None:
    pose, _, _ = fakes
    rng = np.random.default_rng(1)
    images = blob_frames(6).astype(np.int16)
    images = np.clip(images + rng.integers(-20, 21, images.shape), 0, 255).astype(np.uint8)
    frames = Frames.from_images(images)
    one, three = (perceive(frames, use_cache=False, workers=w,
                           detectors=Detectors(pose=pose, segmenter=WideSegmenter()))
                  for w in (1, 3))  # fmt: skip
    assert one.masks.any()
    np.testing.assert_array_equal(one.masks, three.masks)
    np.testing.assert_array_equal(one.keypoints, three.keypoints)
