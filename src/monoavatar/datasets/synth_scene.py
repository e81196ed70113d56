"""Reading a ``monoavatar synth`` folder back: frames, camera, ground-truth perception and the
ground truth itself (for fitting with known observations, tests and benchmarks).

The folder layout is documented in :mod:`monoavatar.synth.scene`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import trimesh
from PIL import Image

from monoavatar.body import BodyModel
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.errors import InputFormatError, InputNotFoundError
from monoavatar.core.landmarks import NUM_FACE_LANDMARKS
from monoavatar.io.frames import Frames
from monoavatar.perception.observations import Observations


def is_synth_scene(path: str | Path) -> bool:
    """Whether ``path`` is a folder written by ``monoavatar synth``."""
    path = Path(path)
    scene = path / "scene.json"
    if not scene.is_file():
        return False
    try:
        return str(json.loads(scene.read_text()).get("format", "")).startswith("monoavatar-synth")
    except (OSError, ValueError):
        return False


@dataclass(frozen=True)
class SynthGroundTruth:
    """The ground truth of a synthetic scene.

    Attributes:
        folder: the scene folder.
        body_model: identity of the body model that generated it (e.g. ``"anny-local"``).
        shapes: (S_subj, S) shape parameters of each subject in that model.
        subject_of_frame: (N,) int subject shown in each frame.
        poses: (N, J, 3) axis-angle joint rotations, radians, fitting skeleton.
        translations: (N, 3) root translations, metres.
        displacements: (S_subj, V_f) clothing and hair displacement along canonical normals, m.
        garments: (S_subj, V_f) 0 skin, 1 top, 2 bottom, 3 hair, 4 shoes.
        keypoints_3d: (N, 33, 3) mediapipe-order landmarks in world coordinates, metres.
        keypoints: (N, 33, 3) exact projected landmarks: x px, y px, visibility 0/1.
        masks: (N, H, W) bool exact person masks.
    """

    folder: Path
    body_model: str
    shapes: np.ndarray
    subject_of_frame: np.ndarray
    poses: np.ndarray
    translations: np.ndarray
    displacements: np.ndarray
    garments: np.ndarray
    keypoints_3d: np.ndarray
    keypoints: np.ndarray
    masks: np.ndarray

    def canonical_mesh(self, subject: int = 0) -> trimesh.Trimesh:
        """The clothed canonical (zero-pose) mesh of a subject, metres, Y up, facing +Z.

        Vertices keep the file's order (not split at UV seams): the subdivided mesh's first
        vertices are the generating body model's own, in its order, so vertex ``i`` of the
        body model corresponds to vertex ``i`` here."""
        path = self.folder / "gt" / f"subject_{subject:03d}" / "canonical.obj"
        if not path.is_file():
            raise InputNotFoundError(path, "ground-truth canonical mesh missing")
        vertices, faces = [], []
        with open(path) as fh:
            for line in fh:
                if line.startswith("v "):
                    vertices.append([float(x) for x in line.split()[1:4]])
                elif line.startswith("f "):
                    faces.append([int(c.split("/")[0]) - 1 for c in line.split()[1:4]])
        return trimesh.Trimesh(np.array(vertices), np.array(faces, dtype=np.int64),
                               process=False)  # fmt: skip

    def posed_mesh(self, frame: int) -> trimesh.Trimesh | None:
        """The saved posed ground-truth mesh (world metres) of a frame, by its index in the
        scene (not in a ``frames`` subset), or None when the scene saved none for it."""
        path = self.folder / "gt" / "posed" / f"{frame:06d}.ply"
        if not path.is_file():
            return None
        mesh = trimesh.load(path, process=False, force="mesh")
        assert isinstance(mesh, trimesh.Trimesh)
        return mesh

    def posed_frames(self) -> list[int]:
        """Frames with a saved posed mesh."""
        return sorted(int(p.stem) for p in (self.folder / "gt" / "posed").glob("*.ply"))

    def body_output(self, body: BodyModel, frames: np.ndarray | None = None):
        """The generating body model posed at the given frames (all by default).

        ``body`` must be the model named by :attr:`body_model` (``load_body_model(...)``).
        Returns the :class:`~monoavatar.body.BodyOutput` (unclothed body, joints, transforms).
        """
        if body.identity != self.body_model:
            raise ValueError(
                f"ground truth was made with body model {self.body_model!r}, "
                f"got {body.identity!r}"
            )
        idx = np.arange(len(self.poses)) if frames is None else np.asarray(frames)
        shape = torch.as_tensor(self.shapes[self.subject_of_frame[idx]], dtype=body.dtype)
        with torch.no_grad():
            return body(
                shape=shape,
                pose=torch.as_tensor(self.poses[idx], dtype=body.dtype),
                translation=torch.as_tensor(self.translations[idx], dtype=body.dtype),
            )


@dataclass(frozen=True)
class SynthScene:
    """A synthetic scene read back.

    Attributes:
        folder: the scene folder.
        frames: the rendered frames (with the scene's noise).
        camera: the scene camera.
        observations: perception taken from the ground truth: exact masks and the jittered
            ``observed`` keypoints (or the exact ones), no face landmarks.
        ground_truth: everything the scene was made from.
        info: the parsed ``scene.json``.
    """

    folder: Path
    frames: Frames
    camera: PinholeCamera
    observations: Observations
    ground_truth: SynthGroundTruth
    info: dict


def stated_height(info: dict[str, Any], subject: int = 0) -> float:
    """The height subject ``subject`` of a parsed ``scene.json`` would state: metres, standing
    without shoes or hair (``stature_m``; scenes before format 4 record only ``height_m``, the
    clothed mesh's, which is then returned)."""
    entry = info["subjects"][subject]
    return float(entry.get("stature_m", entry["height_m"]))


def _read_png_stack(folder: Path, count: int, what: str) -> list[np.ndarray]:
    files = sorted(folder.glob("*.png"))
    if len(files) != count:
        raise InputFormatError(folder, f"expected {count} {what} PNGs, found {len(files)}")
    return [np.asarray(Image.open(f)) for f in files]


def read_synth_scene(
    path: str | Path, *, keypoints: str = "observed", frames: np.ndarray | None = None
) -> SynthScene:
    """Read a ``monoavatar synth`` folder.

    Args:
        path: the scene folder.
        keypoints: ``"observed"`` (jittered, as a detector would give) or ``"exact"``.
        frames: optional (K,) indices of the frames to keep (default all).
    """
    folder = Path(path)
    if not folder.exists():
        raise InputNotFoundError(folder, "no such folder")
    if not is_synth_scene(folder):
        raise InputFormatError(folder, "not a monoavatar synth folder (no valid scene.json)")
    if keypoints not in ("observed", "exact"):
        raise ValueError(f"keypoints must be 'observed' or 'exact', got {keypoints!r}")
    info = json.loads((folder / "scene.json").read_text())
    camera = PinholeCamera.load_json(folder / "camera.json")
    kp = np.load(folder / "keypoints.npz")
    params = np.load(folder / "gt" / "params.npz")
    n = int(kp["keypoints"].shape[0])
    idx = np.arange(n) if frames is None else np.asarray(frames, dtype=np.int64)
    if idx.size == 0 or idx.min() < 0 or idx.max() >= n:
        raise ValueError(f"frame indices must lie in [0, {n}), got {idx}")
    frame_files = sorted((folder / "frames").glob("*.png"))
    mask_files = sorted((folder / "masks").glob("*.png"))
    if len(frame_files) != n or len(mask_files) != n:
        raise InputFormatError(
            folder, f"expected {n} frames and masks, found {len(frame_files)} and {len(mask_files)}"
        )
    images = np.stack([np.asarray(Image.open(frame_files[i]).convert("RGB")) for i in idx])
    masks = np.stack([np.asarray(Image.open(mask_files[i])) > 127 for i in idx])
    fps = float(info.get("fps", 30.0))
    times = idx / fps
    frames_obj = Frames(images=images, timestamps=times, indices=idx, fps=fps, source=str(folder))
    chosen = kp["observed" if keypoints == "observed" else "keypoints"][idx].astype(np.float32)
    no_person = ~masks.reshape(len(idx), -1).any(axis=1)
    obs = Observations(
        masks=masks,
        keypoints=chosen,
        face=np.full((len(idx), NUM_FACE_LANDMARKS, 3), np.nan, np.float32),
        no_person=no_person,
        multiple_people=np.zeros(len(idx), bool),
        camera=camera,
        frame_indices=idx,
        timestamps=times,
        keypoint_source="synth-" + keypoints,
    )
    gt = SynthGroundTruth(
        folder=folder,
        body_model=str(params["body_model"]),
        shapes=params["shapes"],
        subject_of_frame=params["subject_of_frame"][idx],
        poses=params["poses"][idx],
        translations=params["translations"][idx],
        displacements=params["displacements"],
        garments=params["garments"],
        keypoints_3d=kp["keypoints_3d"][idx],
        keypoints=kp["keypoints"][idx],
        masks=masks,
    )
    return SynthScene(folder, frames_obj, camera, obs, gt, info)

