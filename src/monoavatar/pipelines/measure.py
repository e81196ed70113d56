"""``monoavatar measure``: tailor's measurements of an avatar folder, on the body under the
clothes (the body model's shape re-fitted to lie just inside the clothed surface,
:mod:`monoavatar.measure.under`) and on the clothed surface (``avatar.obj``), both in the
canonical rest pose; a JSON file and a picture of where each was taken.

JSON (``measurements.json``): ``format``, ``unit`` (``"m"``, or ``"fraction of height"`` for an
avatar whose scale is unknown: every value divided by the body's height), ``scale_known``,
``note``, then one key per measurement of :data:`~monoavatar.measure.MEASUREMENTS`, each
``{"body": value, "clothed": value}`` (null where a value cannot be taken).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch
from PIL import Image

from monoavatar.body import load_body_model_for
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.errors import InputFormatError
from monoavatar.core.files import atomic_path, atomic_write_text
from monoavatar.core.geometry import vertex_normals
from monoavatar.io.avatar_folder import AvatarFolder
from monoavatar.measure import (
    MEASUREMENTS,
    Measurement,
    MeasureSettings,
    body_under_clothes,
    measure_mesh,
    transfer_parts,
    vertex_parts,
)
from monoavatar.measure.under import UnderSettings, fit_body_under_clothes
from monoavatar.pipelines.stages import PipelineError
from monoavatar.render import rasterize, render_normals

__all__ = ["FORMAT", "UNDER", "MeasureConfig", "MeasureResult", "measure_folder",
           "measurements_picture"]

FORMAT = "monoavatar-measurements-1"

_COLOURS = {
    "height": (90, 90, 90), "chest": (220, 60, 60), "waist": (240, 150, 30),
    "hip": (200, 170, 0), "neck": (120, 70, 200), "upper_arm": (40, 150, 220),
    "thigh": (30, 170, 90), "calf": (0, 120, 120), "shoulder_width": (200, 60, 160),
    "arm_length": (60, 90, 220), "inseam": (150, 100, 50),
}  # fmt: skip


@dataclass
class MeasureResult:
    """Measurements of one avatar folder.

    Attributes:
        values: name → {"body": v, "clothed": v}, in ``unit`` (None: not measurable).
        unit: ``"m"`` or ``"fraction of height"``.
        scale_known: whether the avatar is metric.
        body_height_m: the body's height in the avatar's units (metres when scale_known).
        files: what was written: ``json``, ``picture``.
    """

    values: dict[str, dict[str, float | None]]
    unit: str
    scale_known: bool
    body_height_m: float
    files: dict[str, Path] = field(default_factory=dict)

    def to_json(self) -> dict[str, object]:
        note = ("metres; the avatar was made with the person's height given"
                if self.scale_known else
                "the avatar's scale is unknown (no height was given when it was made), so each "
                "value is a fraction of the body's height; multiply by the person's height in "
                "metres, or re-run reconstruct/photo with --height")  # fmt: skip
        return {"format": FORMAT, "unit": self.unit, "scale_known": self.scale_known,
                "note": note, **self.values}  # fmt: skip


UNDER = ("fit", "clamp")


@dataclass(frozen=True)
class MeasureConfig:
    """``monoavatar measure``'s settings.

    Attributes:
        under: how the body under the clothes is found: ``"fit"``, the body model's shape
            re-fitted to lie inside the clothed surface (:mod:`monoavatar.measure.under`), or
            ``"clamp"``, the avatar's own shape with only its inward offsets.
        fit: the re-fit's settings.
        definitions: where the measurements are taken.
        picture: write ``preview/measurements.png``.
    """

    under: str = "fit"
    fit: UnderSettings = field(default_factory=UnderSettings)
    definitions: MeasureSettings = field(default_factory=MeasureSettings)
    picture: bool = True

    def validate(self) -> None:
        if self.under not in UNDER:
            raise PipelineError(f"--under must be one of {UNDER}, got {self.under!r}")


def measure_folder(folder: str | Path, json_path: str | Path | None = None,
                   config: MeasureConfig | None = None) -> MeasureResult:  # fmt: skip
    """Measure the avatar of ``folder`` and write ``json_path`` (default
    ``folder/measurements.json``) and, with ``config.picture``,
    ``folder/preview/measurements.png``.

    Raises:
        InputNotFoundError, AvatarFolderError: not an avatar folder.
        InputFormatError: an avatar whose body model has not the joints measurements need.
    """
    config = config or MeasureConfig()
    config.validate()
    folder = Path(folder)
    avatar = AvatarFolder.load(folder)
    params = avatar.params
    body = load_body_model_for(params.body_model)
    try:
        parts = vertex_parts(body.skin_weights.double().numpy(), body.joint_names)
    except ValueError as exc:
        raise InputFormatError(folder / "params.npz", str(exc)) from exc
    with torch.no_grad():
        rest, joints = body.rest_shape(torch.as_tensor(params.shape, dtype=body.dtype)[None])
    rest_v, rest_j = rest[0].double().numpy(), joints[0].double().numpy()
    offsets = np.asarray(params.offsets, float)
    if config.under == "fit":
        _, under, under_j = fit_body_under_clothes(body, params.shape, offsets, config.fit)
    else:
        under = body_under_clothes(rest_v, vertex_normals(rest_v, body.faces).numpy(), offsets)
        under_j = rest_j
    settings = config.definitions
    measured = {
        "body": measure_mesh(under, body.faces.numpy(), parts, under_j, body.joint_names,
                             settings),
        "clothed": measure_mesh(avatar.vertices, avatar.faces,
                                transfer_parts(rest_v, parts, avatar.vertices), rest_j,
                                body.joint_names, settings),
    }  # fmt: skip
    height = measured["body"]["height"].value
    scale = 1.0 if params.scale_known else 1.0 / height
    values = {name: {kind: _plain(measured[kind][name].value * scale) for kind in measured}
              for name in MEASUREMENTS}  # fmt: skip
    result = MeasureResult(values, "m" if params.scale_known else "fraction of height",
                           params.scale_known, height)  # fmt: skip
    out = Path(json_path) if json_path is not None else folder / "measurements.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, json.dumps(result.to_json(), indent=2) + "\n")
    result.files["json"] = out
    if config.picture:
        image = measurements_picture(avatar.vertices, avatar.faces, measured["clothed"],
                                     result)  # fmt: skip
        path = folder / "preview" / "measurements.png"
        path.parent.mkdir(exist_ok=True)
        with atomic_path(path) as tmp:
            Image.fromarray(image).save(tmp, format="PNG")
        result.files["picture"] = path
    return result


def _plain(value: float) -> float | None:
    return round(float(value), 4) if np.isfinite(value) else None


def measurements_picture(vertices: np.ndarray, faces: np.ndarray,
                         measured: dict[str, Measurement], result: MeasureResult,
                         size: int = 560) -> np.ndarray:  # fmt: skip
    """(size, 2·size + legend, 3) uint8: the mesh (V, 3) from the front and from its left
    side, grey, each measurement drawn on it in its colour, and a legend with the values."""
    centre = 0.5 * (vertices.min(0) + vertices.max(0))
    extent = float(np.ptp(vertices[:, 1]))
    panels = []
    for direction in (np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])):
        eye = centre + 6.0 * extent * direction
        focal = 6.0 * size / 1.15
        cam = PinholeCamera.look_at(eye, centre, np.array([0.0, 1.0, 0.0]), focal, size, size)
        frags = rasterize(torch.as_tensor(vertices), torch.as_tensor(faces), cam)
        normals = render_normals(torch.as_tensor(vertices), torch.as_tensor(faces), frags,
                                 cam).numpy()  # fmt: skip
        shade = np.clip(-normals[..., 2], 0, 1) * 0.55 + 0.35
        image = np.where(frags.mask.numpy()[..., None], shade[..., None], 0.97)
        canvas = np.ascontiguousarray((np.repeat(image, 3, axis=2) * 255).astype(np.uint8))
        for name, m in reversed(measured.items()):  # torso girths over the limbs
            for line in m.drawing:
                if len(line) < 2 or not np.isfinite(line).all():
                    continue
                px, _ = cam.project(torch.as_tensor(line))
                pts = np.round(px.numpy() * 4).astype(np.int32)  # 2 bits of sub-pixel shift
                cv2.polylines(canvas, [pts], False, _COLOURS[name], 2, cv2.LINE_AA, shift=2)
        panels.append(canvas)
    legend = np.full((size, 300, 3), 247, np.uint8)
    unit = "cm" if result.scale_known else "% of height"
    cv2.putText(legend, f"body / clothed ({unit})", (12, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.55,
                (0, 0, 0), 1, cv2.LINE_AA)  # fmt: skip
    for row, name in enumerate(MEASUREMENTS):
        vals = result.values[name]
        text = " / ".join("-" if vals[k] is None else f"{100 * vals[k]:.1f}"  # type: ignore[operator]
                          for k in ("body", "clothed"))
        y = 64 + 40 * row
        cv2.line(legend, (12, y - 5), (36, y - 5), _COLOURS[name], 3, cv2.LINE_AA)
        cv2.putText(legend, f"{name.replace('_', ' ')}: {text}", (44, y),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)  # fmt: skip
    return np.concatenate([panels[0], panels[1], legend], axis=1)
