"""Perception: person masks, 2D body landmarks, face landmarks and optical flow per frame.

Entry points: :func:`perceive` (frames → :class:`Observations`, cached on disk) and
:func:`perceive_image` (one image array). Detectors sit behind the interfaces in
:mod:`monoavatar.perception.interfaces`; the mediapipe ones are in
:mod:`monoavatar.perception.mediapipe_backend`.
"""

from monoavatar.core.landmarks import MEDIAPIPE_LANDMARKS
from monoavatar.perception.errors import (
    MultiplePeopleWarning,
    NoPersonError,
    NoPersonWarning,
    PerceptionError,
)
from monoavatar.perception.flow import DeepFlow, DISFlow, estimate_flow
from monoavatar.perception.interfaces import (
    FaceDetector,
    FlowEstimator,
    PersonSegmenter,
    PoseDetector,
    PoseResult,
)
from monoavatar.perception.observations import Observations, PrecomputedPerception
from monoavatar.perception.people import detect_face
from monoavatar.perception.pipeline import (
    Detectors,
    PerceptionSettings,
    default_detectors,
    perceive,
    perceive_image,
)

__all__ = [
    "MEDIAPIPE_LANDMARKS",
    "DISFlow",
    "DeepFlow",
    "Detectors",
    "FaceDetector",
    "FlowEstimator",
    "MultiplePeopleWarning",
    "NoPersonError",
    "NoPersonWarning",
    "Observations",
    "PerceptionError",
    "PerceptionSettings",
    "PersonSegmenter",
    "PoseDetector",
    "PoseResult",
    "PrecomputedPerception",
    "default_detectors",
    "detect_face",
    "estimate_flow",
    "perceive",
    "perceive_image",
]
