"""A capture of 1–8 frames through the few-frame network (Paper D, Sec. D.3, bottom-up): the
prediction put into the world of the frames' camera.

The network sees the crops (:func:`~monoavatar.learn.fast_data.crop_views`) and answers in
camera axes about the root; here the root rotation is turned into world axes
(``R_world = Rᶜᵀ R_camera``, Rᶜ the camera's world-to-camera rotation) and each frame's
translation solved from its keypoints (:func:`~monoavatar.learn.fast_model.solve_translation`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from monoavatar.body import BodyModel, lbs
from monoavatar.core.camera import PinholeCamera
from monoavatar.learn.fast_data import crop_views
from monoavatar.learn.fast_model import FastNetwork, solve_translation

__all__ = ["FastCapture", "match_height", "predict_capture", "rest_height"]


@dataclass
class FastCapture:
    """The network's avatar for F frames.

    Attributes:
        shape: (6,) phenotypes β; offsets: (V, 3) metres, canonical frame; code: (L,) the
            offset code z.
        poses: (F, J, 3) axis-angle, the root's in world axes; translations: (F, 3) world
            metres (as :class:`~monoavatar.fit.pose.PoseTrack` keeps them).
        placed: (F,) bool, False where a frame had too few confident keypoints to be placed
            (its translation is copied from the nearest placed frame).
    """

    shape: np.ndarray
    offsets: np.ndarray
    code: np.ndarray
    poses: np.ndarray
    translations: np.ndarray
    placed: np.ndarray


def rest_height(body: BodyModel, shape: np.ndarray, offsets: np.ndarray) -> float:
    """Standing height of ``T(β) + D``, metres (extent along canonical y)."""
    with torch.no_grad():
        rest, _ = body.rest_shape(torch.as_tensor(shape, dtype=body.dtype)[None])
    y = rest[0, :, 1].double().numpy() + offsets[:, 1]
    return float(y.max() - y.min())


def match_height(body: BodyModel, shape: np.ndarray, offsets: np.ndarray, height: float,
                 parameter: str = "height") -> np.ndarray:  # fmt: skip
    """β with its ``parameter`` phenotype set (by bisection over [−1, 1]) so that the body
    with ``offsets`` stands ``height`` metres tall (clamped to the range's ends)."""
    k = body.shape_names.index(parameter)
    lo, hi = -1.0, 1.0
    beta = np.array(shape, dtype=np.float64)
    for _ in range(30):
        beta[k] = 0.5 * (lo + hi)
        if rest_height(body, beta, offsets) < height:
            lo = beta[k]
        else:
            hi = beta[k]
    return beta


def predict_capture(net: FastNetwork, body: BodyModel, masks: np.ndarray, keypoints: np.ndarray,
                    camera: PinholeCamera) -> FastCapture:  # fmt: skip
    """The network's avatar for F frames.

    Args:
        masks: (F, H, W) bool person masks; keypoints: (F, 33, 3) x px, y px, confidence
            (mediapipe order), as perception gives them.
        camera: the frames' camera.
    """
    crops, kps, _ = crop_views(masks, keypoints, net.settings.crop_size)
    device = next(net.parameters()).device
    m = torch.from_numpy(crops.astype(np.float32) / 255.0)[None, :, None].to(device)
    k = torch.from_numpy(kps)[None].to(device)
    with torch.no_grad():
        out = net(m, k)
    beta = out.beta[0].double().cpu()
    offsets = out.offsets[0].double().cpu()
    rotations = out.rotations[0].double().cpu()  # (F, J, 3, 3), root in camera axes
    R = torch.as_tensor(camera.R, dtype=torch.float64)
    world = rotations.clone()
    world[:, 0] = R.T @ rotations[:, 0]
    poses = lbs.matrix_to_axis_angle(world)
    # each frame posed with the root at the camera-frame origin, then shifted onto its keypoints
    cam_pose = lbs.matrix_to_axis_angle(rotations).to(body.dtype)
    with torch.no_grad():
        posed = body(shape=beta.to(body.dtype)[None].expand(len(cam_pose), -1), pose=cam_pose,
                     offsets=offsets.to(body.dtype))  # fmt: skip
        landmarks = body.keypoints(posed.vertices).double()
        root = posed.joints[:, 0].double()
        _, rest_joints = body.rest_shape(beta.to(body.dtype)[None])
    j0 = rest_joints[0, 0].double().numpy()
    translations = np.zeros((len(poses), 3))
    placed = np.zeros(len(poses), bool)
    for i in range(len(poses)):
        points = (landmarks[i] - root[i]).numpy()
        try:
            u = solve_translation(points, keypoints[i], camera.K)
        except ValueError:
            continue
        translations[i] = camera.R.T @ (u - camera.t) - j0
        placed[i] = True
    if placed.any():
        good = np.flatnonzero(placed)
        for i in np.flatnonzero(~placed):
            translations[i] = translations[good[np.argmin(np.abs(good - i))]]
    return FastCapture(shape=beta.numpy(), offsets=offsets.numpy(), code=out.code[0].cpu()
                       .double().numpy(), poses=poses.numpy(), translations=translations,
                       placed=placed)  # fmt: skip
