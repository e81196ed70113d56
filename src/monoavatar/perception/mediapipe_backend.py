"""Detectors built on mediapipe 0.10.x legacy solutions, whose wheels ship the ``.tflite`` models
(nothing is downloaded: only the models inside the wheel are used, which is why pose runs with
``model_complexity=1``, the one pose-landmark model the wheel carries).

All run per image (``static_image_mode=True``): results do not depend on frame order, and the
functions work on any image array. Temporal consistency is added afterwards by the pipeline.
"""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from monoavatar.core.landmarks import NUM_BODY_LANDMARKS, NUM_FACE_LANDMARKS
from monoavatar.perception.interfaces import PoseResult


def check_image(image: np.ndarray) -> np.ndarray:
    """Validate an (H, W, 3) uint8 RGB image and return it C-contiguous."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(
            f"expected an (H, W, 3) uint8 RGB image, got shape {image.shape} dtype {image.dtype}"
        )
    if image.shape[0] < 2 or image.shape[1] < 2:
        raise ValueError(f"image too small: {image.shape[1]}x{image.shape[0]}")
    return np.ascontiguousarray(image)


def _mediapipe() -> Any:
    with native_stderr_hidden():
        import mediapipe  # slow import: only when a mediapipe detector is made

    return mediapipe


@contextmanager
def native_stderr_hidden() -> Iterator[None]:
    """Hide what native code writes to the process's stderr (file descriptor 2) inside the
    block: the TensorFlow Lite and absl lines mediapipe's graphs print when they start and first
    run, some from their own threads ("Created TensorFlow Lite XNNPACK delegate", "All log
    messages before absl::InitializeLog()", "Feedback manager ..."), read like errors. Python's
    own ``sys.stderr`` (progress bars, warnings) still reaches the terminal: when it is the
    process's stderr it is pointed at a copy of it for the block, closed when the block ends
    (a progress bar made inside the block must end inside it). What was hidden is shown if the
    block raises. Blocks may nest."""
    sys.stderr.flush()
    saved = os.dup(2)
    python_stderr = sys.stderr
    try:
        swap = python_stderr.fileno() == 2
    except (AttributeError, OSError, ValueError):  # replaced by a stream without a descriptor
        swap = False
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        if swap:
            sys.stderr = open(os.dup(saved), "w", buffering=1, encoding=python_stderr.encoding,
                              errors="backslashreplace")  # noqa: SIM115
        try:
            yield
        except BaseException:
            os.dup2(saved, 2)
            sink.seek(0)
            os.write(saved, sink.read())
            raise
        finally:
            if swap:
                sys.stderr.close()
                sys.stderr = python_stderr
            os.dup2(saved, 2)
            os.close(saved)


class _Closing:
    _solution: Any
    _started: bool = False

    def close(self) -> None:
        """Release the mediapipe graph (its threads are joined with native stderr hidden: a
        line one of them logs late, after the last result came back, is caught here)."""
        if self._solution is not None:
            with native_stderr_hidden():
                self._solution.close()
            self._solution = None

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _run(self, image: np.ndarray) -> Any:
        if self._solution is None:
            raise RuntimeError(f"{type(self).__name__} is closed")
        if not self._started:  # the native start-up lines come with the first frame
            self._started = True
            with native_stderr_hidden():
                return self._solution.process(check_image(image))
        return self._solution.process(check_image(image))


class MediaPipePose(_Closing):
    """Mediapipe Pose (BlazePose full): 33 landmarks with visibility, and a person mask.

    Args:
        min_detection_confidence: the person detector's score threshold in [0, 1].
        segmentation: also return mediapipe's person mask.
    """

    def __init__(self, min_detection_confidence: float = 0.5, segmentation: bool = True) -> None:
        mp = _mediapipe()
        self._segmentation = segmentation
        self._confidence = float(min_detection_confidence)
        with native_stderr_hidden():
            self._solution = mp.solutions.pose.Pose(
                static_image_mode=True,
                model_complexity=1,
                enable_segmentation=segmentation,
                min_detection_confidence=self._confidence,
            )
        self._name = (
            f"mediapipe-{mp.__version__}-pose-full-c{self._confidence:g}"
            f"{'-seg' if segmentation else ''}"
        )

    @property
    def name(self) -> str:
        return self._name

    def detect(self, image: np.ndarray) -> PoseResult | None:
        """image: (H, W, 3) uint8 RGB → 33 landmarks (x px, y px, visibility), their metric 3D
        world positions and the mask."""
        result = self._run(image)
        if result.pose_landmarks is None:
            return None
        h, w = image.shape[:2]
        keypoints = np.array(
            [[lm.x * w, lm.y * h, lm.visibility] for lm in result.pose_landmarks.landmark],
            dtype=np.float32,
        ).reshape(NUM_BODY_LANDMARKS, 3)
        keypoints[:, 2] = np.clip(keypoints[:, 2], 0.0, 1.0)
        mask = None
        if self._segmentation and result.segmentation_mask is not None:
            mask = np.clip(np.asarray(result.segmentation_mask, dtype=np.float32), 0.0, 1.0)
        world = None
        if result.pose_world_landmarks is not None:
            world = np.array([[lm.x, lm.y, lm.z, lm.visibility]
                              for lm in result.pose_world_landmarks.landmark],
                             dtype=np.float32).reshape(NUM_BODY_LANDMARKS, 4)  # fmt: skip
            world[:, 3] = np.clip(world[:, 3], 0.0, 1.0)
        return PoseResult(keypoints=keypoints, segmentation=mask, world=world)


class MediaPipeSelfieSegmenter(_Closing):
    """Mediapipe Selfie Segmentation: a mask of every person in the image.

    Args:
        landscape: use the landscape model (144×256 input) instead of the general one (256×256).
    """

    def __init__(self, landscape: bool = False) -> None:
        mp = _mediapipe()
        with native_stderr_hidden():
            self._solution = mp.solutions.selfie_segmentation.SelfieSegmentation(
                model_selection=1 if landscape else 0
            )
        self._name = f"mediapipe-{mp.__version__}-selfie-{'landscape' if landscape else 'general'}"

    @property
    def name(self) -> str:
        return self._name

    def segment(self, image: np.ndarray) -> np.ndarray:
        """image: (H, W, 3) uint8 RGB → (H, W) float32 person probability."""
        result = self._run(image)
        return np.clip(np.asarray(result.segmentation_mask, dtype=np.float32), 0.0, 1.0)


class MediaPipeFaceMesh(_Closing):
    """Mediapipe Face Mesh: 468 landmarks per face (confidence 1 for every landmark, as the mesh
    model gives none per point).

    Faces far from the camera (full-body shots) are small; the pipeline therefore runs this on a
    crop around the head (:func:`monoavatar.perception.people.detect_face`).

    Args:
        max_faces: the most faces to return.
        min_detection_confidence: the face detector's score threshold in [0, 1].
    """

    def __init__(self, max_faces: int = 4, min_detection_confidence: float = 0.5) -> None:
        mp = _mediapipe()
        with native_stderr_hidden():
            self._solution = mp.solutions.face_mesh.FaceMesh(
                static_image_mode=True,
                max_num_faces=int(max_faces),
                refine_landmarks=False,
                min_detection_confidence=float(min_detection_confidence),
            )
        self._name = (
            f"mediapipe-{mp.__version__}-facemesh-n{int(max_faces)}-c{min_detection_confidence:g}"
        )

    @property
    def name(self) -> str:
        return self._name

    def detect(self, image: np.ndarray) -> list[np.ndarray]:
        """image: (H, W, 3) uint8 RGB → a (468, 3) array (x px, y px, 1) per face."""
        result = self._run(image)
        if not result.multi_face_landmarks:
            return []
        h, w = image.shape[:2]
        faces = []
        for face in result.multi_face_landmarks:
            pts = np.array([[lm.x * w, lm.y * h, 1.0] for lm in face.landmark], dtype=np.float32)
            faces.append(pts[:NUM_FACE_LANDMARKS])
        return faces
