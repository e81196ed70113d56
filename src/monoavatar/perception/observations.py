"""``Observations``: what perception hands to fitting.

Conventions: pixel coordinates (x right, y down) with the origin at the top-left corner of the
top-left pixel, so the centre of pixel (col, row) is at (col + 0.5, row + 0.5); landmarks may
lie outside the image (predicted but cut off). Confidences are in [0, 1]; a landmark with
confidence 0 is absent and its x, y are meaningless (0).
"""

from __future__ import annotations

import hashlib
import io
import json
import pickle
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from monoavatar.core.camera import PinholeCamera
from monoavatar.core.files import atomic_write_bytes
from monoavatar.core.landmarks import NUM_BODY_LANDMARKS, NUM_FACE_LANDMARKS

_FORMAT_VERSION = 1


@dataclass(frozen=True)
class Observations:
    """Per-frame person masks, body and face landmarks, and optionally optical flow.

    Attributes:
        masks: (N, H, W) bool, True on the person.
        keypoints: (N, 33, 3) float32 body landmarks in mediapipe's order
            (:data:`~monoavatar.core.landmarks.MEDIAPIPE_LANDMARKS`): x px, y px,
            confidence (mediapipe's visibility, or OpenPose's confidence).
        face: (N, 468, 3) float32 face-mesh landmarks: x px, y px, confidence; rows are NaN
            where the landmark is absent (no face found, or a vertex a converted format lacks).
        no_person: (N,) bool, True for frames where no person was found; their masks are empty,
            keypoint confidences 0 and face rows NaN.
        multiple_people: (N,) bool, True for frames where several people were seen (the most
            central and largest was kept).
        camera: the camera the frames were taken with.
        frame_indices: (N,) int64 index of each frame in its source (see ``Frames.indices``).
        timestamps: (N,) float64 seconds (NaN when unknown).
        flow: (N-1, H, W, 2) float32 forward optical flow in pixels, or None: the content at
            pixel centre p of frame t is at p + flow[t, row, col] in frame t+1.
        world_keypoints: (N, 33, 4) float32 or None: the detector's metric 3D body landmarks
            (mediapipe's world landmarks) x, y, z metres relative to the midpoint of the hips,
            in the camera's axes (x right, y down, z forward), and their confidence; NaN rows
            where absent.
        keypoint_source: what produced the keypoints, e.g. ``"mediapipe-pose"``,
            ``"openpose-coco18"`` (joint definitions differ slightly between detectors, e.g.
            the hips).
    """

    masks: np.ndarray
    keypoints: np.ndarray
    face: np.ndarray
    no_person: np.ndarray
    multiple_people: np.ndarray
    camera: PinholeCamera
    frame_indices: np.ndarray
    timestamps: np.ndarray
    flow: np.ndarray | None = None
    keypoint_source: str = "mediapipe-pose"
    world_keypoints: np.ndarray | None = None

    def __post_init__(self) -> None:
        masks = np.asarray(self.masks, dtype=bool)
        if masks.ndim != 3:
            raise ValueError(f"Observations.masks must be (N, H, W), got shape {masks.shape}")
        n, h, w = masks.shape
        expected = {
            "keypoints": (n, NUM_BODY_LANDMARKS, 3),
            "face": (n, NUM_FACE_LANDMARKS, 3),
            "no_person": (n,),
            "frame_indices": (n,),
            "timestamps": (n,),
            "multiple_people": (n,),
        }
        dtypes = {
            "keypoints": np.float32, "face": np.float32, "no_person": bool,
            "frame_indices": np.int64, "timestamps": np.float64, "multiple_people": bool,
        }  # fmt: skip
        object.__setattr__(self, "masks", masks)
        for name, shape in expected.items():
            value = np.asarray(getattr(self, name), dtype=dtypes[name])
            if value.shape != shape:
                raise ValueError(
                    f"Observations.{name} must have shape {shape}, got {value.shape}"
                )
            object.__setattr__(self, name, value)
        if (self.camera.width, self.camera.height) != (w, h):
            raise ValueError(
                f"Observations: camera is for {self.camera.width}x{self.camera.height} images, "
                f"masks are {w}x{h}"
            )
        if self.world_keypoints is not None:
            world = np.asarray(self.world_keypoints, dtype=np.float32)
            if world.shape != (n, NUM_BODY_LANDMARKS, 4):
                raise ValueError(f"Observations.world_keypoints must have shape "
                                 f"{(n, NUM_BODY_LANDMARKS, 4)}, got {world.shape}")  # fmt: skip
            object.__setattr__(self, "world_keypoints", world)
        if self.flow is not None:
            flow = np.asarray(self.flow, dtype=np.float32)
            if flow.shape != (max(n - 1, 0), h, w, 2):
                raise ValueError(
                    f"Observations.flow must have shape {(max(n - 1, 0), h, w, 2)}, "
                    f"got {flow.shape}"
                )
            object.__setattr__(self, "flow", flow)

    def __len__(self) -> int:
        return int(self.masks.shape[0])

    @property
    def height(self) -> int:
        return int(self.masks.shape[1])

    @property
    def width(self) -> int:
        return int(self.masks.shape[2])

    @property
    def image_size(self) -> tuple[int, int]:
        """(height, width) in pixels, as in the arrays' shapes."""
        return self.height, self.width

    @property
    def face_found(self) -> np.ndarray:
        """(N,) bool, True where any face landmark is present."""
        return np.asarray(~np.all(np.isnan(self.face[..., 0]), axis=1))

    @property
    def person_frames(self) -> np.ndarray:
        """(K,) int64 positions (0..N-1) of frames with a person."""
        return np.flatnonzero(~self.no_person)

    # -- persistence --------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write to an ``.npz`` file atomically (a temporary file in the same folder, renamed).

        Masks are bit-packed; the camera is stored as JSON.
        """
        arrays: dict[str, np.ndarray] = {
            "version": np.asarray(_FORMAT_VERSION),
            "mask_shape": np.asarray(self.masks.shape, dtype=np.int64),
            "masks_packed": np.packbits(self.masks.reshape(-1)),
            "keypoints": self.keypoints,
            "face": self.face,
            "no_person": self.no_person,
            "frame_indices": self.frame_indices,
            "timestamps": self.timestamps,
            "camera": np.asarray(json.dumps(self.camera.to_dict())),
            "keypoint_source": np.asarray(self.keypoint_source),
            "multiple_people": np.asarray(self.multiple_people),
        }
        if self.flow is not None:
            arrays["flow"] = self.flow
        if self.world_keypoints is not None:
            arrays["world_keypoints"] = self.world_keypoints
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **arrays)
        atomic_write_bytes(Path(path), buffer.getvalue())

    @staticmethod
    def load(path: str | Path) -> Observations:
        """Read a file written by :meth:`save`. Raises ``ValueError`` for other files."""
        path = Path(path)
        try:
            data = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, pickle.UnpicklingError) as exc:
            raise ValueError(f"{path}: not an observations file ({exc})") from exc
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise ValueError(f"{path}: not an observations file (not an .npz archive)")
        with data:
            try:
                version = int(data["version"])
                if version != _FORMAT_VERSION:
                    raise ValueError(f"{path}: unsupported observations version {version}")
                shape = tuple(int(s) for s in data["mask_shape"])
                count = int(np.prod(shape))
                masks = np.unpackbits(data["masks_packed"], count=count).astype(bool)
                return Observations(
                    masks=masks.reshape(shape),
                    keypoints=data["keypoints"],
                    face=data["face"],
                    no_person=data["no_person"],
                    multiple_people=data["multiple_people"],
                    camera=PinholeCamera.from_dict(json.loads(str(data["camera"]))),
                    frame_indices=data["frame_indices"],
                    timestamps=data["timestamps"],
                    flow=data["flow"] if "flow" in data.files else None,
                    keypoint_source=str(data["keypoint_source"]),
                    world_keypoints=(data["world_keypoints"]
                                     if "world_keypoints" in data.files else None),
                )
            except (KeyError, OSError, EOFError, zipfile.BadZipFile) as exc:
                raise ValueError(f"{path}: not an observations file ({exc})") from exc


@dataclass(frozen=True)
class PrecomputedPerception:
    """Results from elsewhere (OpenPose, People-Snapshot), used by
    :func:`~monoavatar.perception.pipeline.perceive` instead of running a detector.

    Attributes:
        keypoints: (N, 33, 3) x px, y px, confidence in our order (confidence 0: absent), or
            None.
        face: (N, 468, 3) x px, y px, confidence with NaN rows where absent, or None.
        masks: (N, H, W) bool person masks (used as given), or None.
        multiple_people: (N,) bool frames where the source saw several people, or None.
        keypoint_source: name of what produced the keypoints, e.g. ``"openpose-body25"``.
    """

    keypoints: np.ndarray | None = None
    face: np.ndarray | None = None
    masks: np.ndarray | None = None
    multiple_people: np.ndarray | None = None
    keypoint_source: str = "precomputed"

    def digest(self) -> str:
        """A content hash of the arrays (for cache keys)."""
        h = hashlib.blake2b(digest_size=20)
        for a in (self.keypoints, self.face, self.masks, self.multiple_people):
            if a is None:
                h.update(b"<none>")
                continue
            a = np.ascontiguousarray(a)
            h.update(f"{a.shape}{a.dtype.str}".encode())
            h.update(a.data)
        h.update(self.keypoint_source.encode())
        return h.hexdigest()
