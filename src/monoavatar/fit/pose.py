"""Pose fitting through a video (Sec. B.3.2): one shape and per-frame poses.

Two steps:

1. **Initialisation**: one shape and P = 5 poses fitted jointly on 5 frames spread over the
   start of the sequence, to the 2D keypoints and the silhouettes, with the A-pose prior, soft
   joint limits and, when given, the person's height. Without a height the result is up to
   scale: the shape prior keeps the body near Anny's average height.
2. **Tracking**: with the shape fixed, frames are fitted in short windows, each initialised by a
   constant-velocity prediction from the frames before it (a Kalman-style predictor without the
   covariance, Sec. A.3.4). Energy per frame: robust confidence-weighted keypoints; silhouette
   (Eq. B.4) on a 4-level Gaussian pyramid; A-pose prior; joint limits; temporal smoothness;
   capsule self-penetration of forearms and torso. Frames whose energy jumps are re-fitted from
   alternative starts (turned by half a turn, or with the detector's left/right swapped), and
   flagged when that does not help.

The energy and its optimiser are in :mod:`monoavatar.fit.pose_energy`.
"""

from __future__ import annotations

import json
import math
import time
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from monoavatar.body import BodyModel, lbs
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.errors import InputFormatError, InputNotFoundError, MonoavatarError
from monoavatar.core.landmarks import MEDIAPIPE_MIRROR
from monoavatar.core.threads import torch_threads
from monoavatar.fit import pose_energy as pe
from monoavatar.fit.pose_energy import PoseSettings
from monoavatar.fit.prior import PosePrior, apose_prior
from monoavatar.perception.observations import Observations
from monoavatar.render import rasterize

FORMAT = "monoavatar-poses-1"


class PoseFitError(MonoavatarError, RuntimeError):
    """Pose fitting cannot run on these observations (e.g. too few frames with a person)."""


@dataclass(frozen=True)
class PoseTrack:
    """The result of pose fitting.

    Attributes:
        body_model: identity of the body model (``BodyModel.identity``).
        shape: (S,) shape parameters, fixed over the sequence.
        poses: (N, J, 3) axis-angle joint rotations in radians, local to the parent joint in
            canonical axes; joint 0 is the global orientation in world coordinates.
        translations: (N, 3) root translations in world metres.
        camera: the camera (world → camera, OpenCV convention).
        frame_indices: (N,) index of each frame in its source.
        keypoint_error: (N,) mean distance in pixels between projected model keypoints and
            detections with confidence ≥ ``min_confidence`` (NaN without any).
        silhouette_iou: (N,) IoU of the rendered fitted body with the observed mask.
        energy: (N,) final fitting energy per frame.
        failed: (N,) True for frames without a person or whose fit stayed poor; their pose is
            interpolated from neighbours.
        height: metres, the fitted body's standing height (rest pose, top of head to soles).
        scale_known: whether ``height`` was given (False: the result is up to scale).
        seconds: wall time of the fit.
        timings: seconds per step (``init``, ``track``, ``evaluate``).
    """

    body_model: str
    shape: np.ndarray
    poses: np.ndarray
    translations: np.ndarray
    camera: PinholeCamera
    frame_indices: np.ndarray
    keypoint_error: np.ndarray
    silhouette_iou: np.ndarray
    energy: np.ndarray
    failed: np.ndarray
    height: float
    scale_known: bool
    seconds: float
    timings: dict[str, float] = field(default_factory=dict)

    def save(self, path: str | Path) -> None:
        """Write a ``.npz`` (keys as the attributes; the camera as ``camera_K``, ``camera_R``,
        ``camera_t`` (metres) and ``image_size`` (width, height)), atomically."""
        from monoavatar.core.files import atomic_write_npz

        atomic_write_npz(
            path,
            format=np.array(FORMAT),
            body_model=np.array(self.body_model),
            shape=self.shape,
            poses=self.poses,
            translations=self.translations,
            camera_K=self.camera.K,
            camera_R=self.camera.R,
            camera_t=self.camera.t,
            image_size=np.array([self.camera.width, self.camera.height]),
            frame_indices=self.frame_indices,
            keypoint_error=self.keypoint_error,
            silhouette_iou=self.silhouette_iou,
            energy=self.energy,
            failed=self.failed,
            height=np.array(self.height),
            scale_known=np.array(self.scale_known),
            seconds=np.array(self.seconds),
            timings=np.array(json.dumps(self.timings)),
        )

    @staticmethod
    def load(path: str | Path) -> PoseTrack:
        """Read a ``poses.npz``.

        Raises:
            InputNotFoundError: no such file; InputFormatError: not a poses file of this
            format, a key missing, or arrays whose frame counts disagree.
        """
        path = Path(path)
        if not path.is_file():
            raise InputNotFoundError(path, "no such poses file")
        try:
            with np.load(path, allow_pickle=False) as data:
                if str(data.get("format", "")) != FORMAT:
                    raise InputFormatError(path, "not a monoavatar poses file")
                w, h = (int(v) for v in data["image_size"])
                camera = PinholeCamera(K=data["camera_K"], R=data["camera_R"],
                                       t=data["camera_t"], width=w, height=h)  # fmt: skip
                track = PoseTrack(
                    body_model=str(data["body_model"]),
                    shape=data["shape"],
                    poses=data["poses"],
                    translations=data["translations"],
                    camera=camera,
                    frame_indices=data["frame_indices"],
                    keypoint_error=data["keypoint_error"],
                    silhouette_iou=data["silhouette_iou"],
                    energy=data["energy"],
                    failed=data["failed"],
                    height=float(data["height"]),
                    scale_known=bool(data["scale_known"]),
                    seconds=float(data["seconds"]),
                    timings=json.loads(str(data["timings"])),
                )
        except InputFormatError:
            raise
        except (KeyError, ValueError, TypeError, OSError, EOFError, zipfile.BadZipFile) as exc:
            raise InputFormatError(path, f"not a readable poses file ({exc!r})") from exc
        k = len(track.frame_indices)
        sizes = {"poses": track.poses.shape[:1], "translations": track.translations.shape[:1],
                 "failed": track.failed.shape[:1], "energy": track.energy.shape[:1]}
        if track.poses.ndim != 3 or any(n != (k,) for n in sizes.values()):
            raise InputFormatError(path, f"frame counts disagree: {k} frame indices, {sizes}")
        return track


# -- initial placement ---------------------------------------------------------------------


def world_up(camera: PinholeCamera) -> np.ndarray:
    """The world direction that appears as 'up' in the image (−y of the camera)."""
    up: np.ndarray = camera.R.T @ np.array([0.0, -1.0, 0.0])
    return up / np.linalg.norm(up)


def _turn(up: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about the world direction ``up``."""
    return lbs.axis_angle_to_matrix(torch.from_numpy(up * angle)).numpy()


def _root_rotation(up: np.ndarray, facing: np.ndarray) -> np.ndarray:
    """Axis-angle of the root rotation taking canonical +Y to ``up`` and +Z to ``facing``
    (made orthogonal to ``up``)."""
    y = up / np.linalg.norm(up)
    z = facing - y * (facing @ y)
    z /= np.linalg.norm(z)
    x = np.cross(y, z)
    matrix = np.stack([x, y, z], axis=1)
    return lbs.matrix_to_axis_angle(torch.from_numpy(matrix)).numpy()


def _facing_camera(keypoints: np.ndarray, min_conf: float) -> bool:
    """Whether the person faces the camera: their left shoulder/hip appears right of their
    right one in the image (True when undecidable)."""
    votes = 0.0
    for left, right in ((11, 12), (23, 24), (7, 8)):
        c = min(keypoints[left, 2], keypoints[right, 2])
        if c >= min_conf:
            votes += c * np.sign(keypoints[left, 0] - keypoints[right, 0])
    return votes >= 0


def _place(body_height: float, rest_root: np.ndarray, rest_mid: float, mask: np.ndarray,
           camera: PinholeCamera, yaw: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A first root rotation (3,) and translation (3,) that stand the body upright, facing the
    camera turned by ``yaw`` about the vertical, at the depth where its height matches the
    mask's."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    if len(rows) == 0:
        rows = np.array([0, camera.height - 1])
        cols = np.array([0, camera.width - 1])
    h_px = rows[-1] - rows[0] + 1
    centre = np.array([(cols[0] + cols[-1] + 1) / 2, (rows[0] + rows[-1] + 1) / 2])
    depth = camera.K[1, 1] * body_height / h_px
    origin, direction = camera.pixel_rays(torch.from_numpy(centre[None]))
    d_cam = camera.R @ direction[0].numpy()
    target = origin[0].numpy() + direction[0].numpy() * depth / d_cam[2]
    up = world_up(camera)
    facing = -camera.R.T @ camera.t - target  # towards the camera centre
    root = _root_rotation(up, _turn(up, yaw) @ facing)
    # posed root joint = rest root + translation; aim the body's vertical middle (``rest_mid``,
    # canonical y) at the mask centre
    translation = target - rest_root - up * (rest_mid - rest_root[1])
    return root, translation


# -- the steps -------------------------------------------------------------------------------


def _rest_height(body: BodyModel, shape: Tensor) -> Tensor:
    rest, _ = body.rest_shape(shape[None])
    return rest[0, :, 1].max() - rest[0, :, 1].min()


def fit_initial(
    body: BodyModel, obs: Observations, frame_ids: np.ndarray, settings: PoseSettings,
    prior: PosePrior,
) -> tuple[Tensor, np.ndarray, np.ndarray]:
    """Step 1: one shape and P poses on frames ``frame_ids`` (P,). Returns shape (S,),
    poses (P, J, 3), translations (P, 3)."""
    dtype = body.dtype
    frames = pe.frames_at(obs, frame_ids, settings, dtype)
    shape = body.default_shape(1)[0].clone()
    with torch.no_grad():
        rest, joints = body.rest_shape(shape[None])
        height0 = float(_rest_height(body, shape))
    target_height = settings.height or height0
    ctx = pe.energy_context(body, obs.camera, settings, prior, rest[0], joints[0])
    ids = pe.subset_ids(body, settings.silhouette_points, settings.seed)
    sub = pe.make_subset(body, rest[0], joints[0], ids)
    p = len(frame_ids)
    facing = _facing_camera(obs.keypoints[frame_ids[0]], settings.min_confidence)
    base = 0.0 if facing else math.pi

    # (a) rigid placement: try four headings, keep the best after a short rigid fit
    best: tuple[float, pe.Variables] | None = None
    for yaw in (base, base + 0.5 * math.pi, base - 0.5 * math.pi, base + math.pi):
        rest_mid = float(rest[0, :, 1].max() + rest[0, :, 1].min()) / 2
        root, trans = _place(target_height, joints[0, 0].numpy(), rest_mid,
                             obs.masks[frame_ids[0]], obs.camera, yaw)  # fmt: skip
        pose = np.zeros((p, body.num_joints, 3))
        pose[:, 0] = root
        pose[:, 1:] = prior.mean.reshape(-1, 3).numpy()
        var = pe.Variables(pose, np.repeat(trans[None], p, 0), dtype)
        var.body.requires_grad_(False)

        def rigid(var: pe.Variables = var) -> Tensor:
            return pe.weighted_energy(ctx, pe.energy_terms(ctx, sub, var, frames)).sum()

        pe.lbfgs([var.delta, var.translation], rigid, 15)
        with torch.no_grad():
            value = float(rigid())
        if best is None or value < best[0]:
            best = (value, var)
    assert best is not None
    var = best[1]
    var.body.requires_grad_(True)
    shape_p = shape.clone().requires_grad_(True)

    # (b) poses, then shape and poses together
    def energy(with_shape: bool) -> Tensor:
        s = shape_p if with_shape else shape_p.detach()
        rest_v, rest_j = body.rest_shape(s[None])
        sub_s = pe.make_subset(body, rest_v[0], rest_j[0], ids)
        total = pe.weighted_energy(ctx, pe.energy_terms(ctx, sub_s, var, frames)).sum()
        if with_shape:
            total = total + settings.shape_prior_weight * p * (s**2).sum()
            if settings.height is not None:
                h = rest_v[0, :, 1].max() - rest_v[0, :, 1].min()
                total = total + settings.height_weight * p * (h - settings.height) ** 2
        return total

    pe.lbfgs(var.params, lambda: energy(False), settings.init_iterations // 2)
    pe.lbfgs([*var.params, shape_p], lambda: energy(True), settings.init_iterations)
    poses, trans = var.numpy()
    return shape_p.detach(), poses, trans


def facing_yaw(roots: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(N,) radians: the direction each root rotation (N, 3) (axis-angle) turns the body's
    front (canonical +Z) to, about the world direction ``up`` (3,), from a fixed reference."""
    y = up / np.linalg.norm(up)
    a = np.cross(y, [1.0, 0.0, 0.0] if abs(y[0]) < 0.9 else [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(y, a)
    front = lbs.axis_angle_to_matrix(torch.as_tensor(roots, dtype=torch.float64)).numpy()[:, :, 2]
    return np.arctan2(front @ b, front @ a)


def half_turn_flips(yaw: np.ndarray, penalty: float) -> np.ndarray:
    """(N,) bool: the frames to turn by half a turn so that the facing ``yaw`` (N,) (radians,
    frames in time order) changes least: the Viterbi path over "as fitted" and "turned by π"
    minimising Σ |Δyaw| between neighbours (wrapped to ±π) + ``penalty`` radians per turned
    frame. A fit that faces the wrong way between two that face right costs about 2π as
    fitted and 2·|Δyaw| + ``penalty`` turned."""
    n = len(yaw)
    if n < 3:
        return np.zeros(n, dtype=bool)
    turn = np.array([0.0, math.pi])
    cost = np.array([0.0, penalty])
    back = np.zeros((n, 2), dtype=np.int64)
    for i in range(1, n):
        step = yaw[i] + turn[None, :] - yaw[i - 1] - turn[:, None]  # (from, to)
        total = cost[:, None] + np.abs((step + math.pi) % (2 * math.pi) - math.pi)
        back[i] = np.argmin(total, axis=0)
        cost = total[back[i], [0, 1]] + np.array([0.0, penalty])
    states = np.zeros(n, dtype=np.int64)
    states[-1] = int(np.argmin(cost))
    for i in range(n - 1, 0, -1):
        states[i - 1] = back[i, states[i]]
    return states.astype(bool)


def _predict(poses: list[np.ndarray], trans: list[np.ndarray], steps: int) -> tuple[np.ndarray,
                                                                                   np.ndarray]:
    """Constant-velocity prediction of ``steps`` further frames from the fitted ones: the root
    keeps turning at its last rate, the body keeps its last pose, the translation its velocity."""
    last, last_t = poses[-1], trans[-1]
    out_p = np.repeat(last[None], steps, 0)
    if len(poses) < 2:
        return out_p, np.repeat(last_t[None], steps, 0)
    r_last = lbs.axis_angle_to_matrix(torch.from_numpy(last[0])).numpy()
    r_prev = lbs.axis_angle_to_matrix(torch.from_numpy(poses[-2][0])).numpy()
    delta = r_last @ r_prev.T
    dt = trans[-1] - trans[-2]
    out_t = np.empty((steps, 3))
    r = r_last
    for k in range(steps):
        r = delta @ r
        out_p[k, 0] = lbs.matrix_to_axis_angle(torch.from_numpy(r)).numpy()
        out_t[k] = last_t + dt * (k + 1)
    return out_p, out_t


def _history(poses: dict[int, np.ndarray], trans: dict[int, np.ndarray], dtype: torch.dtype,
             count: int = 2) -> tuple[Tensor, Tensor, Tensor] | None:  # fmt: skip
    done = sorted(poses)[-count:]
    if not done:
        return None
    p = torch.as_tensor(np.stack([poses[i] for i in done]), dtype=dtype)
    t = torch.as_tensor(np.stack([trans[i] for i in done]), dtype=dtype)
    return lbs.axis_angle_to_matrix(p[:, 0]), p[:, 1:], t


def fit_poses(
    body: BodyModel,
    obs: Observations,
    settings: PoseSettings | None = None,
    *,
    progress: bool = False,
) -> PoseTrack:
    """Fit one shape and a pose per frame to perception results (Sec. B.3.2).

    Args:
        body: the body model (e.g. ``load_body_model("anny")``).
        obs: masks and 2D keypoints of N frames, with the camera.
        settings: options (default :class:`PoseSettings`).
        progress: show progress bars.
    Raises:
        PoseFitError: fewer than 2 frames with a person.
    """
    settings = settings or PoseSettings()
    with torch_threads(settings.threads):
        return _fit_poses(body, obs, settings, progress)


def _fit_poses(body: BodyModel, obs: Observations, settings: PoseSettings,
               progress: bool) -> PoseTrack:  # fmt: skip
    start = time.perf_counter()
    n = len(obs)
    usable = np.flatnonzero(~obs.no_person)
    if len(usable) < 2:
        raise PoseFitError(
            f"pose fitting needs at least 2 frames with a person, found {len(usable)} of {n}"
        )
    dtype = body.dtype
    prior = apose_prior(body)
    timings: dict[str, float] = {}

    # step 1: initialisation on P frames spread over the start of the sequence
    span = max(settings.init_frames, int(round(settings.init_span * len(usable))))
    pick = np.unique(np.round(np.linspace(0, min(span, len(usable)) - 1,
                                          settings.init_frames)).astype(int))  # fmt: skip
    init_ids = usable[pick]
    shape, init_poses, init_trans = fit_initial(body, obs, init_ids, settings, prior)
    timings["init"] = time.perf_counter() - start

    # step 2: tracking in windows with the shape fixed
    t0 = time.perf_counter()
    with torch.no_grad():
        rest, joints = body.rest_shape(shape[None])
    ctx = pe.energy_context(body, obs.camera, settings, prior, rest[0], joints[0])
    ids = pe.subset_ids(body, settings.silhouette_points, settings.seed)
    sub = pe.make_subset(body, rest[0], joints[0], ids)
    known = {int(i): (init_poses[k], init_trans[k]) for k, i in enumerate(init_ids)}
    poses: dict[int, np.ndarray] = {}
    trans: dict[int, np.ndarray] = {}
    energy = np.full(n, np.nan)
    history: list[float] = []
    windows = [usable[i : i + settings.window] for i in range(0, len(usable), settings.window)]
    bar = tqdm(windows, desc="fit poses", unit="window", disable=not progress)
    for window in bar:
        done = sorted(poses)
        if done:
            pred_p, pred_t = _predict([poses[i] for i in done[-2:]],
                                      [trans[i] for i in done[-2:]], len(window))  # fmt: skip
        else:  # first window: the init frames' poses, predicted forward in between
            first = known[int(window[0])]
            pred_p = np.repeat(first[0][None], len(window), 0)
            pred_t = np.repeat(first[1][None], len(window), 0)
            for k, i in enumerate(window):
                if int(i) in known:
                    pred_p[k], pred_t[k] = known[int(i)]
                elif k > 0:
                    p1, t1 = _predict(list(pred_p[max(0, k - 2) : k]),
                                      list(pred_t[max(0, k - 2) : k]), 1)  # fmt: skip
                    pred_p[k], pred_t[k] = p1[0], t1[0]
        frames = pe.fix_swaps(ctx, sub, pe.frames_at(obs, window, settings, dtype), pred_p, pred_t)
        hist = _history(poses, trans, dtype)
        p_out, t_out, e_out = pe.fit_window(ctx, sub, frames, pred_p, pred_t, hist)
        # re-fit frames whose energy jumped
        reference = float(np.median(history)) if history else float(np.median(e_out))
        bad = np.flatnonzero(e_out > settings.refit_factor * max(reference, 0.5))
        for k in bad:
            p_out[k], t_out[k], e_out[k] = refit_frame(
                ctx, sub, pe.frame_slice(frames, k), p_out[k], t_out[k], float(e_out[k])
            )
        for k, i in enumerate(window):
            poses[int(i)], trans[int(i)], energy[int(i)] = p_out[k], t_out[k], e_out[k]
        history.extend(e_out.tolist())
        bar.set_postfix(energy=f"{np.median(e_out):.2f}")
    timings["track"] = time.perf_counter() - t0
    if settings.flip_penalty_deg is not None:
        t0 = time.perf_counter()
        _turn_back_flips(ctx, sub, obs, math.radians(settings.flip_penalty_deg), poses, trans,
                         energy)  # fmt: skip
        timings["flips"] = time.perf_counter() - t0

    all_poses = np.zeros((n, body.num_joints, 3))
    all_trans = np.zeros((n, 3))
    failed = np.ones(n, bool)
    # a frame failed when its energy is both high and far above the sequence's typical one
    limit = max(settings.fail_energy, settings.refit_factor * float(np.nanmedian(energy)))
    for i in range(n):
        if i in poses:
            all_poses[i], all_trans[i] = poses[i], trans[i]
            failed[i] = not energy[i] <= limit
    _interpolate_failed(all_poses, all_trans, failed)

    t0 = time.perf_counter()
    kp_err, iou = evaluate_fit(body, shape, all_poses, all_trans, obs, settings.min_confidence)
    timings["evaluate"] = time.perf_counter() - t0
    with torch.no_grad():
        height = float(_rest_height(body, shape))
    return PoseTrack(
        body_model=body.identity,
        shape=shape.double().numpy(),
        poses=all_poses,
        translations=all_trans,
        camera=obs.camera,
        frame_indices=obs.frame_indices,
        keypoint_error=kp_err,
        silhouette_iou=iou,
        energy=energy,
        failed=failed,
        height=height,
        scale_known=settings.height is not None,
        seconds=time.perf_counter() - start,
        timings=timings,
    )


def fit_photo(body: BodyModel, obs: Observations, settings: PoseSettings | None = None
              ) -> PoseTrack:  # fmt: skip
    """Fit one shape and one pose to a single photograph (frame 0 of ``obs``): step 1 on that
    frame alone, then one window fit with the shape fixed, re-fitted from alternative starts
    when the energy stays high (Sec. B.3.2, with N = 1).

    Raises:
        PoseFitError: no person in the photo.
    """
    settings = settings or PoseSettings()
    if len(obs) < 1 or bool(obs.no_person[0]):
        raise PoseFitError("no person was found in the photo")
    start = time.perf_counter()
    with torch_threads(settings.threads):
        prior = apose_prior(body)
        frame_ids = np.array([0])
        shape, poses, trans = fit_initial(body, obs, frame_ids, settings, prior)
        with torch.no_grad():
            rest, joints = body.rest_shape(shape[None])
        ctx = pe.energy_context(body, obs.camera, settings, prior, rest[0], joints[0])
        sub = pe.make_subset(body, rest[0], joints[0],
                             pe.subset_ids(body, settings.silhouette_points, settings.seed))
        frames = pe.frames_at(obs, frame_ids, settings, body.dtype)
        poses, trans, energy = pe.fit_window(ctx, sub, frames, poses, trans, None)
        if energy[0] > settings.fail_energy:
            poses[0], trans[0], energy[0] = refit_frame(ctx, sub, frames, poses[0], trans[0],
                                                        float(energy[0]))  # fmt: skip
        kp_err, iou = evaluate_fit(body, shape, poses, trans, obs, settings.min_confidence)
        with torch.no_grad():
            height = float(_rest_height(body, shape))
    return PoseTrack(
        body_model=body.identity, shape=shape.double().numpy(), poses=poses,
        translations=trans, camera=obs.camera, frame_indices=obs.frame_indices[:1],
        keypoint_error=kp_err, silhouette_iou=iou, energy=energy,
        failed=np.array([not energy[0] <= settings.fail_energy]), height=height,
        scale_known=settings.height is not None, seconds=time.perf_counter() - start,
        timings={"fit": time.perf_counter() - start},
    )  # fmt: skip


def refine_poses(
    body: BodyModel,
    obs: Observations,
    track: PoseTrack,
    offsets: Tensor | np.ndarray,
    settings: PoseSettings | None = None,
    *,
    progress: bool = False,
) -> PoseTrack:
    """Re-fit every frame's pose with the clothed avatar: the track's shape plus per-vertex
    offsets D (the pose ↔ shape alternation after a first consensus shape).

    The first pass tracks with a shape fitted to 5 frames' keypoints; the consensus shape,
    fitted to every frame's silhouette, is closer to the person, and poses fitted with it
    (and with D on the silhouette) unpose rays that agree better. Keypoints stay on the body
    (D moves the surface, not the joints). Each window starts from the track's poses and is
    smoothed against the refined frames before it.

    Args:
        body: the body model the track was fitted with.
        obs: the observations the track was fitted to (same frames).
        track: the first pass; its ``shape`` is kept.
        offsets: (V, 3) canonical offsets D in metres.
        settings: options (``refine_iterations`` L-BFGS iterations per window).
    Returns:
        A new track; ``timings["refine"]`` holds this pass's time.
    """
    settings = settings or PoseSettings()
    with torch_threads(settings.threads):
        return _refine_poses(body, obs, track, offsets, settings, progress)


def _refine_poses(body: BodyModel, obs: Observations, track: PoseTrack,
                  offsets: Tensor | np.ndarray, settings: PoseSettings,
                  progress: bool) -> PoseTrack:  # fmt: skip
    start = time.perf_counter()
    n = len(obs)
    if track.poses.shape[0] != n:
        raise ValueError(f"the track has {track.poses.shape[0]} frames, the observations {n}")
    dtype = body.dtype
    shape = torch.as_tensor(track.shape, dtype=dtype)
    d = torch.as_tensor(offsets, dtype=dtype)
    if d.shape != (body.num_vertices, 3):
        raise ValueError(f"offsets must have shape ({body.num_vertices}, 3), got {tuple(d.shape)}")
    with torch.no_grad():
        rest, joints = body.rest_shape(shape[None])
    ctx = pe.energy_context(body, obs.camera, settings, apose_prior(body), rest[0], joints[0])
    ids = pe.subset_ids(body, settings.silhouette_points, settings.seed)
    sub = replace(pe.make_subset(body, rest[0], joints[0], ids), offsets=d[ids])
    poses, trans = track.poses.copy(), track.translations.copy()
    energy = np.full(n, np.nan)
    usable = np.flatnonzero(~obs.no_person)
    refined_p: dict[int, np.ndarray] = {}
    refined_t: dict[int, np.ndarray] = {}
    windows = [usable[i : i + settings.window] for i in range(0, len(usable), settings.window)]
    for window in tqdm(windows, desc="refine poses", unit="window", disable=not progress):
        frames = pe.fix_swaps(ctx, sub, pe.frames_at(obs, window, settings, dtype), poses[window],
                            trans[window])  # fmt: skip
        hist = _history(refined_p, refined_t, dtype)
        p_out, t_out, e_out = pe.fit_window(ctx, sub, frames, poses[window], trans[window], hist,
                                          settings.refine_iterations)  # fmt: skip
        for k, i in enumerate(window):
            refined_p[int(i)], refined_t[int(i)] = p_out[k], t_out[k]
            poses[i], trans[i], energy[i] = p_out[k], t_out[k], e_out[k]
    seconds = time.perf_counter() - start
    limit = max(settings.fail_energy, settings.refit_factor * float(np.nanmedian(energy)))
    failed = ~(energy <= limit)  # NaN (no person) fails too
    _interpolate_failed(poses, trans, failed)
    kp_err, iou = evaluate_fit(body, shape, poses, trans, obs, settings.min_confidence, d)
    return replace(
        track, poses=poses, translations=trans, keypoint_error=kp_err, silhouette_iou=iou,
        energy=energy, failed=failed, seconds=track.seconds + time.perf_counter() - start,
        timings={**track.timings, "refine": seconds},
    )  # fmt: skip


def _turned(pose: np.ndarray, up: np.ndarray, angle: float) -> np.ndarray:
    """A copy of ``pose`` (J, 3) with its root turned by ``angle`` radians about ``up``."""
    out = pose.copy()
    root = lbs.axis_angle_to_matrix(torch.from_numpy(pose[0])).numpy()
    out[0] = lbs.matrix_to_axis_angle(torch.from_numpy(_turn(up, angle) @ root)).numpy()
    return out


def _turn_back_flips(ctx: pe.EnergyContext, sub: pe.Subset, obs: Observations, penalty: float,
                     poses: dict[int, np.ndarray], trans: dict[int, np.ndarray],
                     energy: np.ndarray) -> None:  # fmt: skip
    """Re-fit, turned by half a turn, the frames whose facing breaks the sequence's turn
    (:func:`half_turn_flips` with ``penalty`` radians), keypoints as detected and exchanged left
    for right; the re-fit replaces the frame's pose unless its energy exceeds
    ``flip_energy_factor`` times the frame's (``poses``, ``trans``, ``energy`` in place)."""
    settings = ctx.settings
    order = sorted(poses)
    up = world_up(ctx.camera)
    flips = half_turn_flips(facing_yaw(np.stack([poses[i][0] for i in order]), up), penalty)
    flipped = [order[k] for k in np.flatnonzero(flips)]
    if not flipped:
        return
    # every flagged frame turned by half a turn, keypoints as detected and exchanged: one batch
    frames = pe.frames_at(obs, np.array(flipped), settings, ctx.body.dtype)
    rows = [k for k in range(len(flipped)) for _ in range(2)]
    starts = np.stack([_turned(poses[flipped[k]], up, math.pi) for k in rows])
    p, t, e = _fit_starts(ctx, sub, frames, rows, [False, True] * len(flipped), starts,
                          np.stack([trans[flipped[k]] for k in rows]), 2 * settings.iterations)
    for k, i in enumerate(flipped):
        best = 2 * k + int(e[2 * k + 1] < e[2 * k])
        if float(e[best]) <= settings.flip_energy_factor * energy[i]:
            poses[i], trans[i], energy[i] = p[best], t[best], float(e[best])


def _fit_starts(ctx: pe.EnergyContext, sub: pe.Subset, frames: pe.Frames, rows: list[int],
                swap: list[bool], poses: np.ndarray, trans: np.ndarray, iterations: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Independent fits from S starts in one batch (:func:`pe.fit_frames`): start k fits frame
    ``rows[k]`` of ``frames`` from ``poses[k]`` (J, 3) and ``trans[k]`` (3,), with that frame's
    keypoints exchanged left for right where ``swap[k]``. Returns poses (S, J, 3),
    translations (S, 3) and energies (S,)."""
    sub_s, frames_s = pe.select_frames(sub, frames, torch.as_tensor(rows, dtype=torch.int64))
    kp = frames_s.keypoints
    kp = torch.where(torch.as_tensor(swap)[:, None, None], kp[:, list(MEDIAPIPE_MIRROR)], kp)
    return pe.fit_frames(ctx, sub_s, pe.Frames(kp, frames_s.targets), poses, trans, iterations)


def refit_frame(ctx: pe.EnergyContext, sub: pe.Subset, frame: pe.Frames, pose: np.ndarray,
                 trans: np.ndarray, value: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Try alternative starts for one frame: turned by half a turn about the vertical (also
    with the keypoints' left and right exchanged), the keypoints exchanged alone, and turned by
    a quarter turn either way (side views, where a fit can stall half-way through a turn),
    fitted side by side in one batch; keep what explains the frame best (judged on the
    keypoints as detected, either way round)."""
    best = (pose, trans, value)
    up = world_up(ctx.camera)
    half = _turned(pose, up, math.pi)
    starts = np.stack([half, half, pose, _turned(pose, up, math.pi / 2),
                       _turned(pose, up, -math.pi / 2)])  # fmt: skip
    p, t, e = _fit_starts(ctx, sub, frame, [0] * 5, [False, True, True, False, False], starts,
                          np.repeat(trans[None], 5, 0), 2 * ctx.settings.iterations)  # fmt: skip
    for k in range(5):  # in this order, a clear improvement only: no flip on a whim
        if float(e[k]) < 0.7 * best[2]:
            best = (p[k], t[k], float(e[k]))
    return best


def _interpolate_failed(poses: np.ndarray, trans: np.ndarray, failed: np.ndarray) -> None:
    """Replace failed frames by the nearest good frame's pose (in place)."""
    good = np.flatnonzero(~failed)
    if len(good) == 0:
        return
    for i in np.flatnonzero(failed):
        j = good[np.argmin(np.abs(good - i))]
        poses[i], trans[i] = poses[j], trans[j]


def evaluate_fit(
    body: BodyModel, shape: Tensor, poses: np.ndarray, translations: np.ndarray,
    obs: Observations, min_confidence: float = 0.3, offsets: Tensor | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame keypoint error (pixels, mean over detections with confidence ≥
    ``min_confidence``; NaN without any) and silhouette IoU of the rendered body with the
    observed mask. Returns (N,), (N,)."""
    n = len(poses)
    kp_err = np.full(n, np.nan)
    iou = np.zeros(n)
    with torch.no_grad():
        for i in range(n):
            out = body(shape=shape[None].to(body.dtype),
                       pose=torch.as_tensor(poses[i : i + 1], dtype=body.dtype),
                       translation=torch.as_tensor(translations[i : i + 1], dtype=body.dtype),
                       offsets=offsets)  # fmt: skip
            px, _ = obs.camera.project(body.keypoints(out.vertices)[0])
            det = obs.keypoints[i]
            ok = (det[:, 2] >= min_confidence) & body.keypoint_valid.numpy()
            if ok.any():
                kp_err[i] = np.linalg.norm(px.numpy()[ok] - det[ok, :2], axis=1).mean()
            frags = rasterize(out.vertices[0], body.faces, obs.camera)
            model = frags.face_id.numpy() >= 0
            union = np.logical_or(model, obs.masks[i]).sum()
            iou[i] = np.logical_and(model, obs.masks[i]).sum() / union if union else 0.0
    return kp_err, iou

