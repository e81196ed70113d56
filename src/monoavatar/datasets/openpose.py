"""Reading OpenPose JSON output folders as precomputed perception.

OpenPose writes one ``*_keypoints.json`` per frame::

    {"version": 1.3, "people": [{"pose_keypoints_2d": [x0, y0, c0, x1, ...],
                                 "face_keypoints_2d": [...], ...}, ...]}

``pose_keypoints_2d`` holds 25 joints (BODY_25) or 18 (COCO-18); ``face_keypoints_2d`` holds 70
points (dlib's 68 plus the pupils) or is empty. Coordinates are pixels with pixel centres at
integers (shifted by +0.5 to our convention), missing joints are (0, 0, 0). They are converted
to our 33-landmark mediapipe order (joints that exist in both; zero confidence elsewhere) and to
face-mesh rows (68 mapped vertices; NaN elsewhere) by :mod:`monoavatar.core.landmarks`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from monoavatar.core.errors import EmptyVideoError, InputFormatError, InputNotFoundError
from monoavatar.core.landmarks import (
    NUM_BODY_LANDMARKS,
    NUM_FACE_LANDMARKS,
    openpose_to_mediapipe_body,
    openpose_to_mediapipe_face,
)
from monoavatar.io.images import natural_sort_key
from monoavatar.perception.observations import PrecomputedPerception

_FORMATS = {75: "body25", 54: "coco18"}


def list_openpose_files(folder: str | Path) -> list[Path]:
    """The ``*_keypoints.json`` files of an OpenPose output folder (all ``*.json`` files when
    none is named so), in natural sort order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputNotFoundError(folder, "no such folder")
    files = [p for p in folder.glob("*_keypoints.json") if p.is_file()]
    files = files or [p for p in folder.glob("*.json") if p.is_file()]
    files = sorted(files, key=natural_sort_key)
    if not files:
        raise EmptyVideoError(folder, "no OpenPose *.json file in the folder")
    return files


def _person_score(body: np.ndarray, image_size: tuple[int, int] | None) -> float:
    """Bounding-box area of the confident joints, weighted by closeness to the image centre."""
    seen = body[body[:, 2] > 0, :2]
    if len(seen) < 2:
        return 0.0
    extent = np.ptp(seen, axis=0)
    area = float(max(extent[0], 1.0) * max(extent[1], 1.0))
    if image_size is None:
        return area
    h, w = image_size
    d = np.linalg.norm(seen.mean(axis=0) - np.array([w / 2.0, h / 2.0]))
    return area * float(np.exp(-2.0 * (d / (0.5 * np.hypot(w, h))) ** 2))


def _floats(path: Path, person: dict[str, object], key: str) -> np.ndarray:
    values = person.get(key, [])
    try:
        return np.asarray(values if values is not None else [], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InputFormatError(path, f"'{key}' is not a list of numbers ({exc})") from exc


def read_openpose_file(
    path: str | Path, image_size: tuple[int, int] | None = None
) -> tuple[np.ndarray | None, np.ndarray | None, str | None, int]:
    """One OpenPose JSON file.

    Args:
        image_size: (height, width) of the frame, to prefer the most central person.
    Returns:
        body: (J, 3) the kept person's OpenPose keypoints (J = 25 or 18), or None (no person);
        face: (70 or 68, 3) their face keypoints, or None; the body format ("body25",
        "coco18", or None); the number of people in the file.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputFormatError(path, f"not a readable OpenPose JSON file ({exc})") from exc
    people = data.get("people") if isinstance(data, dict) else None
    if not isinstance(people, list):
        raise InputFormatError(path, "not an OpenPose file (no 'people' list)")
    bodies: list[np.ndarray] = []
    faces: list[np.ndarray | None] = []
    fmt: str | None = None
    for person in people:
        if not isinstance(person, dict):
            raise InputFormatError(path, "an entry of 'people' is not an object")
        flat = _floats(path, person, "pose_keypoints_2d")
        if flat.size == 0:
            continue
        this = _FORMATS.get(flat.size)
        if this is None:
            raise InputFormatError(
                path,
                f"pose_keypoints_2d has {flat.size} numbers; expected 75 (BODY_25) or "
                "54 (COCO-18)",
            )
        if fmt is not None and this != fmt:
            raise InputFormatError(path, "people in one file have different body formats")
        fmt = this
        bodies.append(flat.reshape(-1, 3))
        face = _floats(path, person, "face_keypoints_2d")
        if face.size not in (0, 210, 204):
            raise InputFormatError(
                path, f"face_keypoints_2d has {face.size} numbers; expected 210 (70 points)"
            )
        faces.append(face.reshape(-1, 3) if face.size else None)
    if not bodies:
        return None, None, None, 0
    best = int(np.argmax([_person_score(b, image_size) for b in bodies]))
    return bodies[best], faces[best], fmt, len(bodies)


def read_openpose_folder(
    folder: str | Path,
    frame_indices: np.ndarray | list[int] | None = None,
    *,
    image_size: tuple[int, int] | None = None,
) -> PrecomputedPerception:
    """OpenPose JSON files of a folder as precomputed keypoints and face landmarks.

    Args:
        folder: OpenPose's ``--write_json`` output: one JSON file per frame, in natural sort
            order (file k is source frame k).
        frame_indices: (N,) source indices of the frames in use (``Frames.indices``); default
            all files.
        image_size: (height, width) of the frames, to prefer the most central person when a
            file holds several.
    Returns:
        PrecomputedPerception with keypoints (N, 33, 3) in our order and pixel convention,
        face (N, 468, 3) (None when no file has face keypoints), and ``multiple_people``
        flags for frames where a file holds several people (the most central and largest is
        kept; :func:`~monoavatar.perception.pipeline.perceive` warns about them).
    Raises:
        InputNotFoundError, EmptyVideoError (no JSON file), InputFormatError (malformed file,
        mixed body formats, fewer files than frames).
    """
    folder = Path(folder)
    files = list_openpose_files(folder)
    if frame_indices is None:
        indices = np.arange(len(files))
    else:
        indices = np.asarray(frame_indices, dtype=np.int64).reshape(-1)
        if len(indices) and (indices.min() < 0 or indices.max() >= len(files)):
            raise InputFormatError(
                folder,
                f"holds {len(files)} OpenPose file(s) but frame index {int(indices.max())} "
                "is needed (one JSON file per video frame is expected)",
            )
    n = len(indices)
    keypoints = np.zeros((n, NUM_BODY_LANDMARKS, 3), dtype=np.float32)
    face = np.full((n, NUM_FACE_LANDMARKS, 3), np.nan, dtype=np.float32)
    multiple = np.zeros(n, dtype=bool)
    formats: dict[str, Path] = {}
    any_face = False
    for i, index in enumerate(indices.tolist()):
        body, face_pts, fmt, count = read_openpose_file(files[index], image_size)
        if body is None or fmt is None:
            continue
        formats.setdefault(fmt, files[index])
        if len(formats) > 1:
            first, second = sorted(formats.items())
            raise InputFormatError(
                folder,
                f"mixed body formats: {first[1].name} is {first[0]}, {second[1].name} is "
                f"{second[0]}",
            )
        keypoints[i] = openpose_to_mediapipe_body(body, fmt)
        multiple[i] = count > 1
        if face_pts is not None:
            face[i] = openpose_to_mediapipe_face(face_pts)
            any_face = True
    fmt_name = next(iter(formats), "body25")
    return PrecomputedPerception(
        keypoints=keypoints,
        face=face if any_face else None,
        multiple_people=multiple,
        keypoint_source=f"openpose-{fmt_name}",
    )
