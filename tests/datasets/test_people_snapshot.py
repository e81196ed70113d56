from __future__ import annotations

import os
import pickle
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from monoavatar.core.landmarks import MEDIAPIPE_LANDMARKS
from monoavatar.datasets import is_people_snapshot, read_people_snapshot, read_snapshot_camera
from monoavatar.io import (
    EmptyVideoError,
    FrameSelection,
    InputFormatError,
    InputNotFoundError,
    InputWarning,
    UnsafePickleError,
    read_frames,
)
from tests.io.media_helpers import frame_number, write_video

N, W, H = 8, 64, 48
F, C = (70.0, 72.0), (31.0, 23.5)


def _mask(k: int) -> np.ndarray:
    m = np.zeros((H, W), np.uint8)
    m[10:40, 4 * k : 4 * k + 12] = 255  # the person moves right by 4 px per frame
    return m


def _coco(k: int) -> np.ndarray:
    kp = np.zeros((18, 3))
    kp[0] = (10.0 + k, 20.0, 0.9)  # nose
    kp[1] = (11.0, 25.0, 0.8)  # neck (no mediapipe counterpart)
    kp[5] = (15.0, 26.0, 0.7)  # left shoulder
    kp[8] = (9.0, 35.0, 0.6)  # right hip
    return kp


def _write_sequence(folder: Path, distortion: np.ndarray | None = None, n_masks: int = N) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    write_video(folder / "subject.mp4", n=N, width=W, height=H)
    with h5py.File(folder / "masks.hdf5", "w") as fh:
        fh.create_dataset("masks", data=np.stack([_mask(k) for k in range(n_masks)]))
    with h5py.File(folder / "keypoints.hdf5", "w") as fh:
        fh.create_dataset("keypoints", data=np.stack([_coco(k).reshape(-1) for k in range(N)]))
    camera = {
        "camera_f": np.array(F), "camera_c": np.array(C),
        "camera_k": np.zeros(5) if distortion is None else distortion,
        "camera_t": np.zeros(3), "camera_rt": np.zeros(3), "width": W, "height": H,
    }
    (folder / "camera.pkl").write_bytes(pickle.dumps(camera, protocol=2))  # like Python 2
    return folder


def test_reads_a_sequence(tmp_path: Path) -> None:
    folder = _write_sequence(tmp_path / "male-1")
    assert is_people_snapshot(folder) and not is_people_snapshot(tmp_path)
    with pytest.raises(EmptyVideoError, match="read_people_snapshot"):
        read_frames(folder)  # a helpful pointer, not just "no image"
    seq = read_people_snapshot(folder)
    assert seq.frames.images.shape == (N, H, W, 3)
    assert [frame_number(im) for im in seq.frames.images] == list(range(N))
    np.testing.assert_allclose(seq.camera.K, [[70, 0, 31.5], [0, 72, 24.0], [0, 0, 1]])
    pre = seq.precomputed
    assert pre.masks is not None and pre.keypoints is not None
    assert pre.masks.dtype == bool
    for k in range(N):
        np.testing.assert_array_equal(pre.masks[k], _mask(k) > 0)
    nose = MEDIAPIPE_LANDMARKS.index("nose")
    shoulder = MEDIAPIPE_LANDMARKS.index("left_shoulder")
    hip = MEDIAPIPE_LANDMARKS.index("right_hip")
    np.testing.assert_allclose(pre.keypoints[3, nose], [13.5, 20.5, 0.9], rtol=1e-6)
    np.testing.assert_allclose(pre.keypoints[3, shoulder], [15.5, 26.5, 0.7], rtol=1e-6)
    np.testing.assert_allclose(pre.keypoints[3, hip], [9.5, 35.5, 0.6], rtol=1e-6)
    others = np.setdiff1d(np.arange(33), [nose, shoulder, hip])
    assert np.all(pre.keypoints[:, others] == 0)
    assert pre.keypoint_source == "people-snapshot-openpose-coco18"


def test_selection_keeps_masks_and_keypoints_aligned(tmp_path: Path) -> None:
    seq = read_people_snapshot(_write_sequence(tmp_path / "s"), FrameSelection(step=3))
    np.testing.assert_array_equal(seq.frames.indices, [0, 3, 6])
    assert [frame_number(im) for im in seq.frames.images] == [0, 3, 6]
    assert seq.precomputed.masks is not None and seq.precomputed.keypoints is not None
    for i, k in enumerate([0, 3, 6]):
        np.testing.assert_array_equal(seq.precomputed.masks[i], _mask(k) > 0)
        assert seq.precomputed.keypoints[i, 0, 0] == pytest.approx(10.5 + k)


def test_distortion_is_removed(tmp_path: Path) -> None:
    k = np.array([-0.25, 0.05, 0.001, -0.002, 0.0])
    folder = _write_sequence(tmp_path / "d", distortion=k)
    # store the nose where a distorted camera sees the undistorted pixel (20, 12)
    K_cv = np.array([[F[0], 0, C[0]], [0, F[1], C[1]], [0, 0, 1]])
    ideal = np.array([20.0, 12.0])
    ray = np.array([[(ideal[0] - C[0]) / F[0], (ideal[1] - C[1]) / F[1], 1.0]])
    seen, _ = cv2.projectPoints(ray, np.zeros(3), np.zeros(3), K_cv, k)
    with h5py.File(folder / "keypoints.hdf5", "r+") as fh:
        data = fh["keypoints"][...]
        data[:, 0:2] = seen.reshape(2)
        fh["keypoints"][...] = data
    seq = read_people_snapshot(folder)
    assert seq.precomputed.keypoints is not None and seq.precomputed.masks is not None
    np.testing.assert_allclose(seq.precomputed.keypoints[0, 0, :2], ideal + 0.5, atol=0.02)
    np.testing.assert_allclose(seq.distortion, k)
    assert not np.array_equal(seq.precomputed.masks[0], _mask(0) > 0)  # masks were remapped
    assert abs(int(seq.precomputed.masks[0].sum()) - int((_mask(0) > 0).sum())) < 120


def test_camera_pickle_is_restricted(tmp_path: Path) -> None:
    folder = _write_sequence(tmp_path / "evil")
    marker = tmp_path / "pwned"

    class Exploit:
        def __reduce__(self) -> tuple[object, tuple[str]]:
            return (os.system, (f"touch {marker}",))

    (folder / "camera.pkl").write_bytes(pickle.dumps({"camera_f": Exploit()}, protocol=2))
    with pytest.raises(UnsafePickleError, match=r"camera\.pkl"):
        read_people_snapshot(folder)
    assert not marker.exists()


def test_camera_pickle_validation(tmp_path: Path) -> None:
    path = tmp_path / "camera.pkl"
    path.write_bytes(pickle.dumps({"camera_f": np.ones(2), "width": 4, "height": 4}))
    with pytest.raises(InputFormatError, match=r"camera\.pkl: missing entries \['camera_c'\]"):
        read_snapshot_camera(path)
    path.write_bytes(pickle.dumps(
        {"camera_f": np.ones(3), "camera_c": np.ones(2), "width": 4, "height": 4}
    ))
    with pytest.raises(InputFormatError, match="'camera_f' must be 2 finite numbers"):
        read_snapshot_camera(path)
    path.write_bytes(pickle.dumps([1, 2]))
    with pytest.raises(InputFormatError, match="expected a pickled dict"):
        read_snapshot_camera(path)


def test_missing_and_inconsistent_files(tmp_path: Path) -> None:
    folder = _write_sequence(tmp_path / "a")
    (folder / "camera.pkl").unlink()
    with pytest.raises(InputNotFoundError, match=r"camera\.pkl: missing"):
        read_people_snapshot(folder)

    folder = _write_sequence(tmp_path / "b")
    with h5py.File(folder / "masks.hdf5", "w") as fh:
        fh.create_dataset("silhouettes", data=np.zeros((N, H, W), np.uint8))
    with pytest.raises(InputFormatError, match=r"masks\.hdf5: no dataset 'masks'"):
        read_people_snapshot(folder)

    folder = _write_sequence(tmp_path / "c")
    with h5py.File(folder / "masks.hdf5", "w") as fh:
        fh.create_dataset("masks", data=np.zeros((N, H, W + 2), np.uint8))
    with pytest.raises(InputFormatError,
                       match=r"masks have shape \(8, 48, 66\); expected \(N, 48, 64\)"):
        read_people_snapshot(folder)

    # a colour axis: named as such; a single-channel axis: accepted
    folder = _write_sequence(tmp_path / "rgb")
    with h5py.File(folder / "masks.hdf5", "w") as fh:
        fh.create_dataset("masks", data=np.stack([np.stack([_mask(k)] * 3, -1) for k in range(N)]))
    with pytest.raises(InputFormatError, match=r"\(8, 48, 64, 3\).*colour axis"):
        read_people_snapshot(folder)
    with h5py.File(folder / "masks.hdf5", "w") as fh:
        fh.create_dataset("masks", data=np.stack([_mask(k)[..., None] for k in range(N)]))
    assert read_people_snapshot(folder).precomputed.masks.shape == (N, H, W)

    folder = _write_sequence(tmp_path / "nan")
    with h5py.File(folder / "masks.hdf5", "w") as fh:
        fh.create_dataset("masks", data=np.full((N, H, W), np.nan, np.float32))
    with pytest.raises(InputFormatError, match=r"masks hold NaN"):
        read_people_snapshot(folder)

    folder = _write_sequence(tmp_path / "d")
    write_video(folder / "other.mp4", n=2)
    with pytest.raises(InputFormatError, match="exactly one video"):
        read_people_snapshot(folder)
    assert len(read_people_snapshot(folder, video=folder / "subject.mp4").frames) == N

    (folder / "masks.hdf5").write_bytes(b"not hdf5")
    with pytest.raises(InputFormatError, match=r"masks\.hdf5: not a readable HDF5"):
        read_people_snapshot(folder, video=folder / "subject.mp4")


def test_fewer_masks_than_frames(tmp_path: Path) -> None:
    folder = _write_sequence(tmp_path / "short", n_masks=5)
    with pytest.warns(InputWarning, match="holds 5 masks but subject.mp4 has 8 frames"):
        seq = read_people_snapshot(folder, FrameSelection(end_s=0.1))
    assert len(seq.frames) == 3
    with pytest.raises(InputFormatError, match=r"holds 5 entries but frame 7 is needed"):
        read_people_snapshot(folder)
