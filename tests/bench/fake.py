"""A fake ``reconstruct`` for the benchmark's tests: it writes the output folder that
the reconstruction pipeline writes (same files and keys), made from the scene's ground truth,
so that the expected measurements are known.

The fake's body is Anny without local changes with the true phenotype (the first 6 shape
parameters) and offsets that move its rest vertices onto the first vertices of the true clothed
canonical mesh (the subdivided mesh keeps the body model's vertices first, in order), so the
posed fake avatar is the true clothed body at the coarse resolution. Its texture is the true
albedo (same UV layout), flagged as albedo in ``report.json``, with the true lighting as its
``lighting_sh``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from monoavatar.body import BodyModel
from monoavatar.core.camera import PinholeCamera
from monoavatar.io.export_mesh import read_obj, write_obj
from tests.avatar_folders import make_params, make_report

STAGES = ("perception", "poses", "shape", "texture", "export")


class FakeReconstruct:
    """Callable like ``monoavatar.pipelines.reconstruct.reconstruct(input, out_dir, config)``.

    Args:
        body: Anny without local changes (``load_body_model("anny")``).
        anny_local: the scene's body model (``"anny-local"``), for the true rest joints.
        avatar: which mesh ``avatar.obj`` holds: ``"fine"`` the true clothed canonical mesh
            itself, ``"coarse"`` the fake body (shape + offsets), or ``"scaled"`` the true mesh
            scaled by ``scale`` about the origin.
        scale: for ``"scaled"``.
        fail_modes: ``config.input.poses`` values for which it raises instead.
    """

    def __init__(self, body: BodyModel, anny_local: BodyModel, avatar: str = "fine",
                 scale: float = 1.0, fail_modes: tuple[str, ...] = ()) -> None:  # fmt: skip
        self.body = body
        self.anny_local = anny_local
        self.avatar = avatar
        self.scale = scale
        self.fail_modes = fail_modes
        self.calls: list[tuple[Path, Path, object]] = []

    def __call__(self, input_path: Path, out_dir: Path, config: object) -> None:
        self.calls.append((Path(input_path), Path(out_dir), config))
        inputs = getattr(config, "input", None)
        if getattr(inputs, "poses", None) in self.fail_modes:
            raise RuntimeError("fake failure")
        write_fake_reconstruction(Path(input_path), Path(out_dir), self.body, self.anny_local,
                                  int(getattr(inputs, "frames", 2)), self.avatar,
                                  self.scale)  # fmt: skip


def write_fake_reconstruction(scene: Path, out: Path, body: BodyModel, anny_local: BodyModel,
                              keyframes: int, avatar: str = "fine",
                              scale: float = 1.0) -> None:  # fmt: skip
    """Write ``avatar.obj``, ``texture.png``, ``params.npz`` and ``report.json`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    gv, gf = read_obj(scene / "gt" / "subject_000" / "canonical.obj")
    gt = np.load(scene / "gt" / "params.npz")
    camera = json.loads((scene / "camera.json").read_text())
    n = int(gt["poses"].shape[0])
    idx = np.linspace(0, n - 1, keyframes).round().astype(np.int64)
    shape = torch.as_tensor(gt["shapes"][0][: body.shape_dim], dtype=body.dtype)[None]
    with torch.no_grad():
        rest, joints = body.rest_shape(shape)
        _, gt_joints = anny_local.rest_shape(torch.as_tensor(gt["shapes"][:1],
                                                             dtype=anny_local.dtype))  # fmt: skip
    offsets = gv[: body.num_vertices] - rest[0].double().numpy()
    translations = gt["translations"][idx] + (gt_joints[0, 0] - joints[0, 0]).double().numpy()
    if avatar == "fine":
        write_obj(out / "avatar.obj", gv, gf)
    elif avatar == "scaled":
        write_obj(out / "avatar.obj", gv * scale, gf)
    elif avatar == "coarse":
        write_obj(out / "avatar.obj", gv[: body.num_vertices], body.faces.numpy())
    else:
        raise ValueError(avatar)
    texture = np.asarray(Image.open(scene / "gt" / "subject_000" / "canonical.png")
                         .convert("RGB"))  # fmt: skip
    fake_camera = PinholeCamera(np.asarray(camera["K"]), np.asarray(camera["R"]),
                                np.asarray(camera["t"]), camera["width"], camera["height"])
    params = make_params(body.identity, shape[0].double().numpy(), offsets, gt["poses"][idx],
                         translations, fake_camera, frame_indices=idx,
                         height_m=float(np.ptp(gv[:, 1])), lighting_sh=gt["sh"][0])  # fmt: skip
    report = make_report(len(idx), texture_size=texture.shape[1], warnings=["UserWarning: fake"],
                         timings={s: 0.5 + i for i, s in enumerate(STAGES)}, seconds=12.5,
                         peak_memory_mb=321.0)  # fmt: skip
    params.save(out / "params.npz")
    report.write(out / "report.json")
    Image.fromarray(texture).save(out / "texture.png")
