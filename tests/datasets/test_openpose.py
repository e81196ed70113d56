from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from monoavatar.core.landmarks import (
    FACE68_TO_MEDIAPIPE468,
    MEDIAPIPE_LANDMARKS,
    OPENPOSE_BODY25,
    OPENPOSE_COCO18,
)
from monoavatar.datasets import read_openpose_folder
from monoavatar.io import EmptyVideoError, InputFormatError

MP = {name: i for i, name in enumerate(MEDIAPIPE_LANDMARKS)}


def _person(names: tuple[str, ...], offset: float = 0.0, face: bool = False,
            scale: float = 1.0) -> dict[str, list[float]]:
    """Joint j at (100 + 10 j, 50 + 5 j) * scale + offset with confidence 0.5 + j / 100; the
    neck missing (0, 0, 0)."""
    body = []
    for j, name in enumerate(names):
        if name == "neck":
            body += [0.0, 0.0, 0.0]
        else:
            body += [(100 + 10 * j) * scale + offset, (50 + 5 * j) * scale, 0.5 + j / 100]
    person: dict[str, list[float]] = {"pose_keypoints_2d": body, "face_keypoints_2d": []}
    if face:
        pts = []
        for i in range(70):
            pts += [200.0 + i, 30.0 + i / 2, 0.0 if i == 3 else 0.8]
        person["face_keypoints_2d"] = pts
    return person


def _write(folder: Path, frames: list[list[dict[str, list[float]]]]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for k, people in enumerate(frames):
        doc = {"version": 1.3, "people": people}
        (folder / f"video_{k:012d}_keypoints.json").write_text(json.dumps(doc))
    return folder


def test_body25_with_face(tmp_path: Path) -> None:
    folder = _write(tmp_path / "op", [[_person(OPENPOSE_BODY25, face=True)], []])
    pre = read_openpose_folder(folder)
    assert pre.keypoint_source == "openpose-body25"
    assert pre.keypoints is not None and pre.keypoints.shape == (2, 33, 3)
    kp = pre.keypoints[0]
    toes = {"left_big_toe": "left_foot_index", "right_big_toe": "right_foot_index"}
    mapped = set()
    for j, name in enumerate(OPENPOSE_BODY25):
        target = toes.get(name, name)
        if target in MP:
            mapped.add(MP[target])
            np.testing.assert_allclose(
                kp[MP[target]], [100 + 10 * j + 0.5, 50 + 5 * j + 0.5, 0.5 + j / 100], rtol=1e-6
            )
    assert len(mapped) == 21
    assert np.all(kp[sorted(set(range(33)) - mapped)] == 0)  # e.g. eye corners, hands
    assert np.all(pre.keypoints[1] == 0)  # no person in the second file
    # face: the 68 dlib points land on their mesh vertices, the rest is NaN
    assert pre.face is not None and pre.face.shape == (2, 468, 3)
    vertex = FACE68_TO_MEDIAPIPE468[10]
    np.testing.assert_allclose(pre.face[0, vertex], [210.5, 35.5, 0.8], rtol=1e-6)
    assert np.isnan(pre.face[0, FACE68_TO_MEDIAPIPE468[3]]).all()  # zero confidence
    assert np.isfinite(pre.face[0, :, 0]).sum() == 67
    assert np.isnan(pre.face[1]).all()


def test_coco18(tmp_path: Path) -> None:
    folder = _write(tmp_path / "op", [[_person(OPENPOSE_COCO18)]])
    pre = read_openpose_folder(folder)
    assert pre.keypoint_source == "openpose-coco18"
    assert pre.face is None
    assert pre.keypoints is not None
    j = OPENPOSE_COCO18.index("right_hip")
    np.testing.assert_allclose(pre.keypoints[0, MP["right_hip"], :2], [100 + 10 * j + 0.5,
                                                                      50 + 5 * j + 0.5])
    assert np.count_nonzero(pre.keypoints[0, :, 2]) == 17  # all but the neck


def test_most_central_largest_person_is_kept(tmp_path: Path) -> None:
    small = _person(OPENPOSE_BODY25, offset=1000.0, scale=0.5)
    big = _person(OPENPOSE_BODY25)
    folder = _write(tmp_path / "op", [[small, big], [big]])
    pre = read_openpose_folder(folder, image_size=(400, 700))
    assert pre.keypoints is not None and pre.multiple_people is not None
    assert pre.keypoints[0, MP["nose"], 0] == pytest.approx(100.5)
    np.testing.assert_array_equal(pre.multiple_people, [True, False])


def test_frame_indices_select_files(tmp_path: Path) -> None:
    frames = [[_person(OPENPOSE_COCO18, offset=k)] for k in range(5)]
    folder = _write(tmp_path / "op", frames)
    (folder / "camera.json").write_text("{}")  # other JSON files beside OpenPose's are ignored
    pre = read_openpose_folder(folder, frame_indices=[1, 4])
    assert pre.keypoints is not None
    np.testing.assert_allclose(pre.keypoints[:, MP["nose"], 0], [101.5, 104.5])
    with pytest.raises(InputFormatError, match="holds 5 OpenPose file.*frame index 7"):
        read_openpose_folder(folder, frame_indices=[0, 7])


def test_errors(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(EmptyVideoError, match="no OpenPose"):
        read_openpose_folder(tmp_path / "empty")
    bad = _write(tmp_path / "bad", [[{"pose_keypoints_2d": [1.0] * 30}]])
    with pytest.raises(InputFormatError, match=r"_keypoints\.json: pose_keypoints_2d has 30"):
        read_openpose_folder(bad)
    mixed = _write(tmp_path / "mixed", [[_person(OPENPOSE_COCO18)], [_person(OPENPOSE_BODY25)]])
    with pytest.raises(InputFormatError, match="mixed body formats"):
        read_openpose_folder(mixed)
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "a_keypoints.json").write_text("{not json")
    with pytest.raises(InputFormatError, match=r"a_keypoints\.json: not a readable OpenPose"):
        read_openpose_folder(broken)
    (broken / "a_keypoints.json").write_text('{"version": 1.3}')
    with pytest.raises(InputFormatError, match="no 'people' list"):
        read_openpose_folder(broken)
