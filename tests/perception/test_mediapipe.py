"""The mediapipe detectors on a real photograph (skimage's astronaut, NASA, public domain):
landmarks land on the person, the mask covers the person, and nothing is downloaded."""

from __future__ import annotations

import socket
import warnings

import cv2
import numpy as np
import pytest

from monoavatar.io import Frames
from monoavatar.perception import (
    MEDIAPIPE_LANDMARKS,
    MultiplePeopleWarning,
    NoPersonError,
    NoPersonWarning,
    Observations,
    PerceptionSettings,
    default_detectors,
    detect_face,
    perceive,
    perceive_image,
)
from monoavatar.perception.mediapipe_backend import MediaPipeFaceMesh, MediaPipePose

LM = {name: i for i, name in enumerate(MEDIAPIPE_LANDMARKS)}


def _inside(mask: np.ndarray, xy: np.ndarray) -> bool:
    col, row = int(np.floor(xy[0])), int(np.floor(xy[1]))
    return bool(0 <= row < mask.shape[0] and 0 <= col < mask.shape[1] and mask[row, col])


def test_landmarks_land_on_the_person(astronaut_observations: Observations) -> None:
    obs = astronaut_observations
    assert not obs.no_person[0] and not obs.multiple_people[0]
    kp, mask = obs.keypoints[0], obs.masks[0]
    for name in ("nose", "left_eye", "right_eye", "left_shoulder", "right_shoulder"):
        assert kp[LM[name], 2] > 0.9, name
        assert _inside(mask, kp[LM[name], :2]), name
    nose_y = kp[LM["nose"], 1]
    shoulders_y = kp[[LM["left_shoulder"], LM["right_shoulder"]], 1]
    hips_y = kp[[LM["left_hip"], LM["right_hip"]], 1]
    assert nose_y < shoulders_y.min() and shoulders_y.max() < hips_y.min()
    # facing the camera: the person's left is on the image's right, the nose between shoulders
    assert kp[LM["right_shoulder"], 0] < kp[LM["nose"], 0] < kp[LM["left_shoulder"], 0]
    assert kp[LM["right_eye"], 0] < kp[LM["left_eye"], 0]
    # the face in the photo: nose near (222, 128) px (checked by eye)
    np.testing.assert_allclose(kp[LM["nose"], :2], [222, 128], atol=15)


def test_confident_landmarks_lie_on_the_mask(astronaut_observations: Observations) -> None:
    """Every landmark mediapipe is sure of lies on the person's mask; the ones it guesses below
    the photo's edge (legs, hips, hands) are marked unsure."""
    kp, mask = astronaut_observations.keypoints[0], astronaut_observations.masks[0]
    h, w = mask.shape
    sure = kp[:, 2] > 0.5
    assert sure.sum() >= 12  # face, shoulders and more
    assert all(_inside(mask, xy) for xy in kp[sure, :2])
    outside = (kp[:, 0] < 0) | (kp[:, 0] >= w) | (kp[:, 1] < 0) | (kp[:, 1] >= h)
    assert outside.any() and np.all(kp[outside, 2] < 0.3)
    # the head's landmarks lie within the face region, between the shoulders
    head = kp[:11, :2]
    assert np.all((head[:, 0] > 170) & (head[:, 0] < 290) & (head[:, 1] > 70) & (head[:, 1] < 180))


def test_mask_covers_the_person(astronaut_observations: Observations) -> None:
    mask = astronaut_observations.masks[0]
    assert 0.30 < mask.mean() < 0.60
    # regions that are plainly the person (face, chest) and plainly background (flag, rocket)
    assert mask[90:170, 190:260].mean() > 0.97  # face
    assert mask[260:420, 110:300].mean() > 0.97  # chest and arms
    assert mask[0:60, 0:60].mean() < 0.02  # flag
    assert mask[0:200, 380:470].mean() < 0.02  # shuttle model
    count, _ = cv2.connectedComponents(mask.astype(np.uint8))
    assert count == 2  # one component (plus background)


def test_face_landmarks_on_the_face(astronaut_observations: Observations) -> None:
    obs = astronaut_observations
    assert obs.face_found[0]
    face = obs.face[0]
    assert np.isfinite(face).all() and np.all(face[:, 2] == 1.0)
    nose = obs.keypoints[0, LM["nose"], :2]
    assert np.linalg.norm(face[:, :2].mean(axis=0) - nose) < 20
    assert np.mean([_inside(obs.masks[0], p) for p in face[:, :2]]) > 0.98
    extent = np.ptp(face[:, :2], axis=0)
    assert 60 < extent[0] < 140 and 80 < extent[1] < 160  # a face-sized mesh


def test_face_found_on_a_small_person_through_the_head_crop(astronaut: np.ndarray) -> None:
    small = cv2.resize(astronaut, (128, 128), interpolation=cv2.INTER_AREA)
    canvas = np.full((512, 512, 3), 128, np.uint8)
    canvas[300:428, 200:328] = small
    with MediaPipeFaceMesh() as face, MediaPipePose() as pose:
        assert face.detect(canvas) == []  # too small for the face detector on the whole frame
        body = pose.detect(canvas)
        assert body is not None
        faces = detect_face(canvas, face, body.keypoints)
    assert len(faces) == 1
    centre = faces[0][:, :2].mean(axis=0)
    np.testing.assert_allclose(centre, [200 + 224 / 4, 300 + 124 / 4], atol=6)


def test_no_person(astronaut: np.ndarray) -> None:
    y, x = np.mgrid[:256, :256]
    gradient = np.stack([x, y, (x + y) // 2], axis=-1).astype(np.uint8)
    with MediaPipePose() as pose:
        assert pose.detect(gradient) is None
    with pytest.raises(NoPersonError, match="found in only 0 of 1"):
        perceive_image(gradient)


def test_frames_without_a_person_in_a_sequence(astronaut: np.ndarray) -> None:
    """Real detectors on frames where the person leaves: the frames without anybody are listed
    by index; too many of them stop perception."""
    photo = cv2.resize(astronaut, (256, 256), interpolation=cv2.INTER_AREA)
    y, x = np.mgrid[:256, :256]
    empty = np.stack([x, y, (x + y) // 2], axis=-1).astype(np.uint8)
    settings = PerceptionSettings(face=False)
    frames = Frames(np.stack([photo, empty, photo, photo, empty]), np.arange(5) / 5.0,
                    np.array([0, 5, 10, 15, 20]), fps=5.0)  # fmt: skip
    with pytest.warns(NoPersonWarning, match=r"no person found in 2 of 5 .*\[5, 20\]"):
        obs = perceive(frames, settings=settings, use_cache=False)
    np.testing.assert_array_equal(obs.no_person, [False, True, False, False, True])
    person = obs.masks[[0, 2, 3]].all(axis=0)
    assert person[45:85, 95:130].mean() > 0.97 and person[130:210, 55:150].mean() > 0.97
    mostly_empty = frames.subset([0, 1, 4])
    with pytest.raises(NoPersonError, match=r"found in only 1 of 3 .* frame\(s\) \[5, 20\]"):
        perceive(mostly_empty, settings=settings, use_cache=False)


def test_several_people_are_reported(astronaut: np.ndarray) -> None:
    scene = np.full((400, 800, 3), 200, np.uint8)
    scene[16:400, 300:684] = cv2.resize(astronaut, (384, 384), interpolation=cv2.INTER_AREA)
    scene[150:400, 20:270] = cv2.resize(astronaut, (250, 250), interpolation=cv2.INTER_AREA)
    with pytest.warns(MultiplePeopleWarning, match="most central and largest"):
        obs = perceive_image(scene)  # the default settings search for a second person
    assert obs.multiple_people[0]
    assert 300 < obs.keypoints[0, LM["nose"], 0] < 684  # the large, central subject
    assert obs.masks[0, :, :290].sum() == 0 and obs.masks[0, :, 300:].sum() > 50_000


def test_detectors_are_deterministic_and_reusable(astronaut: np.ndarray) -> None:
    with default_detectors() as dets:
        a = perceive_image(astronaut, detectors=dets)
        b = perceive_image(astronaut, detectors=dets)
    np.testing.assert_array_equal(a.keypoints, b.keypoints)
    np.testing.assert_array_equal(a.masks, b.masks)
    np.testing.assert_array_equal(a.face, b.face)


def test_selfie_segmenter_and_grabcut(astronaut: np.ndarray,
                                      astronaut_observations: Observations) -> None:
    settings = PerceptionSettings(segmenter="selfie", grabcut=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MultiplePeopleWarning)
        obs = perceive_image(astronaut, settings=settings)
    a, b = obs.masks[0], astronaut_observations.masks[0]
    assert (a & b).sum() / (a | b).sum() > 0.7
    assert a[90:170, 190:260].mean() > 0.97


def test_runs_offline(astronaut: np.ndarray, monkeypatch: pytest.MonkeyPatch) -> None:
    """Models come from the installed wheel: any network access fails the test."""

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("network access attempted")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    with MediaPipePose() as pose, MediaPipeFaceMesh() as face:
        assert pose.detect(astronaut) is not None
        assert len(face.detect(astronaut)) == 1


def test_bad_images_are_rejected() -> None:
    with MediaPipePose() as pose:
        with pytest.raises(ValueError, match=r"\(H, W, 3\) uint8 RGB"):
            pose.detect(np.zeros((10, 10), np.uint8))
    with pytest.raises(RuntimeError, match="closed"):
        pose.detect(np.zeros((10, 10, 3), np.uint8))


def test_mediapipe_detectors_satisfy_the_interfaces() -> None:
    from monoavatar.perception import FaceDetector, FlowEstimator, PersonSegmenter, PoseDetector
    from monoavatar.perception.mediapipe_backend import MediaPipeSelfieSegmenter

    with MediaPipePose() as pose, MediaPipeFaceMesh() as face, MediaPipeSelfieSegmenter() as seg:
        assert isinstance(pose, PoseDetector) and isinstance(face, FaceDetector)
        assert isinstance(seg, PersonSegmenter)
        assert "pose-full" in pose.name and "facemesh" in face.name and "selfie" in seg.name
    from monoavatar.perception import DISFlow

    assert isinstance(DISFlow(), FlowEstimator)


def test_head_crop_maps_back_exactly(astronaut: np.ndarray) -> None:
    """Face landmarks found on the resampled head crop agree with those found on the whole
    photo (a check of the crop's pixel-coordinate mapping)."""
    with MediaPipeFaceMesh() as face, MediaPipePose() as pose:
        whole = face.detect(astronaut)
        body = pose.detect(astronaut)
        assert body is not None and len(whole) == 1
        crop = detect_face(astronaut, face, body.keypoints, crop_size=256)
    assert len(crop) == 1
    offset = (crop[0][:, :2] - whole[0][:, :2]).mean(axis=0)
    np.testing.assert_allclose(offset, [0.0, 0.0], atol=1.0)
    assert np.median(np.linalg.norm(crop[0][:, :2] - whole[0][:, :2], axis=1)) < 2.5


def test_world_landmarks_are_metric_hip_centred_and_upright(
    astronaut_observations: Observations,
) -> None:
    world = astronaut_observations.world_keypoints
    assert world is not None and world.shape == (1, 33, 4)
    w = world[0]
    hips = 0.5 * (w[LM["left_hip"], :3] + w[LM["right_hip"], :3])
    np.testing.assert_allclose(hips, 0.0, atol=0.02)  # origin between the hips
    # metres, camera axes (y down): the shoulders 0.3-0.7 m above the hips, 0.25-0.5 m apart,
    # the person's left on the image's right as in the 2D landmarks
    left, right = w[LM["left_shoulder"], :3], w[LM["right_shoulder"], :3]
    assert 0.3 < -(0.5 * (left + right))[1] < 0.7
    assert 0.25 < np.linalg.norm(left - right) < 0.5 and left[0] > right[0]
