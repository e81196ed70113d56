"""Reading People-Snapshot sequences (the layout of the original research code's inputs).

A sequence folder holds::

    <name>.mp4        the video
    masks.hdf5        dataset "masks": (N, H, W) person masks (0/1 or 0/255), one per frame
    keypoints.hdf5    dataset "keypoints": (N, 54) OpenPose COCO-18 x, y, confidence (optional)
    camera.pkl        a pickled dict: camera_f (2,) focal lengths px, camera_c (2,) principal
                      point px, camera_k (5,) OpenCV distortion (k1, k2, p1, p2, k3), width, height

``camera.pkl`` is read with a restricted unpickler (:mod:`monoavatar.io.safe_pickle`). Pixel
coordinates in these files put pixel centres at integers (OpenCV/OpenPose); they are shifted by
+0.5 px to our convention. When ``camera_k`` is not zero, images, masks and keypoints are
undistorted here, so that everything downstream is a plain pinhole camera with the same K.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from monoavatar.core.camera import CameraError, PinholeCamera
from monoavatar.core.errors import InputFormatError, InputNotFoundError, InputWarning
from monoavatar.core.landmarks import openpose_to_mediapipe_body
from monoavatar.core.safe_pickle import safe_load
from monoavatar.io.frames import Frames, FrameSelection
from monoavatar.io.video import VIDEO_EXTENSIONS, count_video_frames, read_video
from monoavatar.perception.observations import PrecomputedPerception


@dataclass(frozen=True)
class SnapshotCamera:
    """A People-Snapshot camera.

    Attributes:
        camera: the pinhole camera (our pixel convention; identity extrinsics).
        distortion: (5,) OpenCV distortion coefficients (k1, k2, p1, p2, k3) of the recording.
    """

    camera: PinholeCamera
    distortion: np.ndarray

    @property
    def distorted(self) -> bool:
        return bool(np.any(np.abs(self.distortion) > 1e-12))


@dataclass(frozen=True)
class PeopleSnapshot:
    """A People-Snapshot sequence, ready for :func:`~monoavatar.perception.pipeline.perceive`::

        seq = read_people_snapshot(folder)
        obs = perceive(seq.frames, seq.camera, precomputed=seq.precomputed)

    Attributes:
        frames: the selected video frames (undistorted when the camera has distortion).
        camera: pinhole camera of the (undistorted) frames.
        precomputed: the dataset's masks (N, H, W) and keypoints (N, 33, 3) (None when the
            folder has no ``keypoints.hdf5``), for the same frames.
        distortion: (5,) the recording's distortion coefficients (already removed).
    """

    frames: Frames
    camera: PinholeCamera
    precomputed: PrecomputedPerception
    distortion: np.ndarray


def is_people_snapshot(folder: str | Path) -> bool:
    """Whether ``folder`` has a People-Snapshot layout (``masks.hdf5`` and ``camera.pkl``)."""
    folder = Path(folder)
    return (folder / "masks.hdf5").is_file() and (folder / "camera.pkl").is_file()


def read_snapshot_camera(path: str | Path) -> SnapshotCamera:
    """Read a People-Snapshot ``camera.pkl`` (restricted unpickling, validated).

    Raises:
        InputNotFoundError, UnsafePickleError, InputFormatError (missing or malformed entries).
    """
    path = Path(path)
    data = safe_load(path)
    if not isinstance(data, dict):
        raise InputFormatError(path, f"expected a pickled dict, got {type(data).__name__}")
    required = ("camera_f", "camera_c", "width", "height")
    missing = [k for k in required if k not in data]
    if missing:
        raise InputFormatError(path, f"missing entries {missing} (has {sorted(map(str, data))})")

    def vector(key: str, size: int) -> np.ndarray:
        try:
            value = np.asarray(data[key], dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise InputFormatError(path, f"'{key}' is not numeric ({exc})") from exc
        if value.shape != (size,) or not np.all(np.isfinite(value)):
            raise InputFormatError(
                path, f"'{key}' must be {size} finite numbers, got {np.shape(data[key])}"
            )
        return value

    f = vector("camera_f", 2)
    c = vector("camera_c", 2)
    k = np.zeros(5)
    if data.get("camera_k") is not None:
        raw = np.asarray(data["camera_k"], dtype=np.float64).reshape(-1)
        if raw.size > 5 or not np.all(np.isfinite(raw)):
            raise InputFormatError(path, f"'camera_k' must be up to 5 numbers, got {raw.shape}")
        k[: raw.size] = raw
    try:
        width, height = int(data["width"]), int(data["height"])
        K = np.array([[f[0], 0.0, c[0] + 0.5], [0.0, f[1], c[1] + 0.5], [0.0, 0.0, 1.0]])
        camera = PinholeCamera(K=K, R=np.eye(3), t=np.zeros(3), width=width, height=height)
    except (TypeError, ValueError, CameraError) as exc:
        raise InputFormatError(path, f"invalid camera ({exc})") from exc
    return SnapshotCamera(camera=camera, distortion=k)


def _h5_dataset(path: Path, name: str, indices: np.ndarray) -> tuple[np.ndarray, int]:
    """Rows ``indices`` of dataset ``name`` and the dataset's length."""
    import h5py

    if not path.is_file():
        raise InputNotFoundError(path, "no such file")
    try:
        with h5py.File(path, "r") as fh:
            if name not in fh:
                raise InputFormatError(
                    path, f"no dataset '{name}' (has {sorted(fh.keys())})"
                )
            ds = fh[name]
            total = int(ds.shape[0]) if ds.ndim else 0
            if len(indices) and int(indices.max()) >= total:
                raise InputFormatError(
                    path, f"holds {total} entries but frame {int(indices.max())} is needed"
                )
            return np.asarray(ds[np.asarray(indices).tolist()]), total
    except OSError as exc:
        raise InputFormatError(path, f"not a readable HDF5 file ({exc})") from exc


def _undistort_points(points: np.ndarray, K_cv: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(M, 2) distorted pixel coordinates (centres at integers) → undistorted, same K."""
    if len(points) == 0:
        return points
    out = cv2.undistortPoints(points.reshape(-1, 1, 2).astype(np.float64), K_cv, k, P=K_cv)
    return np.asarray(out).reshape(-1, 2)


def read_people_snapshot(
    folder: str | Path,
    selection: FrameSelection | None = None,
    *,
    video: str | Path | None = None,
) -> PeopleSnapshot:
    """Read a People-Snapshot sequence folder.

    Args:
        folder: the sequence folder (see the module docstring for its files).
        selection: which frames to use (masks and keypoints follow the video's frame indices).
        video: the video file, when the folder holds several (default: its only video).
    Returns:
        PeopleSnapshot with frames, camera and precomputed masks and keypoints.
    Raises:
        InputNotFoundError (a missing file), InputFormatError (malformed files, or counts or
        sizes that disagree between the video, the masks and the camera), and the video
        reader's errors.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputNotFoundError(folder, "no such folder")
    if video is None:
        videos = sorted(
            p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_EXTENSIONS
        )
        if len(videos) != 1:
            raise InputFormatError(
                folder,
                f"expected exactly one video in a People-Snapshot folder, found "
                f"{[p.name for p in videos]}; pass video=...",
            )
        video = videos[0]
    video = Path(video)
    for name in ("masks.hdf5", "camera.pkl"):
        if not (folder / name).is_file():
            raise InputNotFoundError(folder / name, "missing from the People-Snapshot folder")
    snap = read_snapshot_camera(folder / "camera.pkl")
    camera = snap.camera

    frames = read_video(video, selection)
    total = count_video_frames(video)
    if (frames.width, frames.height) != (camera.width, camera.height):
        raise InputFormatError(
            folder / "camera.pkl",
            f"camera is for {camera.width}x{camera.height} images, {video.name} has "
            f"{frames.width}x{frames.height}",
        )
    masks, n_masks = _h5_dataset(folder / "masks.hdf5", "masks", frames.indices)
    if n_masks != total:
        warnings.warn(
            f"{folder / 'masks.hdf5'}: holds {n_masks} masks but {video.name} has {total} "
            "frames; assuming they start together",
            InputWarning,
            stacklevel=2,
        )
    if masks.ndim == 4 and masks.shape[3] == 1:  # a trailing channel axis of one
        masks = masks[..., 0]
    if masks.shape[1:] != (frames.height, frames.width):
        raise InputFormatError(
            folder / "masks.hdf5",
            f"masks have shape {tuple(masks.shape)}; expected (N, {frames.height}, "
            f"{frames.width}), one {frames.width}x{frames.height} mask per frame of "
            f"{video.name}" + (" (the masks have a colour axis: store one channel)"
                               if masks.ndim == 4 else ""),
        )  # fmt: skip
    if np.issubdtype(masks.dtype, np.floating) and not np.isfinite(masks).all():
        raise InputFormatError(folder / "masks.hdf5", "masks hold NaN or infinite values")
    masks = masks > 0

    keypoints = None
    source = "precomputed"
    if (folder / "keypoints.hdf5").is_file():
        raw, n_kp = _h5_dataset(folder / "keypoints.hdf5", "keypoints", frames.indices)
        if raw.reshape(len(raw), -1).shape[1] != 54:
            raise InputFormatError(
                folder / "keypoints.hdf5",
                f"expected (N, 54) COCO-18 keypoints, got {(n_kp, *raw.shape[1:])}",
            )
        body = raw.reshape(len(raw), 18, 3).astype(np.float64)
        if snap.distorted:
            K_cv = camera.K.copy()
            K_cv[:2, 2] -= 0.5
            seen = body[..., 2] > 0
            body[seen, :2] = _undistort_points(body[seen, :2], K_cv, snap.distortion)
        keypoints = openpose_to_mediapipe_body(body, "coco18")
        source = "people-snapshot-openpose-coco18"

    images = frames.images
    if snap.distorted:
        K_cv = camera.K.copy()
        K_cv[:2, 2] -= 0.5
        size = (camera.width, camera.height)
        map1, map2 = cv2.initUndistortRectifyMap(
            K_cv, snap.distortion, np.eye(3), K_cv, size, cv2.CV_32FC1
        )
        images = np.stack([cv2.remap(im, map1, map2, cv2.INTER_LINEAR) for im in images])
        masks = np.stack(
            [cv2.remap(m.astype(np.uint8), map1, map2, cv2.INTER_NEAREST) > 0 for m in masks]
        )
        frames = Frames(
            images=images, timestamps=frames.timestamps, indices=frames.indices,
            fps=frames.fps, source=frames.source,
        )
    return PeopleSnapshot(
        frames=frames,
        camera=camera,
        precomputed=PrecomputedPerception(keypoints=keypoints, masks=masks,
                                          keypoint_source=source),
        distortion=snap.distortion,
    )
