"""Perception: from frames to ``Observations`` (person masks, body and face landmarks, flow).

Per frame: body landmarks and a person probability map (mediapipe Pose, or Selfie Segmentation),
then over the sequence: temporal smoothing of the probabilities (between frames where the
person hardly moved), thresholding, one person kept (the most central and largest; others are
reported), small holes filled, GrabCut at the boundary (optional); face-mesh landmarks on a crop
around the head; optionally optical flow between consecutive frames. Results are cached on disk
(:mod:`monoavatar.perception.cache`).

Every detector sits behind an interface (:mod:`monoavatar.perception.interfaces`); pass your own
in :class:`Detectors`, or precomputed keypoints / masks / face landmarks in
:class:`PrecomputedPerception` (OpenPose, People-Snapshot).
"""

from __future__ import annotations

import math
import warnings
from concurrent.futures import Future
from dataclasses import asdict, dataclass, replace
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Literal

import numpy as np
from tqdm import tqdm

from monoavatar.core.camera import PinholeCamera
from monoavatar.core.errors import format_indices
from monoavatar.core.landmarks import NUM_BODY_LANDMARKS, NUM_FACE_LANDMARKS
from monoavatar.core.threads import frame_pool
from monoavatar.io.frames import Frames
from monoavatar.io.intrinsics import default_camera
from monoavatar.perception import cache as cache_mod
from monoavatar.perception import people
from monoavatar.perception.errors import MultiplePeopleWarning, NoPersonError, NoPersonWarning
from monoavatar.perception.flow import (
    FlowMethod,
    flow_estimator_name,
    flow_sequence,
    make_flow_estimator,
)
from monoavatar.perception.interfaces import (
    FaceDetector,
    FlowEstimator,
    PersonSegmenter,
    PoseDetector,
)
from monoavatar.perception.masks import (
    fill_holes,
    grabcut_refine,
    landmark_motion,
    largest_component,
    select_person,
    smooth_frame,
)
from monoavatar.perception.mediapipe_backend import native_stderr_hidden
from monoavatar.perception.observations import Observations, PrecomputedPerception

_VISIBLE = 0.5  # keypoint confidence above which a landmark counts as seen


@dataclass(frozen=True)
class PerceptionSettings:
    """Options of :func:`perceive`. All are part of the cache key.

    Attributes:
        segmenter: ``"pose"``: mediapipe Pose's own person mask (one person, tight);
            ``"selfie"``: mediapipe Selfie Segmentation (every person, looser).
        mask_threshold: probability above which a pixel is the person, in (0, 1).
        temporal_sigma: temporal smoothing of the probabilities, standard deviation in source
            frames (0: none). Frames further apart than 3 sigma are not mixed.
        temporal_max_motion: a neighbour is mixed into a frame only when the person moved less
            than this between them (:func:`~monoavatar.perception.masks.landmark_motion`: 90th
            percentile of the body landmarks' displacement over their vertical extent); frames
            whose motion is unknown (no landmarks) are not mixed; ``inf`` mixes all. Smoothing
            across real motion would cut off moving limbs.
        max_hole_fraction: holes up to this fraction of the person's area are filled.
        grabcut: refine the mask boundary with GrabCut's colour models (mediapipe's mask comes
            from a low-resolution network and can reach past the outline).
        grabcut_band_px: width in pixels of the boundary band GrabCut may change (narrow:
            in blurred, noisy frames GrabCut's colour models have less to go by).
        min_mask_fraction: a mask smaller than this fraction of the image means no person.
        other_person_fraction: another person counts (and is warned about) when at least
            this fraction of the subject's area: a mask component, or a person found by
            ``check_several_people``.
        check_several_people: after finding a person, hide them and run the pose detector
            again to find a second one; the more central and larger is kept, with a warning.
            On by default: mediapipe's pose solution reports one person and its mask covers
            only that one, so without this search a second person goes unnoticed (unless the
            ``"selfie"`` segmenter or precomputed OpenPose input shows them). It costs little
            where there is one person (the second search usually stops at the person
            detector). The pose model may "find" a person in leftover clutter once the real
            one is hidden; such finds are small, and a find counts only when it covers
            ``other_person_fraction`` of the subject's area.
        face: detect face-mesh landmarks.
        flow: optical flow between consecutive frames: ``"dis"``, ``"deepflow"`` or None.
        min_detection_confidence: the detectors' score threshold, in (0, 1).
        min_person_fraction: fewer frames with a person than this fraction of all frames (and
            always fewer than one) raises :class:`NoPersonError`.
    """

    segmenter: Literal["pose", "selfie"] = "pose"
    mask_threshold: float = 0.5
    temporal_sigma: float = 1.0
    temporal_max_motion: float = 0.03
    max_hole_fraction: float = 0.01
    grabcut: bool = True
    grabcut_band_px: int = 4
    min_mask_fraction: float = 0.002
    other_person_fraction: float = 0.25
    check_several_people: bool = True
    face: bool = True
    flow: FlowMethod | None = None
    min_detection_confidence: float = 0.5
    min_person_fraction: float = 0.5

    def __post_init__(self) -> None:
        if self.segmenter not in ("pose", "selfie"):
            raise ValueError(f"segmenter must be 'pose' or 'selfie', got {self.segmenter!r}")
        if self.flow not in (None, "dis", "deepflow"):
            raise ValueError(f"flow must be None, 'dis' or 'deepflow', got {self.flow!r}")
        for name in ("mask_threshold", "min_detection_confidence"):
            value = getattr(self, name)
            if not 0.0 < value < 1.0:
                raise ValueError(f"{name} must be in (0, 1), got {value!r}")
        for name in ("min_mask_fraction", "other_person_fraction", "min_person_fraction"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value!r}")
        if self.temporal_sigma < 0 or self.max_hole_fraction < 0 or self.grabcut_band_px < 1:
            raise ValueError(
                "temporal_sigma and max_hole_fraction must be >= 0 and grabcut_band_px >= 1, got "
                f"{self.temporal_sigma}, {self.max_hole_fraction}, {self.grabcut_band_px}"
            )
        if not self.temporal_max_motion >= 0:  # also rejects NaN
            raise ValueError(
                f"temporal_max_motion must be >= 0 (inf allowed), got {self.temporal_max_motion!r}"
            )


@dataclass
class Detectors:
    """The detectors perception runs; any may be None when not needed.

    ``segmenter`` is used for masks when given; otherwise the pose detector's own mask.
    """

    pose: PoseDetector | None = None
    segmenter: PersonSegmenter | None = None
    face: FaceDetector | None = None
    flow: FlowEstimator | None = None

    def names(self) -> dict[str, str | None]:
        """Each detector's name (None when absent), for cache keys."""
        return {
            "pose": self.pose.name if self.pose is not None else None,
            "segmenter": self.segmenter.name if self.segmenter is not None else None,
            "face": self.face.name if self.face is not None else None,
        }

    def close(self) -> None:
        """Close the detectors that hold resources (mediapipe graphs)."""
        for det in (self.pose, self.segmenter, self.face, self.flow):
            close = getattr(det, "close", None)
            if callable(close):
                close()

    def __enter__(self) -> Detectors:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _mediapipe_version() -> str:
    try:
        return version("mediapipe")
    except PackageNotFoundError:  # pragma: no cover
        return "unknown"


def _needs(
    settings: PerceptionSettings, pre: PrecomputedPerception
) -> tuple[bool, bool, bool]:
    """Whether pose detection, a separate segmenter and face detection must run."""
    need_segmenter = pre.masks is None and settings.segmenter == "selfie"
    need_pose = pre.keypoints is None or (pre.masks is None and settings.segmenter == "pose")
    need_face = settings.face and pre.face is None
    return need_pose, need_segmenter, need_face


def default_detectors(
    settings: PerceptionSettings | None = None,
    precomputed: PrecomputedPerception | None = None,
) -> Detectors:
    """Mediapipe (and OpenCV flow) detectors for ``settings``; only those that will run are
    made. Close them with :meth:`Detectors.close` (or use as a context manager)."""
    from monoavatar.perception.mediapipe_backend import (
        MediaPipeFaceMesh,
        MediaPipePose,
        MediaPipeSelfieSegmenter,
    )

    settings = settings or PerceptionSettings()
    need_pose, need_segmenter, need_face = _needs(settings, precomputed or PrecomputedPerception())
    conf = settings.min_detection_confidence
    return Detectors(
        pose=MediaPipePose(conf, segmentation=settings.segmenter == "pose") if need_pose else None,
        segmenter=MediaPipeSelfieSegmenter() if need_segmenter else None,
        face=MediaPipeFaceMesh(min_detection_confidence=conf) if need_face else None,
        flow=make_flow_estimator(settings.flow) if settings.flow else None,
    )


def _default_names(settings: PerceptionSettings, pre: PrecomputedPerception) -> dict[str, object]:
    """The names :func:`default_detectors` would give, without loading mediapipe."""
    need_pose, need_segmenter, need_face = _needs(settings, pre)
    return {
        "backend": f"mediapipe-{_mediapipe_version()}",
        "pose": need_pose,
        "segmenter": need_segmenter,
        "face": need_face,
    }


# -- the sequence ---------------------------------------------------------------------------
def _still_neighbours(
    keypoints: np.ndarray, indices: np.ndarray, i: int, settings: PerceptionSettings
) -> np.ndarray:
    """(N,) bool: the frames within temporal reach of frame ``i`` between which and frame ``i``
    the person moved less than ``settings.temporal_max_motion`` (frame ``i`` included)."""
    idx = np.asarray(indices, dtype=np.float64)
    out = np.zeros(len(idx), dtype=bool)
    out[i] = True
    if settings.temporal_sigma <= 0:
        return out
    for j in np.flatnonzero(np.abs(idx - idx[i]) <= 3.0 * settings.temporal_sigma):
        if j != i:
            motion = landmark_motion(keypoints[i], keypoints[j], _VISIBLE)
            out[j] = motion <= settings.temporal_max_motion
    return out


@dataclass
class _Raw:
    masks: np.ndarray
    keypoints: np.ndarray
    face: np.ndarray
    no_person: np.ndarray
    multiple_people: np.ndarray
    world: np.ndarray


def _reach(indices: np.ndarray, sigma: float) -> np.ndarray:
    """(N,) for each frame, the last frame whose probabilities its temporal smoothing reads
    (source frame indices within 3 sigma; ``indices`` ascending)."""
    idx = np.asarray(indices, dtype=np.float64)
    if sigma <= 0 or len(idx) < 2:
        return np.arange(len(idx))
    return np.searchsorted(idx, idx + 3.0 * sigma, side="right") - 1


def _refined_mask(image: np.ndarray, mask: np.ndarray, settings: PerceptionSettings
                  ) -> np.ndarray:  # fmt: skip
    """A thresholded person mask refined: GrabCut at the boundary (when on), small holes
    filled. Safe to run in a worker thread (OpenCV and numpy only)."""
    if settings.grabcut:
        mask = largest_component(grabcut_refine(image, mask, settings.grabcut_band_px))
    return fill_holes(mask, settings.max_hole_fraction)


def _run(
    frames: Frames,
    settings: PerceptionSettings,
    dets: Detectors,
    pre: PrecomputedPerception,
    progress: bool = False,
    workers: int = 2,
) -> _Raw:
    """The detectors on every frame (this thread, in frame order), each frame's mask finished
    as soon as the frames its smoothing reads are detected, its refinement (GrabCut) in
    ``workers`` threads meanwhile, then the face landmarks on the finished masks."""
    n, h, w = len(frames), frames.height, frames.width
    need_pose, _, need_face = _needs(settings, pre)
    if need_pose and dets.pose is None:
        raise ValueError("perception needs a pose detector (Detectors.pose is None)")
    if pre.masks is None and dets.segmenter is None and dets.pose is None:
        raise ValueError("perception needs a segmenter or a pose detector that gives masks")
    keypoints = np.zeros((n, NUM_BODY_LANDMARKS, 3), dtype=np.float32)
    world = np.full((n, NUM_BODY_LANDMARKS, 4), np.nan, dtype=np.float32)
    found = np.zeros(n, dtype=bool)
    multiple = np.zeros(n, dtype=bool)
    min_area = max(1, int(settings.min_mask_fraction * h * w))
    probs = np.zeros((n, h, w), dtype=np.uint8) if pre.masks is None else None
    detected = np.zeros_like(keypoints)  # the landmarks as detected, before any re-detection

    def detect(i: int, image: np.ndarray) -> None:
        result = dets.pose.detect(image) if (need_pose and dets.pose is not None) else None
        if (
            result is not None
            and dets.pose is not None
            and settings.check_several_people
            and pre.keypoints is None
        ):
            result, multiple[i] = people.second_person(image, result, dets.pose, settings, min_area)
        if pre.keypoints is not None:
            keypoints[i] = pre.keypoints[i]
            found[i] = bool(np.any(pre.keypoints[i, :, 2] > 0))
        elif result is not None:
            keypoints[i] = result.keypoints
            found[i] = True
            if result.world is not None:
                world[i] = result.world
        detected[i] = keypoints[i]
        if probs is not None:
            if dets.segmenter is not None:
                prob = dets.segmenter.segment(image)
            elif result is not None and result.segmentation is not None:
                prob = result.segmentation
            else:
                return
            probs[i] = np.clip(np.rint(np.asarray(prob, np.float32) * 255.0), 0, 255)

    def person_mask(i: int, image: np.ndarray) -> np.ndarray:
        """Frame i's mask before refinement: smoothed over still neighbours, thresholded, one
        person kept (landmarks detected again where they belong to another person)."""
        if probs is None:
            assert pre.masks is not None
            return np.asarray(pre.masks[i], dtype=bool)
        still = _still_neighbours(detected, frames.indices, i, settings)
        smoothed = smooth_frame(probs, frames.indices, i, settings.temporal_sigma, still)
        person = smoothed >= settings.mask_threshold * 255.0
        choice = select_person(person, settings.other_person_fraction, min_area)
        multiple[i] |= choice.num_people > 1
        if (
            multiple[i]
            and pre.keypoints is None
            and dets.pose is not None
            and found[i]
            and people.keypoints_belong_elsewhere(keypoints[i], choice.mask, choice.others)
        ):
            again = dets.pose.detect(people.hide_people(image, choice.others, choice.mask))
            if again is not None:
                keypoints[i] = again.keypoints
                world[i] = again.world if again.world is not None else np.nan
            else:
                found[i] = False
        return choice.mask

    reach = _reach(frames.indices, settings.temporal_sigma)
    refined: list[Future[np.ndarray]] = []
    masks = np.zeros((n, h, w), dtype=bool)
    face = np.full((n, NUM_FACE_LANDMARKS, 3), np.nan, dtype=np.float32)
    with frame_pool(workers) as pool:

        def finish(i: int) -> Future[np.ndarray]:
            image = frames.images[i]
            mask = person_mask(i, image)
            if probs is None:  # given masks are used as they are
                done: Future[np.ndarray] = Future()
                done.set_result(mask)
                return done
            return pool.submit(_refined_mask, image, mask, settings)

        images = tqdm(frames.images, desc="perception", unit="frame", disable=not progress)
        for i, image in enumerate(images):
            detect(i, image)
            while len(refined) < n and reach[len(refined)] <= i:
                refined.append(finish(len(refined)))
        while len(refined) < n:
            refined.append(finish(len(refined)))
        for i, image in enumerate(frames.images):
            mask = refined[i].result()
            if not found[i] or int(mask.sum()) < min_area:
                found[i] = False
                continue
            masks[i] = mask
            if pre.face is not None:
                face[i] = pre.face[i]
            elif need_face and dets.face is not None:
                faces = people.detect_face(image, dets.face, keypoints[i])
                chosen = people.choose_face(faces, keypoints[i], mask)
                if chosen is not None:
                    face[i] = chosen
    no_person = ~found
    keypoints[no_person] = 0.0
    face[no_person] = np.nan
    world[no_person] = np.nan
    if pre.multiple_people is not None:
        multiple |= np.asarray(pre.multiple_people, dtype=bool)
    multiple &= found
    return _Raw(masks, keypoints, face, no_person, multiple, world)


def _check_precomputed(frames: Frames, pre: PrecomputedPerception) -> None:
    n, h, w = len(frames), frames.height, frames.width
    checks = {
        "keypoints": (pre.keypoints, (n, NUM_BODY_LANDMARKS, 3)),
        "face": (pre.face, (n, NUM_FACE_LANDMARKS, 3)),
        "masks": (pre.masks, (n, h, w)),
        "multiple_people": (pre.multiple_people, (n,)),
    }
    for name, (value, shape) in checks.items():
        if value is not None and np.shape(value) != shape:
            raise ValueError(
                f"precomputed {name} must have shape {shape} for these frames, "
                f"got {np.shape(value)}"
            )


def perceive(
    frames: Frames,
    camera: PinholeCamera | None = None,
    settings: PerceptionSettings | None = None,
    *,
    detectors: Detectors | None = None,
    precomputed: PrecomputedPerception | None = None,
    use_cache: bool = True,
    cache_dir: str | Path | None = None,
    progress: bool = False,
    workers: int = 2,
) -> Observations:
    """Person masks, body and face landmarks (and optionally flow) for every frame.

    Args:
        frames: the frames, (N, H, W, 3) uint8 RGB.
        camera: the frames' camera (default: :func:`monoavatar.io.intrinsics.default_camera`);
            it is attached to the result and does not change perception.
        settings: options (default :class:`PerceptionSettings`).
        detectors: detectors to use instead of mediapipe's (they are not closed here).
        precomputed: keypoints, masks or face landmarks from elsewhere, used instead of running
            the corresponding detector.
        use_cache: read and write the on-disk cache.
        cache_dir: cache root (default ``$MONOAVATAR_CACHE`` or ``~/.cache/monoavatar``).
        progress: show a progress bar while the detectors run.
        workers: threads that refine the masks (GrabCut) while the detectors run; the
            result does not depend on it.
    Returns:
        Observations for all N frames; frames without a person are flagged in ``no_person``.
    Warns:
        NoPersonWarning: listing the source indices of frames without a person.
        MultiplePeopleWarning: listing the frames where several people were seen.
    Raises:
        NoPersonError: fewer frames with a person than ``settings.min_person_fraction`` of N
            (and always when none has one).
    """
    settings = settings or PerceptionSettings()
    pre = precomputed or PrecomputedPerception()
    if len(frames) == 0:
        raise ValueError(f"{frames.source}: no frames to perceive")
    camera = camera or default_camera(frames.width, frames.height)
    if (camera.width, camera.height) != (frames.width, frames.height):
        raise ValueError(
            f"camera is for {camera.width}x{camera.height} images, frames are "
            f"{frames.width}x{frames.height}"
        )
    _check_precomputed(frames, pre)
    names: object = detectors.names() if detectors is not None else _default_names(settings, pre)
    perception_settings = {k: v for k, v in asdict(settings).items() if k != "flow"}
    key = cache_mod.make_key(
        "observations-2", frames.digest, perception_settings, names, pre.digest()
    )
    folder = cache_mod.perception_cache_dir(cache_dir)
    entry = folder / f"{key}.npz"

    cached = _load_entry(entry) if use_cache else None
    owned: Detectors | None = None
    try:
        if cached is None:
            dets = detectors if detectors is not None else default_detectors(settings, pre)
            if detectors is None:
                owned = dets
            with native_stderr_hidden():  # mediapipe's graphs log as they start, from threads
                raw = _run(frames, settings, dets, pre, progress, workers)
                if owned is not None:  # its threads joined while a late line is still hidden
                    owned.close()
                    owned = None
            source = pre.keypoint_source if pre.keypoints is not None else (
                dets.pose.name if dets.pose is not None else "none"
            )
            obs = Observations(
                masks=raw.masks, keypoints=raw.keypoints, face=raw.face,
                no_person=raw.no_person, multiple_people=raw.multiple_people, camera=camera,
                frame_indices=frames.indices, timestamps=frames.timestamps,
                keypoint_source=source,
                world_keypoints=raw.world if np.isfinite(raw.world).any() else None,
            )
            if use_cache:
                obs.save(entry)
        else:
            obs = Observations(
                masks=cached.masks, keypoints=cached.keypoints, face=cached.face,
                no_person=cached.no_person, multiple_people=cached.multiple_people,
                camera=camera, frame_indices=frames.indices, timestamps=frames.timestamps,
                keypoint_source=cached.keypoint_source, world_keypoints=cached.world_keypoints,
            )
        flow = None
        if settings.flow is not None and len(frames) > 1:
            estimator = detectors.flow if detectors is not None else None
            flow = _flow(frames, estimator, settings.flow, folder, use_cache)
    finally:
        if owned is not None:
            owned.close()
    if settings.flow is not None:
        obs = replace(obs, flow=flow if flow is not None else np.zeros((0, *obs.image_size, 2)))
    _report(frames, obs, settings)
    return obs


def _load_entry(entry: Path) -> Observations | None:
    if not entry.is_file():
        return None
    try:
        return Observations.load(entry)
    except Exception as exc:  # a damaged entry is recomputed, not fatal
        warnings.warn(f"ignoring unreadable cache entry {entry} ({exc})", stacklevel=3)
        return None


def _flow(
    frames: Frames,
    estimator: FlowEstimator | None,
    method: FlowMethod,
    folder: Path,
    use_cache: bool,
) -> np.ndarray:
    """Flow of consecutive frames, from the cache or computed (``estimator``, else ``method``'s
    default estimator, made only when needed)."""
    name = estimator.name if estimator is not None else flow_estimator_name(method)
    key = cache_mod.make_key("flow", frames.digest, name)
    entry = folder / f"{key}.flow.npz"
    if use_cache:
        arrays = cache_mod.load_arrays(entry)
        expected = (len(frames) - 1, frames.height, frames.width, 2)
        if arrays is not None and arrays.get("flow", np.empty(0)).shape == expected:
            return arrays["flow"]
    flow = flow_sequence(frames.images, estimator or make_flow_estimator(method))
    if use_cache:
        cache_mod.save_arrays(entry, {"flow": flow}, compress=False)
    return flow


SMALL_PERSON = 0.25
"""A person spanning less of the image height than this is small for the detectors."""


def _size_hint(obs: Observations) -> str:
    """Why few frames show a person, when the frames that do show one small: a sentence, or
    "" when the person found is not small (or none was found)."""
    heights = []
    for mask, none in zip(obs.masks, obs.no_person, strict=True):
        rows = np.flatnonzero(mask.any(axis=1))
        if not none and rows.size:
            heights.append((rows[-1] - rows[0] + 1) / mask.shape[0])
    if not heights or float(np.median(heights)) >= SMALL_PERSON:
        return ""
    return (f"Where a person was found it spans only {100 * float(np.median(heights)):.0f} % of "
            "the image height (median): the detectors need a person filling about a third of "
            "the frame or more; crop the video to the person or film closer")  # fmt: skip


def _report(frames: Frames, obs: Observations, settings: PerceptionSettings) -> None:
    n = len(obs)
    missing = frames.indices[obs.no_person].tolist()
    found = n - len(missing)
    required = max(1, math.ceil(settings.min_person_fraction * n))
    if found < required:
        raise NoPersonError(frames.source, missing, found, required, _size_hint(obs))
    if missing:
        warnings.warn(
            f"{frames.source}: no person found in {len(missing)} of {n} frame(s) "
            f"(source indices {format_indices(missing)}); they are flagged in "
            "Observations.no_person",
            NoPersonWarning,
            stacklevel=3,
        )
    several = frames.indices[obs.multiple_people].tolist()
    if several:
        warnings.warn(
            f"{frames.source}: several people in {len(several)} frame(s) (source indices "
            f"{format_indices(several)}); the most central and largest person was kept",
            MultiplePeopleWarning,
            stacklevel=3,
        )


def perceive_image(
    image: np.ndarray,
    camera: PinholeCamera | None = None,
    settings: PerceptionSettings | None = None,
    *,
    detectors: Detectors | None = None,
    use_cache: bool = False,
) -> Observations:
    """:func:`perceive` for one (H, W, 3) uint8 RGB image (no temporal smoothing, no cache by
    default); returns Observations with N = 1. Pass ``detectors=default_detectors()`` to reuse
    the mediapipe graphs over many calls."""
    frames = Frames.from_images(np.asarray(image)[None], source="<image>")
    return perceive(frames, camera, settings, detectors=detectors, use_cache=use_cache)
