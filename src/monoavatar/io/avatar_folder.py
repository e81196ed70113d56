"""The avatar folder that ``monoavatar reconstruct`` writes and ``animate`` and ``bench`` read,
as one object: :class:`AvatarFolder` (with :class:`AvatarParams` for ``params.npz`` and
:class:`Report` for ``report.json``), saved and loaded as a whole. ``shape.npz`` of
``monoavatar fit-shape`` is :class:`ShapeFile`.

Files of a folder::

    avatar.glb      skinned, textured glTF 2.0 binary (written from a SkinnedMesh)
    avatar.obj      the canonical avatar (+ avatar.mtl, texture.png), UVs
    texture.png     (S, S, 3) albedo texture, glTF UV convention
    params.npz      AvatarParams (keys below)
    report.json     Report
    preview/*.png   pictures of the result
    keyframes.jpg   the key-frames as one picture (``monoavatar view`` shows them), tiles row
                    by row (:func:`~monoavatar.io.viewer_page.keyframe_atlas`)
    ground_truth.npz  for a synth input: ``vertex_error_m`` (V,) each avatar vertex's distance
                    to the ground-truth surface after alignment, metres

``params.npz`` keys: ``format`` (:data:`FORMAT`); ``body_model`` (identity string); ``shape``
(S,); ``offsets`` (V, 3) canonical metres; ``poses`` (K, J, 3) axis-angle radians per key-frame
(joint 0 = global orientation in world axes); ``translations`` (K, 3) metres;
``frame_indices`` (K,) key-frame indices in the input; ``camera_K`` (3, 3) pixels,
``camera_R`` (3, 3), ``camera_t`` (3,) metres (world → camera, OpenCV); ``image_size``
(width, height); ``world_up`` (3,) the world direction that is up; ``height`` metres;
``scale_known`` (bool); ``lighting_sh`` (3, 9) the SH lighting (world axes) divided out of
``texture.png`` (an albedo texture).

Saving writes every file under a staging folder beside the target and renames them in, so a
failure leaves no partial folder; loading checks the format and says what is wrong with an
older or foreign folder.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
import zipfile
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from monoavatar.core.camera import PinholeCamera
from monoavatar.core.errors import InputFormatError, InputNotFoundError
from monoavatar.core.files import atomic_write_npz, atomic_write_text
from monoavatar.io.export_mesh import read_obj, write_obj

__all__ = [
    "AVATAR_FILES",
    "FORMAT",
    "GROUND_TRUTH_FILE",
    "KEYFRAMES_FILE",
    "AvatarFolder",
    "AvatarFolderError",
    "AvatarParams",
    "FitSummary",
    "GroundTruthSummary",
    "InputSummary",
    "Report",
    "ScaleSummary",
    "ShapeFile",
    "TextureSummary",
]

FORMAT = "monoavatar-reconstruction-1"
"""Format of ``params.npz`` and ``report.json``; a folder of another format is refused."""

AVATAR_FILES = ("avatar.glb", "avatar.obj", "avatar.mtl", "texture.png", "params.npz",
                "report.json")  # fmt: skip
"""The files of an avatar folder (besides ``preview/``)."""
KEYFRAMES_FILE = "keyframes.jpg"
GROUND_TRUTH_FILE = "ground_truth.npz"

STALE_STAGING_S = 600.0
"""A staging folder older than this (seconds) is a dead run's and is removed by the next save."""


class AvatarFolderError(InputFormatError):
    """An avatar folder (or one of its files) is missing, of another format, or malformed."""


def _json_value(value: object) -> object:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value)}")


# -- params.npz -------------------------------------------------------------------------------


@dataclass
class AvatarParams:
    """The avatar's parameters and the key-frames' poses (``params.npz``).

    Attributes:
        body_model: identity string of the body model (``BodyModel.identity``).
        shape: (S,) shape parameters.
        offsets: (V, 3) canonical per-vertex offsets, metres.
        poses: (K, J, 3) axis-angle radians per key-frame; joint 0 in world axes.
        translations: (K, 3) metres.
        frame_indices: (K,) key-frame indices in the input.
        camera: the input's camera (world → camera, OpenCV).
        world_up: (3,) the world direction that is up.
        height_m: the avatar's height, metres.
        scale_known: whether the height was given (else the result is up to scale).
        lighting_sh: (3, 9) SH lighting divided out of the albedo texture, world axes.
    """

    body_model: str
    shape: np.ndarray
    offsets: np.ndarray
    poses: np.ndarray
    translations: np.ndarray
    frame_indices: np.ndarray
    camera: PinholeCamera
    world_up: np.ndarray
    height_m: float
    scale_known: bool
    lighting_sh: np.ndarray | None = None

    def save(self, path: str | Path) -> None:
        """Write ``params.npz`` atomically."""
        cam = self.camera
        arrays: dict[str, np.ndarray] = dict(
            format=np.array(FORMAT), body_model=np.array(self.body_model), shape=self.shape,
            offsets=self.offsets, poses=self.poses, translations=self.translations,
            frame_indices=self.frame_indices, camera_K=cam.K, camera_R=cam.R, camera_t=cam.t,
            image_size=np.array([cam.width, cam.height]), world_up=self.world_up,
            height=np.array(self.height_m), scale_known=np.array(self.scale_known),
        )  # fmt: skip
        if self.lighting_sh is not None:
            arrays["lighting_sh"] = self.lighting_sh
        atomic_write_npz(path, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> AvatarParams:
        """Read ``params.npz``.

        Raises:
            InputNotFoundError: no such file.
            AvatarFolderError: not an npz file, another format, a key missing.
        """
        path = Path(path)
        if not path.is_file():
            raise InputNotFoundError(path, "no params.npz: not a 'monoavatar reconstruct' folder")
        try:
            with np.load(path, allow_pickle=False) as data:
                p = {key: data[key] for key in data.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise AvatarFolderError(path, f"not an npz file ({exc})") from exc
        if "format" not in p:
            raise AvatarFolderError(path, "no format key: written by another program or an "
                                    "older monoavatar; run 'monoavatar reconstruct' again")
        if str(p["format"]) != FORMAT:
            raise AvatarFolderError(path, f"format {str(p['format'])!r}, this monoavatar reads "
                                    f"{FORMAT!r}; run 'monoavatar reconstruct' again")
        needed = ("body_model", "shape", "offsets", "poses", "translations", "frame_indices",
                  "camera_K", "camera_R", "camera_t", "image_size", "world_up", "height",
                  "scale_known")  # fmt: skip
        missing = [key for key in needed if key not in p]
        if missing:
            raise AvatarFolderError(path, f"keys {missing} missing")
        width, height = (int(x) for x in p["image_size"])
        try:
            camera = PinholeCamera(p["camera_K"], p["camera_R"], p["camera_t"], width, height)
            params = cls(
                body_model=str(p["body_model"]),
                shape=np.asarray(p["shape"], dtype=np.float64).reshape(-1),
                offsets=np.asarray(p["offsets"], dtype=np.float64),
                poses=np.asarray(p["poses"], dtype=np.float64),
                translations=np.asarray(p["translations"], dtype=np.float64),
                frame_indices=np.asarray(p["frame_indices"], dtype=np.int64).reshape(-1),
                camera=camera,
                world_up=np.asarray(p["world_up"], dtype=np.float64).reshape(3),
                height_m=float(p["height"]),
                scale_known=bool(p["scale_known"]),
                lighting_sh=(np.asarray(p["lighting_sh"], dtype=np.float64).reshape(3, 9)
                             if "lighting_sh" in p else None),  # fmt: skip
            )
        except ValueError as exc:
            raise AvatarFolderError(path, str(exc)) from exc
        k = len(params.frame_indices)
        if params.offsets.ndim != 2 or params.offsets.shape[1] != 3:
            raise AvatarFolderError(path, f"offsets: expected (V, 3), got {params.offsets.shape}")
        if params.poses.ndim != 3 or params.poses.shape[::2] != (k, 3):
            raise AvatarFolderError(path, f"poses: expected ({k}, J, 3), got {params.poses.shape}")
        if params.translations.shape != (k, 3):
            raise AvatarFolderError(
                path, f"translations: expected ({k}, 3), got {params.translations.shape}"
            )
        return params


# -- report.json ------------------------------------------------------------------------------


@dataclass
class InputSummary:
    """What was reconstructed: ``kind`` is video | images | image | people-snapshot | synth;
    ``image_size`` (width, height) pixels; ``keypoints`` the keypoints' source."""

    path: str
    kind: str
    frames: int
    frame_indices: list[int]
    image_size: list[int]
    keypoints: str


@dataclass
class ScaleSummary:
    """Whether the scale is metric (``known``), the avatar's height (metres) and why."""

    known: bool
    height_m: float
    note: str


MIN_FACE_FRAMES = 3
"""Key-frames with a detected face below which no median face error is reported."""


@dataclass
class FitSummary:
    """Per key-frame (K,) fit measures of the final poses and avatar."""

    keypoint_error_px: list[float]
    silhouette_iou: list[float]
    failed: list[bool]
    median_silhouette_iou: float
    pose_energy: list[float]
    #: per key-frame, the face's error against the detected face-mesh landmarks (median pixel
    #: distance over the outer eye corners' distance; None where no face was detected), None
    #: where no key-frame has a detected face
    face_error: list[float | None] | None = None
    #: the median of ``face_error`` over the good key-frames that have one, where there are
    #: at least :data:`MIN_FACE_FRAMES` (fewer small faces say little)
    median_face_error: float | None = None


@dataclass
class TextureSummary:
    """Whether the texture is albedo, its side in texels, the share of the chart covered."""

    albedo: bool
    size: int
    coverage: float


@dataclass
class GroundTruthSummary:
    """For an input with ground truth: the surface error (mm) after pose and scale alignment,
    and after a similarity transform alone (the benchmark's protocol); how far the avatar's
    rest skeleton's bones are from the truth's (degrees: the median bone, the worst bone and
    its joint's name; None when not measured)."""

    surface_error_mm: float
    surface_error_rigid_mm: float
    bone_angle_median_deg: float | None = None
    bone_angle_max_deg: float | None = None
    bone_angle_worst: str | None = None


def _plain(value: Any) -> Any:
    """JSON-ready: arrays and numpy scalars as lists and Python numbers."""
    return json.loads(json.dumps(value, default=_json_value))


@dataclass
class Report:
    """``report.json``: what was reconstructed, with which settings, how well and how fast.

    ``timings`` maps a stage name to seconds (only stages that ran); ``seconds`` the whole run;
    ``peak_memory_mb`` the process's peak resident memory.
    """

    input: InputSummary
    settings: dict[str, Any]
    scale: ScaleSummary
    fit: FitSummary
    texture: TextureSummary
    warnings: list[str] = field(default_factory=list)
    machine: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    seconds: float = 0.0
    peak_memory_mb: float = 0.0
    ground_truth: GroundTruthSummary | None = None
    format: str = FORMAT

    def to_json(self) -> dict[str, Any]:
        """The JSON object (plain Python types), ``ground_truth`` left out when unknown."""
        out: dict[str, Any] = {"format": self.format}
        for f in fields(self):
            if f.name == "format" or (f.name == "ground_truth" and self.ground_truth is None):
                continue
            value = getattr(self, f.name)
            out[f.name] = _plain(asdict(value) if hasattr(value, "__dataclass_fields__")
                                 else value)  # fmt: skip
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any], path: str | Path = "report.json") -> Report:
        """Parse :meth:`to_json`'s object.

        Raises:
            AvatarFolderError: another format or a section missing or malformed.
        """
        if data.get("format") != FORMAT:
            raise AvatarFolderError(path, f"format {data.get('format')!r}, this monoavatar "
                                    f"reads {FORMAT!r}; run 'monoavatar reconstruct' again")
        try:
            gt = data.get("ground_truth")
            return cls(
                input=InputSummary(**data["input"]),
                settings=dict(data["settings"]),
                scale=ScaleSummary(**data["scale"]),
                fit=FitSummary(**data["fit"]),
                texture=TextureSummary(**data["texture"]),
                warnings=[str(w) for w in data.get("warnings", [])],
                machine=dict(data.get("machine", {})),
                timings={str(k): float(v) for k, v in data.get("timings", {}).items()},
                seconds=float(data.get("seconds", 0.0)),
                peak_memory_mb=float(data.get("peak_memory_mb", 0.0)),
                ground_truth=None if gt is None else GroundTruthSummary(**gt),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise AvatarFolderError(path, f"malformed report ({exc!r})") from exc

    def write(self, path: str | Path) -> None:
        """Write ``report.json`` atomically."""
        atomic_write_text(path, json.dumps(self.to_json(), indent=2))

    @classmethod
    def read(cls, path: str | Path) -> Report:
        path = Path(path)
        if not path.is_file():
            raise InputNotFoundError(path, "no report.json in the avatar folder")
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise AvatarFolderError(path, f"not JSON ({exc})") from exc
        if not isinstance(data, dict):
            raise AvatarFolderError(path, "not a JSON object")
        return cls.from_json(data, path)


# -- the folder -------------------------------------------------------------------------------


@dataclass
class AvatarFolder:
    """One avatar folder in memory.

    Attributes:
        params: ``params.npz``.
        report: ``report.json``.
        vertices: (V, 3) canonical avatar vertices (``avatar.obj``), metres.
        faces: (F, 3) its triangles.
        uv: (T, 2) texture coordinates (glTF convention) and ``face_uv`` (F, 3) their
            indices; None when loaded (``avatar.obj`` is read without them).
        texture: (S, S, 3) uint8 ``texture.png``, or None.
        previews: ``preview/NAME.png`` images (H, W, 3) uint8 to write; empty when loaded.
        extras: further files to write, relative path (one folder level at most, e.g.
            ``maps/normal.png``) → content; empty when loaded.
        path: the folder it was loaded from or saved to.
    """

    params: AvatarParams
    report: Report
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None
    face_uv: np.ndarray | None = None
    texture: np.ndarray | None = None
    previews: dict[str, np.ndarray] = field(default_factory=dict)
    extras: dict[str, bytes] = field(default_factory=dict)
    path: Path | None = None

    def save(self, folder: str | Path, glb: Any = None) -> dict[str, Path]:
        """Write the folder: every file into a staging folder beside ``folder``, then moved in
        (existing result files are replaced). ``glb`` a
        :class:`~monoavatar.io.gltf.SkinnedMesh` for ``avatar.glb``. Returns name → path."""
        from monoavatar.io.gltf import write_avatar_glb

        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        for old in out.glob(".staging-*"):  # left by a run that was killed
            if time.time() - old.stat().st_mtime > STALE_STAGING_S:
                shutil.rmtree(old, ignore_errors=True)
        stage = Path(tempfile.mkdtemp(dir=out, prefix=".staging-"))
        try:
            names: list[str] = []
            if glb is not None:
                write_avatar_glb(stage / "avatar.glb", glb)
                names.append("avatar.glb")
            write_obj(stage / "avatar.obj", self.vertices, self.faces, self.uv, self.face_uv,
                      self.texture)  # fmt: skip
            names.append("avatar.obj")
            if self.texture is not None:
                (stage / "avatar.png").rename(stage / "texture.png")
                (stage / "avatar.mtl").write_text("newmtl skin\nKd 1 1 1\nmap_Kd texture.png\n")
                names += ["avatar.mtl", "texture.png"]
            self.params.save(stage / "params.npz")
            self.report.write(stage / "report.json")
            names += ["params.npz", "report.json"]
            if self.previews:
                (stage / "preview").mkdir()
            for name, image in self.previews.items():
                Image.fromarray(image).save(stage / "preview" / f"{name}.png")
            for name, payload in self.extras.items():
                (stage / name).parent.mkdir(parents=True, exist_ok=True)
                (stage / name).write_bytes(payload)
            files: dict[str, Path] = {}
            for name in self.extras:
                (out / name).parent.mkdir(parents=True, exist_ok=True)
                os.replace(stage / name, out / name)
                files[name] = out / name
            for name in names:
                os.replace(stage / name, out / name)
                files[name] = out / name
            if self.previews:
                (out / "preview").mkdir(exist_ok=True)
                for item in sorted((stage / "preview").iterdir()):
                    os.replace(item, out / "preview" / item.name)
                    files[f"preview/{item.name}"] = out / "preview" / item.name
        finally:
            shutil.rmtree(stage, ignore_errors=True)
        self.path = out
        return files

    @classmethod
    def load(cls, folder: str | Path, *, mesh: bool = True) -> AvatarFolder:
        """Read a folder (``mesh`` False: skip ``avatar.obj``, vertices and faces are empty).

        Raises:
            InputNotFoundError: no such folder, or ``params.npz`` / ``report.json`` /
                ``avatar.obj`` missing.
            AvatarFolderError: a file of another format or malformed.
        """
        folder = Path(folder)
        if not folder.is_dir():
            raise InputNotFoundError(folder, "no such avatar folder")
        params = AvatarParams.load(folder / "params.npz")
        report = Report.read(folder / "report.json")
        vertices, faces = np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        if mesh:
            if not (folder / "avatar.obj").is_file():
                raise InputNotFoundError(folder / "avatar.obj", "no avatar.obj in the folder")
            vertices, faces = read_obj(folder / "avatar.obj")
        texture = None
        if (folder / "texture.png").is_file():
            try:
                texture = np.asarray(Image.open(folder / "texture.png").convert("RGB"))
            except OSError as exc:
                raise AvatarFolderError(folder / "texture.png", f"not an image ({exc})") from exc
        return cls(params, report, vertices, faces, texture=texture, path=folder)


# -- shape.npz --------------------------------------------------------------------------------


@dataclass
class ShapeFile:
    """``shape.npz`` of ``monoavatar fit-shape``: the consensus shape and the poses it was fitted
    with.

    Attributes:
        body_model: identity string; ``shape`` (S,); ``offsets`` (V, 3) metres;
        vertices: (V', 3) canonical vertices, metres; ``faces`` (F, 3);
        frames: (M,) key-frames (indices into the track) the shape was fitted to, and
            ``frame_shifts`` (M, 3) metres, their translation corrections (already in
            ``translations``);
        poses: (K, J, 3) radians and ``translations`` (K, 3) metres of every key-frame.
    """

    body_model: str
    shape: np.ndarray
    offsets: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    frames: np.ndarray
    frame_shifts: np.ndarray
    poses: np.ndarray
    translations: np.ndarray

    def save(self, path: str | Path) -> None:
        atomic_write_npz(path, format=np.array(FORMAT),
                         **{f.name: getattr(self, f.name) for f in fields(self)})

    @classmethod
    def load(cls, path: str | Path) -> ShapeFile:
        path = Path(path)
        if not path.is_file():
            raise InputNotFoundError(path, "no such shape file")
        try:
            with np.load(path, allow_pickle=False) as data:
                if "format" not in data.files or str(data["format"]) != FORMAT:
                    raise AvatarFolderError(path, "not a shape.npz of this monoavatar")
                values = {f.name: data[f.name] for f in fields(cls)}
        except (KeyError, OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise AvatarFolderError(path, f"not a shape file ({exc})") from exc
        values["body_model"] = str(values["body_model"])
        return cls(**values)
