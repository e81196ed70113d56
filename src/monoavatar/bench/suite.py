"""The benchmark suite: a fixed, versioned list of synthetic turn-around subjects.

Subjects are not stored as data: each is a ``monoavatar synth turnaround`` scene made from a
fixed seed and garment set, generated on first use into ``SCENES_DIR/<name>`` and reused while
its ``scene.json`` records the same settings. Changing a subject, its frame count or image size
changes the figures, so any such change must bump :data:`SUITE_VERSION`.

The split follows Table B.1 of the dissertation: *minimal* clothing (like D-FAUST) and
*clothed* subjects (like BUFF: tight clothes, t-shirt and shorts, long sleeves and trousers,
loose clothes, a skirt). The seeds were picked so that the subjects differ in sex, height,
weight, muscularity and skin tone (each seed's draw is listed in :data:`FULL_SUBJECTS`).

This module imports nothing heavy (the synth generator is imported only to make a scene).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from monoavatar.core.errors import MonoavatarError
from monoavatar.synth.options import CAPTURES, CLOTHING, FORMAT, VARIETIES

if TYPE_CHECKING:
    from monoavatar.body import BodyModel

__all__ = [
    "CATEGORIES",
    "MODES",
    "FULL_SUBJECTS",
    "QUICK_SUBJECTS",
    "SPLITS",
    "SUITE_V2_VERSION",
    "SUITE_VERSION",
    "V2_SUBJECTS",
    "BenchMode",
    "BenchSubject",
    "BenchSuite",
    "SuiteError",
    "ensure_scene",
    "get_suite",
    "scene_is_valid",
]

SUITE_VERSION = 2
"""Version of the suite; bump it whenever a subject, frame count, size or metric setting
changes, so that figures of different versions are never compared as if alike (2: the synth
scenes of :data:`~monoavatar.synth.options.FORMAT` 2, faces painted on each subject's face)."""

CATEGORIES: dict[str, str] = {
    "minimal": "minimal clothing (like D-FAUST)",
    "clothed": "clothed (like BUFF)",
}
"""Subject categories and how the report names them."""


@dataclass(frozen=True)
class BenchMode:
    """How a subject is reconstructed: ``name`` (used in folder names and ``results.json``),
    ``label`` (for tables), and the reconstruction's ``perception``, ``poses`` and ``offsets``
    settings."""

    name: str
    label: str
    perception: str
    poses: str
    offsets: bool = True

    def to_dict(self) -> dict[str, str | bool]:
        return {"name": self.name, "label": self.label, "perception": self.perception,
                "poses": self.poses, "offsets": self.offsets}  # fmt: skip


MODES: tuple[BenchMode, ...] = (
    BenchMode("estimated", "estimated poses", perception="mediapipe", poses="fit"),
    BenchMode("shape-only", "shape only, estimated poses", perception="mediapipe", poses="fit",
              offsets=False),
    BenchMode("gt-poses", "ground-truth poses", perception="ground-truth", poses="ground-truth"),
)
"""The runs per subject (Table B.1's two settings and the baseline). *estimated*: everything
from the frames (mediapipe masks and keypoints, fitted poses). *shape-only*: the same without
per-vertex offsets, the body model's shape alone (the baseline the offsets must beat; like
every run it starts from an empty cache, so its timings stand alone). *gt-poses*: the true
poses with the scene's exact masks (and jittered keypoints), which isolates the shape stage."""


class SuiteError(MonoavatarError, ValueError):
    """Unknown subject names, or a scene folder that cannot be made."""


@dataclass(frozen=True)
class BenchSubject:
    """One subject of the suite.

    Attributes:
        name: unique name, also the scene's folder name (e.g. ``"clothed-skirt-s17"``).
        category: a key of :data:`CATEGORIES`.
        seed: the synth seed (subject, camera, background, lighting and motion all follow it).
        clothing: the synth garment set (:data:`monoavatar.synth.options.CLOTHING`).
        frames: frames of the turn-around scene.
        width: image width, pixels.
        height: image height, pixels.
        keyframes: key-frames the reconstruction is asked to use, spread evenly over the
            scene; the other frames are held out for the texture metric.
        texture_size: texture side in texels, for the scene's ground truth and the
            reconstruction alike.
        capture: how the scene is filmed (:data:`monoavatar.synth.options.CAPTURES`).
        variety: the subject distribution (:data:`monoavatar.synth.options.VARIETIES`).
        from_video: the estimated-pose runs read the scene's ``video.mp4`` with its focal
            length and the subject's height, as a user runs ``reconstruct VIDEO --focal F
            --height H``; otherwise the synth folder's frames (no height given).
    """

    name: str
    category: str
    seed: int
    clothing: str
    frames: int = 120
    width: int = 540
    height: int = 540
    keyframes: int = 30
    texture_size: int = 1024
    capture: str = "studio"
    variety: str = "standard"
    from_video: bool = False

    def __post_init__(self) -> None:
        if self.category not in CATEGORIES:
            raise SuiteError(f"{self.name}: category must be one of {list(CATEGORIES)}")
        if self.clothing not in CLOTHING:
            raise SuiteError(f"{self.name}: clothing must be one of {CLOTHING}")
        if self.capture not in CAPTURES or self.variety not in VARIETIES:
            raise SuiteError(f"{self.name}: capture must be one of {list(CAPTURES)} and variety "
                             f"one of {VARIETIES}")  # fmt: skip
        if not 2 <= self.keyframes < self.frames:
            raise SuiteError(
                f"{self.name}: keyframes must lie in [2, frames) so frames are held out, "
                f"got {self.keyframes} of {self.frames}"
            )

    def synth_settings(self) -> dict[str, Any]:
        """The :class:`~monoavatar.synth.scene.SynthConfig` fields of this subject's scene,
        as ``scene.json`` records them under ``"config"``."""
        return {
            "kind": "turnaround",
            "frames": self.frames,
            "seed": self.seed,
            "width": self.width,
            "height": self.height,
            "clothing": self.clothing,
            "noise": "low",
            "background": None,
            "texture_size": self.texture_size,
            "fps": 30.0,
            "posed_every": 10,
            "capture": self.capture,
            "variety": self.variety,
        }

    def to_dict(self) -> dict[str, object]:
        """JSON-ready description (for ``results.json``)."""
        return {
            "name": self.name,
            "category": self.category,
            "seed": self.seed,
            "clothing": self.clothing,
            "frames": self.frames,
            "size": [self.width, self.height],
            "keyframes": self.keyframes,
            "texture_size": self.texture_size,
            "capture": self.capture,
            "variety": self.variety,
            "from_video": self.from_video,
        }


@dataclass(frozen=True)
class BenchSuite:
    """A versioned list of subjects (``name``: ``"full"`` or ``"quick"``)."""

    version: int
    name: str
    subjects: tuple[BenchSubject, ...]

    def select(self, names: list[str] | tuple[str, ...] | None) -> BenchSuite:
        """The suite restricted to the named subjects (in suite order); None keeps all.

        Raises:
            SuiteError: a name that is not in the suite (the message lists the valid ones).
        """
        if names is None:
            return self
        known = [s.name for s in self.subjects]
        unknown = [n for n in names if n not in known]
        if unknown:
            raise SuiteError(f"unknown subject(s) {unknown}; the {self.name} suite has {known}")
        if not names:
            raise SuiteError("no subject selected")
        wanted = set(names)
        return BenchSuite(self.version, self.name,
                          tuple(s for s in self.subjects if s.name in wanted))  # fmt: skip

    def to_dict(self) -> dict[str, object]:
        return {
            "version": self.version,
            "name": self.name,
            "subjects": [s.to_dict() for s in self.subjects],
        }


def _subject(category: str, clothing: str, seed: int) -> BenchSubject:
    short = "" if clothing == "minimal" else f"-{clothing}"
    return BenchSubject(name=f"{category}{short}-s{seed}", category=category, seed=seed,
                        clothing=clothing)  # fmt: skip


# What each seed draws: sex (Anny's gender phenotype: 0 male, 1 female), height of the clothed
# canonical mesh (hair and shoes included), notable phenotype offsets from Anny's average
# (weight w, muscle m) and skin tone (index 0 = lightest … 5 = darkest). Seeds were chosen
# for adult heights and variety.
FULL_SUBJECTS: tuple[BenchSubject, ...] = (
    _subject("minimal", "minimal", 3),  # m, 1.47 m, w +0.11, skin 5
    _subject("minimal", "minimal", 7),  # f, 1.79 m, lean (w -0.22, m +0.18), skin 3
    _subject("minimal", "minimal", 19),  # m, 1.95 m, heavy (w +0.32), skin 0
    _subject("minimal", "minimal", 37),  # f, 1.84 m, average build, skin 1
    _subject("clothed", "tight", 24),  # m, 1.66 m, muscular (m +0.30), skin 4
    _subject("clothed", "tshirt-shorts", 14),  # f, 1.78 m, m +0.18, skin 2
    _subject("clothed", "longsleeve-trousers", 21),  # f, 1.66 m, thin (w -0.26), skin 5
    _subject("clothed", "loose", 27),  # f, 1.96 m, heavy (w +0.17, m +0.24), skin 0
    _subject("clothed", "skirt", 35),  # m, 1.80 m, thin (w -0.34), skin 1
)
"""The full suite: 4 minimal + 5 clothed subjects, 120 frames at 540 x 540 each, 30 of them
key-frames spread evenly over the turn (the other 90 are held out)."""

QUICK_SUBJECTS: tuple[BenchSubject, ...] = (
    BenchSubject(
        name="quick-tshirt-shorts-s14",
        category="clothed",
        seed=14,
        clothing="tshirt-shorts",
        frames=12,
        width=256,
        height=256,
        keyframes=6,
        texture_size=256,
    ),
)
"""The quick suite (``--quick``): one clothed subject, 12 frames at 256 x 256, 6 key-frames,
256-texel textures; a smoke test, not a measurement."""


SUITE_V2_VERSION = 2
"""Version of suite v2 (:data:`V2_SUBJECTS`); bump it whenever one of its subjects or
settings changes."""

SPLITS = ("dev", "test")
"""Suite v2's splits: ``dev`` subjects to choose settings on, ``test`` subjects run only to
report a finished change."""


def _v2(split: str, category: str, clothing: str, seed: int) -> BenchSubject:
    v1 = _subject(category, clothing, seed)
    return replace(v1, name=f"v2{split}-{v1.name}", capture="phone", variety="wide",
                   from_video=True)  # fmt: skip


V2_SUBJECTS: dict[str, tuple[BenchSubject, ...]] = {
    "dev": (
        _v2("dev", "minimal", "minimal", 5001),
        _v2("dev", "clothed", "tshirt-shorts", 5002),
        _v2("dev", "clothed", "loose", 5003),
        _v2("dev", "clothed", "skirt", 5004),
    ),
    "test": (
        _v2("test", "minimal", "minimal", 6001),
        _v2("test", "minimal", "minimal", 6002),
        _v2("test", "clothed", "tight", 6003),
        _v2("test", "clothed", "tshirt-shorts", 6004),
        _v2("test", "clothed", "longsleeve-trousers", 6005),
        _v2("test", "clothed", "loose", 6006),
        _v2("test", "clothed", "skirt", 6007),
        _v2("test", "clothed", "longsleeve-trousers", 6008),
    ),
}
"""Suite v2 (issue #24): wide subjects (``synth --variety wide``) filmed as a phone would
(``--capture phone``), reconstructed from the video with its focal length and the subject's
height; 120 frames at 540 x 540, 30 key-frames. Seeds 5001–5004 (``dev``) and 6001–6008
(``test``) were taken in order, not picked by their look or their results."""


def get_suite(quick: bool = False, suite: str = "v1", split: str = "test") -> BenchSuite:
    """The full suite v1, the quick one, or a ``split`` of suite v2 (:data:`SPLITS`)."""
    if suite == "v2":
        if split not in SPLITS:
            raise SuiteError(f"unknown split {split!r}; choose from {SPLITS}")
        return BenchSuite(SUITE_V2_VERSION, f"v2-{split}", V2_SUBJECTS[split])
    if suite != "v1":
        raise SuiteError(f"unknown suite {suite!r}; choose from ('v1', 'v2')")
    if quick:
        return BenchSuite(SUITE_VERSION, "quick", QUICK_SUBJECTS)
    return BenchSuite(SUITE_VERSION, "full", FULL_SUBJECTS)


def scene_is_valid(folder: Path, subject: BenchSubject) -> bool:
    """Whether ``folder`` holds a complete scene generated with this subject's settings."""
    try:
        info = json.loads((folder / "scene.json").read_text())
    except (OSError, ValueError):
        return False
    if info.get("format") != FORMAT:
        return False
    # scenes made before the capture profiles and varieties were studio takes of standard
    # subjects
    if {"capture": "studio", "variety": "standard",
            **info.get("config", {})} != subject.synth_settings():  # fmt: skip
        return False
    for sub in ("frames", "masks"):
        if len(list((folder / sub).glob("*.png"))) != subject.frames:
            return False
    needed = ("camera.json", "keypoints.npz", "gt/params.npz", "gt/subject_000/canonical.obj")
    return all((folder / name).is_file() for name in needed)


def ensure_scene(
    subject: BenchSubject,
    scenes_dir: Path,
    progress: bool = False,
    body: BodyModel | None = None,
) -> Path:
    """The subject's scene folder under ``scenes_dir``, generated unless a valid one is there.

    ``body``: the ``"anny-local"`` model (float32) to generate with, to save loading it.

    A folder that exists but is incomplete or was made with other settings is replaced (it is
    the suite's own cache folder, ``scenes_dir/<name>``).
    """
    folder = Path(scenes_dir) / subject.name
    if scene_is_valid(folder, subject):
        return folder
    from monoavatar.synth.scene import SynthConfig, generate

    if folder.exists():
        if folder.is_dir() and ((folder / "scene.json").exists() or not any(folder.iterdir())):
            shutil.rmtree(folder)
        else:
            raise SuiteError(f"{folder} exists and is not a scene folder; move it away")
    config = SynthConfig(**subject.synth_settings())
    generate(folder, config, body=body, progress=progress)
    if not scene_is_valid(folder, subject):
        raise SuiteError(f"generated scene {folder} does not match the suite's settings")
    return folder
