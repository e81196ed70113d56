"""``monoavatar transfer`` (Sec. E.6.5): dress the person of one avatar folder in the clothes of
another by exchanging their UV maps outside the face.

Both folders are ``photo`` or ``reconstruct`` folders of the same body model. Each is brought
into the UV layout of the once-subdivided body: a ``photo`` folder's ``maps/displacement.npz``
as it is; a ``reconstruct`` folder's per-vertex offsets subdivided with the mesh and rasterised
(its normal map from its surface). The new avatar has A's body shape, and per texel the maps
and the texture of A on A's face and of B elsewhere, blended over a few centimetres at the
border; it is written as an avatar folder like ``photo``'s (with A's key-frame poses).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from monoavatar.body import REGIONS, BodyModel, load_body_model_for
from monoavatar.io.avatar_folder import AvatarFolder, Report
from monoavatar.learn.uvmaps import (
    DISPLACEMENT_SCALE,
    UVLayout,
    displacement_targets,
    rasterise_vertex_values,
    sample_vertex_values,
    uv_layout,
)
from monoavatar.pipelines.stages import PipelineError, check_output_folder

__all__ = ["TransferConfig", "TransferResult", "face_weight", "transfer"]


@dataclass
class TransferConfig:
    """Options of :func:`transfer`.

    Attributes:
        map_size: side of the UV maps the folders are brought to, texels.
        border: width of the blend between A's face and B's clothes, in texels of the maps.
    """

    map_size: int = 256
    border: int = 3


@dataclass
class TransferResult:
    folder: Path
    files: dict[str, Path]
    maps: np.ndarray  # (S, S, 6)
    vertices: np.ndarray  # (V_f, 3)


def face_weight(body: BodyModel, layout: UVLayout, size: int, border: int) -> np.ndarray:
    """(size, size) float32 in [0, 1]: 1 on the face region's texels, 0 elsewhere, blurred over
    ``border`` texels (of a ``layout.size`` map) so that the two avatars meet smoothly."""
    import cv2

    face = (body.regions.numpy() == REGIONS.index("face")).astype(np.float64)[:, None]
    fine = layout.subdivision.apply(torch.as_tensor(face)[None].expand(1, -1, 3))[0, :, :1]
    weight = rasterise_vertex_values(layout, fine.numpy())[..., 0]
    if border > 0:
        weight = cv2.GaussianBlur(weight, (0, 0), border)
    weight = np.clip(weight, 0.0, 1.0).astype(np.float32)
    if size != layout.size:
        weight = np.asarray(cv2.resize(weight, (size, size), interpolation=cv2.INTER_LINEAR))
    return weight


def _maps_of(folder: AvatarFolder, body: BodyModel, layout: UVLayout) -> np.ndarray:
    """(S, S, 6) maps of an avatar folder in ``layout`` (displacement / scale, normals)."""
    assert folder.path is not None
    path = folder.path / "maps" / "displacement.npz"
    with torch.no_grad():
        rest, _ = body.rest_shape(torch.as_tensor(folder.params.shape, dtype=body.dtype)[None])
        base = layout.subdivision.apply(rest.double())[0]
        surface = layout.subdivision.apply(rest.double()
                                           + torch.as_tensor(folder.params.offsets))[0]
    if path.is_file():
        with np.load(path, allow_pickle=False) as d:
            disp, normal = d["displacement"], d["normal"]
        if disp.shape[0] != layout.size:
            raise PipelineError(f"{path}: maps of {disp.shape[0]}² texels, expected "
                                f"{layout.size}²")  # fmt: skip
        return np.concatenate([disp / DISPLACEMENT_SCALE, normal], axis=2).astype(np.float32)
    return displacement_targets(layout, base, surface)


def _texture(folder: AvatarFolder, size: int) -> np.ndarray:
    import cv2

    if folder.texture is None:
        return np.full((size, size, 3), 0.7, np.float32)
    tex = folder.texture.astype(np.float32) / 255.0
    if tex.shape[0] != size:
        tex = np.asarray(cv2.resize(tex, (size, size), interpolation=cv2.INTER_LINEAR))
    return tex


def transfer(a_dir: str | Path, b_dir: str | Path, out_dir: str | Path,
             config: TransferConfig | None = None) -> TransferResult:  # fmt: skip
    """Write the avatar of A (its face and body shape) dressed as B into ``out_dir``.

    Raises:
        InputNotFoundError, AvatarFolderError: a folder missing or not an avatar folder;
        PipelineError: folders of different body models, or maps of another size.
    """
    from monoavatar.pipelines.previews import fine_turntable
    from monoavatar.pipelines.stages import fine_skinned_mesh, map_files, map_pictures

    config = config or TransferConfig()
    a = AvatarFolder.load(a_dir, mesh=False)
    b = AvatarFolder.load(b_dir, mesh=False)
    if a.params.body_model != b.params.body_model:
        raise PipelineError(f"the avatars are of different body models "
                            f"({a.params.body_model!r}, {b.params.body_model!r})")  # fmt: skip
    out = Path(out_dir)
    check_output_folder(out)
    body = load_body_model_for(a.params.body_model)
    layout = uv_layout(body, config.map_size)
    w = face_weight(body, layout, layout.size, config.border)[..., None]
    maps = w * _maps_of(a, body, layout) + (1 - w) * _maps_of(b, body, layout)
    normals = maps[..., 3:]
    maps[..., 3:] = normals / np.maximum(np.linalg.norm(normals, axis=2, keepdims=True), 1e-6)
    maps[~layout.chart] = 0.0
    with torch.no_grad():
        rest, _ = body.rest_shape(torch.as_tensor(a.params.shape, dtype=body.dtype)[None])
        base = layout.subdivision.apply(rest.double())[0].numpy()
    fine = base + sample_vertex_values(layout, maps[..., :3] * DISPLACEMENT_SCALE)
    size = max(a.texture.shape[0] if a.texture is not None else 0,
               b.texture.shape[0] if b.texture is not None else 0, 256)  # fmt: skip
    wt = face_weight(body, layout, size, config.border)[..., None]
    texture = wt * _texture(a, size) + (1 - wt) * _texture(b, size)
    texture8 = (np.clip(texture, 0, 1) * 255 + 0.5).astype(np.uint8)
    params = a.params
    params.offsets = fine[: body.num_vertices] - base[: body.num_vertices]
    params.lighting_sh = None
    report = Report(input=a.report.input, settings={"a": str(a_dir), "b": str(b_dir),
                                                     "map_size": config.map_size,
                                                     "border": config.border},
                    scale=a.report.scale, fit=a.report.fit, texture=a.report.texture,
                    warnings=[], machine=a.report.machine)  # fmt: skip
    disp_png, normal_png = map_pictures(maps, layout.chart)
    sub = layout.subdivision
    folder = AvatarFolder(params, report, fine, sub.faces.numpy(), uv=sub.uv.double().numpy(),
                          face_uv=sub.face_uv.numpy(), texture=texture8,
                          previews={"turntable": fine_turntable(fine, layout, texture),
                                    "maps": np.concatenate([disp_png, normal_png], axis=1)},
                          extras=map_files(maps, layout.chart, None))  # fmt: skip
    files = folder.save(out, glb=fine_skinned_mesh(body, layout, a.params.shape, fine, texture8))
    return TransferResult(out, files, maps, fine)
