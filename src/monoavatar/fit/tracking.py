"""3D motion of a person through a video by optical flow (Paper A, Sec. A.3).

Scene model (Sec. A.3.1): a body of fixed shape (and canonical offsets D, when an avatar is
given), a pose and translation per frame, a static camera. Each frame is started from the
Kalman filters' prediction (Sec. A.3.4: an extended filter per joint rotation, a linear one on
the translation; :mod:`monoavatar.fit.kalman`) and fitted alone by L-BFGS to (Eq. A.4)

    E = λ_f E_f + λ_c E_c + λ_b E_b + λ_sp E_sp + λ_M E_M + λ_k E_k

* E_f, flow matching (Eq. A.1): the observed forward flow from frame i − 1 to frame i against
  the flow the model's motion renders (:func:`flow_targets`, the flow renderer of
  :mod:`monoavatar.render.flow` at sampled pixels);
* E_c, silhouette coverage (Eq. A.3, as in :mod:`monoavatar.fit.pose_energy`: the model inside
  the observed mask and covering its outline);
* E_b, soft joint limits (A.2), and a weak A-pose prior;
* E_sp, capsule interpenetration of forearms and torso;
* E_M, closeness (A.5, :func:`closeness_energy`): squared differences of the joint rotations
  and the translation from the Kalman filters' prediction for this frame (the default), or
  from the previous frame as in the dissertation;
* E_3d, the detector's metric 3D landmarks (mediapipe's world landmarks) against the model's,
  both relative to the hips (:func:`world_landmark_energy`), where the observations have them:
  they tell a limb reaching towards the camera from one reaching away, which the 2D terms
  cannot. The detector assumes a person of average size; its landmarks are first scaled to
  the body's bone lengths (:func:`rescale_landmarks`);
* E_h, the hips' depth: where the 2D keypoints and the 3D landmarks together put the hips in
  the camera frame (:func:`hip_positions`, a linear least-squares solve per frame, then a
  running median and a Gaussian over frames, :func:`smooth_track`), against the model's hips'
  distance from the camera (:func:`hip_energy`). E_3d is relative to the hips and the 2D terms
  see depth only through the body's apparent size, so without it the track's depth is free to
  wander;
* E_k, mediapipe's 2D keypoints (robust, confidence-weighted) — the dissertation initialised by
  hand; here the keypoints start the track and keep it from drifting.

A frame whose energy jumps is re-fitted from its keypoints (from the previous frame's pose,
and from alternative starts: turned by half a turn, left and right exchanged) and flagged
``failed`` when that does not bring it back. A re-fit that would move the body further from
its predicted place than anyone moves in a frame (``reinit_max_shift``) is refused: the
keypoints alone fix depth only through the body's apparent size, and one bad detection would
otherwise teleport the body and, through the translation filter's velocity, send the frames
after it drifting.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from monoavatar.body import BodyModel, lbs
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.errors import MonoavatarError
from monoavatar.core.geometry import camera_rays, hip_ray_rotations, ray_rotations
from monoavatar.core.landmarks import HIP_LANDMARKS, LIMB_LANDMARKS
from monoavatar.core.threads import torch_threads
from monoavatar.fit import energies
from monoavatar.fit import pose_energy as pe
from monoavatar.fit.kalman import RotationFilter, TranslationFilter
from monoavatar.fit.pose import fit_initial, refit_frame
from monoavatar.fit.pose_energy import PoseSettings
from monoavatar.fit.prior import apose_prior
from monoavatar.perception.observations import Observations
from monoavatar.render.raster import rasterize

__all__ = ["LANDMARK_BONES", "FlowTargets", "MotionTrack", "TrackError", "TrackSettings",
           "closeness_energy", "flow_targets", "hip_energy", "hip_positions", "rescale_landmarks",
           "smooth_landmarks", "smooth_track", "track_motion",
           "world_landmark_energy"]  # fmt: skip


class TrackError(MonoavatarError, ValueError):
    """Tracking cannot run on these observations (one frame, no person)."""


@dataclass
class TrackSettings:
    """Options of :func:`track_motion` (``TrackConfig.track``; ``--no-flow`` and
    ``--no-keypoints`` switch the two terms off).

    Weights multiply energies in percent of the person's height (image terms) and radians
    (closeness); ``pose`` holds the weights shared with the pose fitter.
    """

    pose: PoseSettings = field(default_factory=PoseSettings)
    flow: bool = True
    keypoints: bool = True
    flow_weight: float = 2.0
    flow_sigma: float = 3.0  # Geman-McClure scale, percent of height
    flow_points: int = 400  # pixels of frame i − 1 sampled for E_f
    flow_erode_px: int = 2  # flow within this many pixels of the outline is not trusted
    world: bool = True  # the detector's metric 3D landmarks, where the observations have them
    world_weight: float = 0.3
    world_sigma: float = 10.0  # Geman-McClure scale, centimetres
    world_smooth: float = 2.0  # temporal Gaussian over the 3D landmarks, σ in frames (0: none)
    world_rescale: bool = True  # the 3D landmarks scaled to the body (rescale_landmarks)
    hips: bool = True  # E_h, the hips placed by the 2D keypoints and 3D landmarks
    hips_weight: float = 0.3
    hips_sigma: float = 20.0  # Geman-McClure scale, centimetres
    hips_window: int = 15  # frames of the running median over the per-frame hip positions
    hips_smooth: float = 4.0  # then a Gaussian over frames, σ in frames (0: none)
    closeness_weight: float = 10.0
    closeness_to: str = "prediction"  # "prediction" (the Kalman filters') or "previous" (A.5)
    iterations: int = 20
    rigid_iterations: int = 4
    first_iterations: int = 80
    reinit_factor: float = 3.0  # re-fit a frame whose energy exceeds this × the recent median
    recent: int = 30  # frames in that median
    reinit_max_shift: float = 0.3  # metres: a re-fit this far from the predicted place is refused
    rotation_accel_var: float = 2e-3  # rad²/frame⁴
    rotation_measure_var: float = 1e-3  # rad²
    translation_accel_var: float = 1e-4  # m²/frame⁴
    translation_measure_var: float = 1e-4  # m²

    def __post_init__(self) -> None:
        for name in ("flow_points", "iterations", "first_iterations", "recent", "hips_window"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.closeness_to not in ("prediction", "previous"):
            raise ValueError(f"closeness_to must be 'prediction' or 'previous', "
                             f"got {self.closeness_to!r}")  # fmt: skip
        if self.reinit_factor <= 1.0:
            raise ValueError(f"reinit_factor must be above 1, got {self.reinit_factor}")
        if self.reinit_max_shift <= 0.0:
            raise ValueError(f"reinit_max_shift must be positive, got {self.reinit_max_shift}")


@dataclass(frozen=True)
class MotionTrack:
    """A tracked motion.

    Attributes:
        body_model: ``BodyModel.identity``; shape: (S,) shape parameters.
        poses: (N, J, 3) axis-angle radians, local to the parent in canonical axes (joint 0:
            the global orientation, world axes); translations: (N, 3) metres, world frame (the
            camera's world: ``x_cam = R x + t``).
        energy: (N,) each frame's energy without the flow and closeness terms (NaN: no person).
        failed: (N,) frames without a person, or whose fit stayed bad after re-fitting (their
            pose is the prediction).
        reinitialised: (N,) frames re-fitted from their keypoints after an energy jump.
        frame_indices: (N,) source frame index of each row.
        camera: the camera; seconds: wall time; timings: seconds per step.
    """

    body_model: str
    shape: np.ndarray
    poses: np.ndarray
    translations: np.ndarray
    energy: np.ndarray
    failed: np.ndarray
    reinitialised: np.ndarray
    frame_indices: np.ndarray
    camera: PinholeCamera
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)


# -- the flow term ---------------------------------------------------------------------------


@dataclass(frozen=True)
class FlowTargets:
    """Eq. A.1 at K sampled pixels of frame i − 1: the surface point seen at pixel ``p`` (its
    triangle's vertices ``vertex_ids`` (K, 3), barycentrics ``bary`` (K, 3)) should, in frame
    i, project to ``targets`` = p + F_o(p) (K, 2) pixels. With frame i − 1's pose fixed, the
    rendered forward flow is ``π(Σ_k b_k v_k^i) − p`` (:func:`monoavatar.render.flow.render_flow`
    with the two frames' vertex sets exchanged), so ``|F_o − F_r|² = |π(X_i) − target|²``."""

    vertex_ids: Tensor
    bary: Tensor
    targets: Tensor

    def __len__(self) -> int:
        return int(self.targets.shape[0])


def flow_targets(previous: Tensor, faces: Tensor, camera: PinholeCamera, flow: np.ndarray,
                 mask: np.ndarray, count: int, erode_px: int,
                 seed: int) -> FlowTargets:  # fmt: skip
    """Sample ``count`` pixels where the model posed at frame i − 1 (``previous`` (V, 3) world
    metres) is seen inside the observed mask (H, W) eroded by ``erode_px``, with the observed
    forward flow (H, W, 2) pixels from frame i − 1 to i."""
    import cv2

    frags = rasterize(previous.detach(), faces, camera)
    covered = frags.face_id.numpy() >= 0
    inside: np.ndarray = mask.astype(np.uint8)
    if erode_px > 0:
        kernel = np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8)
        inside = np.asarray(cv2.erode(inside, kernel))
    rows, cols = np.nonzero(covered & (inside > 0))
    if len(rows) > count:
        pick = np.random.default_rng(seed).choice(len(rows), count, replace=False)
        rows, cols = rows[pick], cols[pick]
    face = frags.face_id[rows, cols]
    pixels = np.stack([cols + 0.5, rows + 0.5], axis=1)
    targets = pixels + flow[rows, cols].astype(np.float64)
    dtype = previous.dtype
    return FlowTargets(
        vertex_ids=torch.as_tensor(faces)[face].long(),
        bary=frags.bary[rows, cols].to(dtype),
        targets=torch.as_tensor(targets, dtype=dtype),
    )


def _flow_energy(ctx: pe.EnergyContext, rest: Tensor, weights: Tensor, transforms: Tensor,
                 flow: FlowTargets, scale: Tensor, sigma: float) -> Tensor:  # fmt: skip
    """(1,) robust E_f of one frame: the sampled surface points posed by the joint transforms
    (1, J, 4, 4), projected."""
    ids, inverse = torch.unique(flow.vertex_ids.reshape(-1), return_inverse=True)
    posed = lbs.skin(rest[ids][None], weights[ids], transforms)[0]  # (U, 3)
    corners = posed[inverse.reshape(-1, 3)]  # (K, 3, 3)
    points = (flow.bary[..., None] * corners).sum(1)
    projected, _ = ctx.camera.project(points)
    valid = torch.ones(1, len(flow), dtype=torch.bool)
    return energies.correspondence_energy(projected[None], flow.targets[None], valid, scale,
                                          sigma)  # fmt: skip


# -- the tracker -----------------------------------------------------------------------------


def _history(poses: list[np.ndarray], trans: list[np.ndarray], dtype: torch.dtype
             ) -> tuple[Tensor, Tensor, Tensor] | None:  # fmt: skip
    if not poses:
        return None
    p = torch.as_tensor(np.stack(poses[-2:]), dtype=dtype)
    t = torch.as_tensor(np.stack(trans[-2:]), dtype=dtype)
    return lbs.axis_angle_to_matrix(p[:, 0]), p[:, 1:], t


def track_motion(
    body: BodyModel,
    obs: Observations,
    settings: TrackSettings | None = None,
    *,
    shape: Tensor | np.ndarray | None = None,
    offsets: Tensor | np.ndarray | None = None,
    progress: bool = False,
) -> MotionTrack:
    """Track a person's 3D motion through N frames (Sec. A.3).

    Args:
        body: the body model.
        obs: masks and keypoints of the frames, in order, with the camera; ``obs.flow``
            (N − 1, H, W, 2) forward flow is needed for the flow term.
        settings: options (default :class:`TrackSettings`).
        shape: (S,) the body's shape (an avatar's); None: fitted on the first frames.
        offsets: (V, 3) canonical offsets D of the avatar, metres (None: none).
        progress: show a progress bar.
    Raises:
        TrackError: fewer than 2 frames, no person in the first frames, or the flow term asked
            for without flow.
    """
    settings = settings or TrackSettings()
    n = len(obs)
    if n < 2:
        raise TrackError(f"tracking needs a clip of at least 2 frames, got {n}")
    if obs.no_person.all():
        raise TrackError("no person was found in any frame")
    if settings.flow and (obs.flow is None or len(obs.flow) != n - 1):
        raise TrackError("the flow term needs the observed flow of consecutive frames "
                         "(perceive with flow='dis'), or switch it off")  # fmt: skip
    with torch_threads(settings.pose.threads):
        return _track(body, obs, settings, shape, offsets, progress)


def _start(body: BodyModel, obs: Observations, settings: TrackSettings,
           shape: Tensor | np.ndarray | None) -> tuple[Tensor, np.ndarray, np.ndarray, int]:
    """The shape and the first frame's pose (J, 3) and translation (3,), and that frame."""
    ps = settings.pose
    usable = np.flatnonzero(~obs.no_person)
    first = int(usable[0])
    prior = apose_prior(body)
    if shape is None:
        span = max(ps.init_frames, int(round(ps.init_span * len(usable))))
        pick = np.unique(np.round(np.linspace(0, min(span, len(usable)) - 1,
                                              ps.init_frames)).astype(int))  # fmt: skip
        fitted, poses, trans = fit_initial(body, obs, usable[pick], ps, prior)
        return fitted, poses[0], trans[0], first
    _, poses, trans = fit_initial(body, obs, usable[:1], replace(ps, init_iterations=20), prior)
    return torch.as_tensor(shape, dtype=body.dtype), poses[0], trans[0], first


def smooth_landmarks(world: np.ndarray, sigma: float) -> np.ndarray:
    """3D landmarks (N, 33, 4) (x, y, z, confidence; NaN rows where absent) averaged over
    neighbouring frames with Gaussian weights of σ = ``sigma`` frames times each frame's
    confidence; the confidence becomes the weighted mean confidence. Frames without any
    landmark stay NaN."""
    world = np.asarray(world, dtype=np.float64)
    if sigma <= 0:
        return world.copy()
    n = len(world)
    radius = int(np.ceil(3 * sigma))
    offsets = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 * (offsets / sigma) ** 2)
    present = np.isfinite(world).all(axis=-1)  # (N, 33)
    conf = np.where(present, world[..., 3], 0.0)
    xyz = np.where(present[..., None], world[..., :3], 0.0)
    total = np.zeros((n, world.shape[1]))
    acc = np.zeros((n, world.shape[1], 3))
    weight_sum = np.zeros((n, world.shape[1]))
    for k, o in zip(kernel, offsets, strict=True):
        src = np.clip(np.arange(n) + o, 0, n - 1)
        valid = (np.arange(n) + o >= 0) & (np.arange(n) + o < n)
        w = k * conf[src] * valid[:, None]
        acc += w[..., None] * xyz[src]
        total += w
        weight_sum += k * valid[:, None] * present[src]
    out = np.full_like(world, np.nan)
    ok = total > 0
    out[..., :3][ok] = acc[ok] / total[ok][:, None]
    out[..., 3][ok] = total[ok] / np.maximum(weight_sum[ok], 1e-12)
    out[~present.any(axis=1)] = np.nan
    return out


def _track(body: BodyModel, obs: Observations, settings: TrackSettings,
           shape_in: Tensor | np.ndarray | None, offsets_in: Tensor | np.ndarray | None,
           progress: bool) -> MotionTrack:  # fmt: skip
    start = time.perf_counter()
    ps = settings.pose
    if not settings.keypoints:
        ps = replace(ps, keypoint_weight=0.0)
    dtype = body.dtype
    n = len(obs)
    shape, pose0, trans0, first = _start(body, obs, settings, shape_in)
    timings = {"init": time.perf_counter() - start}
    with torch.no_grad():
        rest, joints = body.rest_shape(shape[None])
    rest, joints = rest[0], joints[0]
    d = (torch.zeros_like(rest) if offsets_in is None
         else torch.as_tensor(offsets_in, dtype=dtype))  # fmt: skip
    if d.shape != rest.shape:
        raise ValueError(f"offsets must have shape {tuple(rest.shape)}, got {tuple(d.shape)}")
    ctx = pe.energy_context(body, obs.camera, ps, apose_prior(body), rest, joints)
    ids = pe.subset_ids(body, ps.silhouette_points, ps.seed)
    sub = replace(pe.make_subset(body, rest, joints, ids), offsets=d[ids])
    surface = rest + d
    faces = body.faces

    poses = np.zeros((n, body.num_joints, 3))
    trans = np.zeros((n, 3))
    energy = np.full(n, np.nan)
    failed = np.asarray(obs.no_person, dtype=bool).copy()
    reinit = np.zeros(n, dtype=bool)
    done_p: list[np.ndarray] = []
    done_t: list[np.ndarray] = []
    rot = RotationFilter.start(pose0, settings.rotation_accel_var, settings.rotation_measure_var)
    tra = TranslationFilter.start(trans0, settings.translation_accel_var,
                                  settings.translation_measure_var)  # fmt: skip
    poses[:first], trans[:first] = pose0, trans0
    landmarks = None
    if settings.world and obs.world_keypoints is not None:
        landmarks = smooth_landmarks(obs.world_keypoints, settings.world_smooth)
        if settings.world_rescale:
            with torch.no_grad():
                model_kp = body.keypoints((rest + d)[None])[0].double().numpy()
            landmarks = rescale_landmarks(landmarks, model_kp, body.keypoint_valid.numpy())
    anchors = None
    if landmarks is not None and settings.hips:
        anchors = smooth_track(hip_positions(obs.keypoints, landmarks, np.asarray(obs.camera.K)),
                               settings.hips_window, settings.hips_smooth)
    clock = {"predict": 0.0, "flow": 0.0, "fit": 0.0, "refit": 0.0}
    bar = tqdm(range(first, n), desc="track", unit="frame", disable=not progress)
    for i in bar:
        t0 = time.perf_counter()
        if i == first:
            pred_p, pred_t = pose0[None], trans0[None]
        else:
            rot, tra = rot.predict(), tra.predict()
            pred_p, pred_t = rot.axis_angle[None], tra.position
        clock["predict"] += time.perf_counter() - t0
        if obs.no_person[i]:
            poses[i], trans[i] = pred_p[0], pred_t[0]
            continue
        t0 = time.perf_counter()
        frames = pe.fix_swaps(ctx, sub, pe.frames_at(obs, np.array([i]), ps, dtype),
                              pred_p, pred_t)  # fmt: skip
        flow = None
        if (settings.flow and obs.flow is not None and i > first and not failed[i - 1]
                and not obs.no_person[i - 1]):  # fmt: skip
            with torch.no_grad():
                rotations = lbs.axis_angle_to_matrix(torch.as_tensor(poses[i - 1], dtype=dtype))
                transforms = sub.transforms(rotations[None],
                                            torch.as_tensor(trans[i - 1], dtype=dtype)[None])
                prev = lbs.skin(surface[None], body.skin_weights, transforms)[0]
            flow = flow_targets(prev, faces, obs.camera, obs.flow[i - 1], obs.masks[i - 1],
                                settings.flow_points, settings.flow_erode_px, ps.seed + i)
            if len(flow) == 0:
                flow = None
        clock["flow"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        history = _history(done_p, done_t, dtype)
        if settings.closeness_to == "prediction" and history is not None:
            history = _history([pred_p[0]], [pred_t[0]], dtype)
        iterations = settings.first_iterations if i == first else settings.iterations
        world = None
        if landmarks is not None and np.isfinite(landmarks[i]).any():
            world = torch.as_tensor(landmarks[i : i + 1], dtype=dtype)
        hips = None
        if anchors is not None and np.isfinite(anchors[i]).all():
            hips = torch.as_tensor(anchors[i : i + 1], dtype=dtype)
        p_i, t_i, e_i = _fit_frame(ctx, sub, frames, pred_p, pred_t, history, flow, surface,
                                   settings, iterations, world, hips)  # fmt: skip
        clock["fit"] += time.perf_counter() - t0
        recent = energy[max(0, i - settings.recent) : i]
        recent = recent[np.isfinite(recent)]
        reference = float(np.median(recent)) if len(recent) else e_i
        if len(recent) and e_i > settings.reinit_factor * max(reference, 0.5):
            t0 = time.perf_counter()
            p_r, t_r, e_r = _refit(ctx, sub, frames, done_p, done_t, p_i, t_i, e_i)
            if np.linalg.norm(t_r - pred_t[0]) <= settings.reinit_max_shift:
                p_i, t_i, e_i = p_r, t_r, e_r
            reinit[i] = True
            clock["refit"] += time.perf_counter() - t0
            if e_i > settings.reinit_factor * max(reference, 0.5) and e_i > ps.fail_energy:
                failed[i] = True
        energy[i] = e_i
        if failed[i]:  # the prediction stands in; the filters carry on without a measurement
            p_i, t_i = pred_p[0], pred_t[0]
        poses[i], trans[i] = p_i, t_i
        if not failed[i]:
            if i == first:
                rot = RotationFilter.start(p_i, settings.rotation_accel_var,
                                           settings.rotation_measure_var)  # fmt: skip
                tra = TranslationFilter.start(t_i, settings.translation_accel_var,
                                              settings.translation_measure_var)  # fmt: skip
            else:
                rot, tra = rot.update(p_i), tra.update(t_i)
            done_p.append(p_i)
            done_t.append(t_i)
        bar.set_postfix(energy=f"{e_i:.2f}")
    timings.update(clock)
    return MotionTrack(
        body_model=body.identity, shape=shape.detach().double().numpy().copy(), poses=poses,
        translations=trans, energy=energy, failed=failed, reinitialised=reinit,
        frame_indices=np.asarray(obs.frame_indices, dtype=np.int64).copy(), camera=obs.camera,
        seconds=time.perf_counter() - start, timings=timings,
    )  # fmt: skip


_LEFT_HIP, _RIGHT_HIP = HIP_LANDMARKS


def closeness_energy(root: Tensor, body: Tensor, translation: Tensor,
                     previous: tuple[Tensor, Tensor, Tensor],
                     translation_scale: float = 0.1) -> Tensor:  # fmt: skip
    """Eq. A.5, closeness to the previous frame: ``|θ_i − θ_{i−1}|² + |σ_i − σ_{i−1}|²`` with
    the root's change measured on SO(3) (radians) and the translation in units of
    ``translation_scale`` metres. root (B, 3, 3), body (B, J − 1, 3), translation (B, 3);
    ``previous`` the last frame's (roots (H, 3, 3), body (H, J − 1, 3), translations (H, 3)),
    of which the last row counts. Returns (B,)."""
    turn = energies.small_rotation_vector(root @ previous[0][-1:].transpose(-1, -2))
    return (((body - previous[1][-1:]) ** 2).sum(dim=(1, 2)) + (turn**2).sum(-1)
            + (((translation - previous[2][-1:]) / translation_scale) ** 2).sum(-1))  # fmt: skip


#: Pairs of mediapipe landmarks whose distance :func:`rescale_landmarks` compares: upper and
#: lower arms and legs, feet, hips, shoulders and the two sides of the torso.
LANDMARK_BONES = ((11, 13), (13, 15), (12, 14), (14, 16), (23, 25), (25, 27), (24, 26), (26, 28),
                  (27, 31), (28, 32), (23, 24), (11, 12), (23, 11), (24, 12))  # fmt: skip


def rescale_landmarks(world: np.ndarray, model: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The detector's metric 3D landmarks (N, 33, 4) (NaN rows where absent) scaled to the
    body's size, since the detector assumes an average person: by the median over frames of
    the median over :data:`LANDMARK_BONES` of the model's bone length (its rest-pose landmarks
    ``model`` (33, 3), metres; ``valid`` (33,) the ones it defines) over the observed one."""
    a = np.array([pair[0] for pair in LANDMARK_BONES])
    b = np.array([pair[1] for pair in LANDMARK_BONES])
    ok = valid[a] & valid[b]
    a, b = a[ok], b[ok]
    model_len = np.linalg.norm(model[b] - model[a], axis=-1)  # (K,)
    seen_len = np.linalg.norm(world[:, b, :3] - world[:, a, :3], axis=-1)  # (N, K)
    ratio = model_len / np.where(seen_len > 1e-6, seen_len, np.nan)  # (N, K)
    ratios = [np.median(row[np.isfinite(row)]) for row in ratio if np.isfinite(row).any()]
    if not ratios:
        return world.copy()
    out = world.copy()
    out[..., :3] *= float(np.median(ratios))
    return out


def world_landmark_energy(keypoints: Tensor, camera: PinholeCamera, observed: Tensor,
                          valid: Tensor, sigma: float) -> Tensor:  # fmt: skip
    """The model's 3D landmarks against a detector's metric ones, both relative to the midpoint
    of the hips: mean over the valid landmarks of the robust ρ(|Δ| / σ), Δ in centimetres.

    The detector sees a crop around the person and gives its landmarks in axes aligned with
    that crop's line of sight (weak perspective); they are turned onto the camera's axes by
    the rotation taking the optical axis to the ray through the model's hips
    (:func:`~monoavatar.core.geometry.ray_rotations`), so a person off the image centre is not
    turned.

    keypoints (B, 33, 3) world metres; observed (B, 33, 4) (x, y, z metres, confidence);
    valid (33,) bool, the landmarks the body model defines. Returns (B,).
    """
    R = torch.as_tensor(camera.R, dtype=keypoints.dtype)
    t = torch.as_tensor(camera.t, dtype=keypoints.dtype)
    cam = keypoints @ R.T + t
    hips = 0.5 * (cam[:, _LEFT_HIP] + cam[:, _RIGHT_HIP])
    rel = cam - hips[:, None]
    turn = ray_rotations(hips.detach())  # (B, 3, 3)
    obs = torch.nan_to_num(observed[..., :3]) @ turn.transpose(-1, -2)
    conf = torch.nan_to_num(observed[..., 3]) * valid.to(keypoints.dtype)
    r2 = ((rel - obs) * 100.0).pow(2).sum(-1)
    return (conf * energies.geman_mcclure(r2, sigma)).sum(-1) / conf.sum(-1).clamp_min(1e-6)


def hip_positions(keypoints: np.ndarray, landmarks: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Where the 2D keypoints and the 3D landmarks put the hips' midpoint in each frame.

    The landmarks, relative to the hips in the hip-ray frame (the camera turned so that its
    axis bisects the two hips' viewing rays, :func:`~monoavatar.core.geometry.ray_rotations`),
    are turned to the camera's axes; the midpoint h is then the point for which each landmark
    h + r_k lies on its keypoint's viewing ray d_k: d_k × (h + r_k) = 0, three linear equations
    per landmark, solved for h in least squares weighted by the keypoints' confidences.

    Args:
        keypoints: (N, 33, 3) x px, y px, confidence.
        landmarks: (N, 33, 4) x, y, z metres about the hips' midpoint in the hip-ray frame,
            confidence (NaN rows: none).
        K: (3, 3) intrinsics, pixels.
    Returns:
        (N, 3) camera frame, metres; NaN rows where fewer than four of the limb landmarks
        (:data:`~monoavatar.core.landmarks.LIMB_LANDMARKS`) are seen (the two hips among
        them) or no landmarks exist.
    """
    idx = np.array(LIMB_LANDMARKS)
    kp = np.asarray(keypoints, dtype=np.float64)
    rel = np.asarray(landmarks, dtype=np.float64)[:, idx, :3]
    rays = camera_rays(np.nan_to_num(kp[..., :2]), K)
    unit = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    turn = hip_ray_rotations(torch.as_tensor(unit)).numpy()  # (N, 3, 3)
    r = np.einsum("nij,nkj->nki", turn, np.nan_to_num(rel))  # (N, K, 3) camera axes
    d = unit[:, idx]  # (N, K, 3)
    zero = np.zeros(d.shape[:2])
    cross = np.stack([np.stack([zero, -d[..., 2], d[..., 1]], -1),
                      np.stack([d[..., 2], zero, -d[..., 0]], -1),
                      np.stack([-d[..., 1], d[..., 0], zero], -1)], -2)  # (N, K, 3, 3)
    conf = np.clip(np.nan_to_num(kp[:, idx, 2]), 0.0, 1.0)
    seen = (conf > 0) & np.isfinite(rel).all(-1)
    w = np.where(seen, conf, 0.0)
    A = np.einsum("nk,nkji,nkjl->nil", w, cross, cross)  # Σ w Cᵀ C
    b = -np.einsum("nk,nkji,nkjl,nkl->ni", w, cross, cross, r)  # −Σ w Cᵀ C r
    out = np.full((len(kp), 3), np.nan)
    ok = (seen.sum(1) >= 4) & seen[:, 6] & seen[:, 7]  # the hips are entries 6 and 7
    if ok.any():
        out[ok] = np.linalg.solve(A[ok], b[ok][..., None])[..., 0]
    return out


def smooth_track(values: np.ndarray, window: int, sigma: float) -> np.ndarray:
    """(N, C) → (N, C): per channel, the median of the finite values among the ``window``
    frames centred on each (shorter at the ends; outliers out), then a Gaussian of σ =
    ``sigma`` frames over those medians (jitter out; 0: none). NaN where a frame's window
    holds no finite row."""
    values = np.asarray(values, dtype=np.float64)
    half = window // 2
    med = np.full_like(values, np.nan)
    for i in range(len(values)):
        chunk = values[max(0, i - half) : i + half + 1]
        rows = chunk[np.isfinite(chunk).all(-1)]
        if len(rows):
            med[i] = np.median(rows, axis=0)
    if sigma <= 0:
        return med
    ok = np.isfinite(med).all(-1)
    frames = np.arange(len(values))
    kernel = np.exp(-0.5 * ((frames[:, None] - frames[None]) / sigma) ** 2) * ok[None]
    out = np.full_like(values, np.nan)
    total = kernel.sum(1)
    out[ok] = (kernel[ok] @ np.nan_to_num(med)) / total[ok, None]
    return out


def hip_energy(keypoints: Tensor, camera: PinholeCamera, hips: Tensor, sigma: float) -> Tensor:
    """The depth of the model's hips' midpoint against a position for it: the robust
    ρ(Δ / σ), Δ the difference of their distances from the camera, centimetres (the 2D terms
    place the hips across the image; this places them along the ray). keypoints (B, 33, 3)
    world metres; hips (B, 3) camera frame, metres. Returns (B,)."""
    R = torch.as_tensor(camera.R, dtype=keypoints.dtype)
    t = torch.as_tensor(camera.t, dtype=keypoints.dtype)
    mid = 0.5 * (keypoints[:, _LEFT_HIP] + keypoints[:, _RIGHT_HIP]) @ R.T + t
    delta = (mid.norm(dim=-1) - hips.norm(dim=-1)) * 100.0
    return energies.geman_mcclure(delta.pow(2), sigma)


def _fit_frame(ctx: pe.EnergyContext, sub: pe.Subset, frames: pe.Frames, pred_p: np.ndarray,
               pred_t: np.ndarray, history: tuple[Tensor, Tensor, Tensor] | None,
               flow: FlowTargets | None, surface: Tensor, settings: TrackSettings, iterations: int,
               world: Tensor | None = None,
               hips: Tensor | None = None) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """One frame by Eq. A.4 from the prediction (1, J, 3), (1, 3). Returns the pose (J, 3),
    translation (3,) and the energy without the flow and closeness terms."""
    var = pe.Variables(pred_p, pred_t, frames.keypoints.dtype)
    weights = ctx.body.skin_weights

    def total() -> Tensor:
        rotations = var.rotations()
        transforms = sub.transforms(rotations, var.translation)
        posed = sub.posed(transforms)
        e = pe.weighted_energy(ctx, pe.energy_terms(ctx, sub, var, frames, posed))
        if history is not None:
            e = e + settings.closeness_weight * closeness_energy(
                rotations[:, 0], var.body, var.translation, history)
        if world is not None:
            e = e + settings.world_weight * world_landmark_energy(
                posed[0], ctx.camera, world, ctx.body.keypoint_valid, settings.world_sigma)
        if hips is not None:
            e = e + settings.hips_weight * hip_energy(posed[0], ctx.camera, hips,
                                                      settings.hips_sigma)
        if flow is not None:
            e = e + settings.flow_weight * _flow_energy(
                ctx, surface, weights, transforms, flow, frames.targets.scale,
                settings.flow_sigma)
        return e.sum()

    if settings.rigid_iterations:
        pe.lbfgs([var.delta, var.translation], total, settings.rigid_iterations)
    pe.lbfgs(var.params, total, iterations)
    with torch.no_grad():
        e = pe.weighted_energy(ctx, pe.energy_terms(ctx, sub, var, frames))
    p, t = var.numpy()
    return p[0], t[0], float(e[0])


def _refit(ctx: pe.EnergyContext, sub: pe.Subset, frames: pe.Frames, done_p: list[np.ndarray],
           done_t: list[np.ndarray], pose: np.ndarray, trans: np.ndarray,
           value: float) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """Re-fit a frame from its keypoints alone: from the last good frame's pose, then from the
    pose fitter's alternative starts; keep the lowest energy."""
    best = (pose, trans, value)
    if done_p:
        p, t, e = pe.fit_window(ctx, sub, frames, done_p[-1][None], done_t[-1][None], None,
                                2 * ctx.settings.iterations)  # fmt: skip
        if float(e[0]) < best[2]:
            best = (p[0], t[0], float(e[0]))
    p_r, t_r, e_r = refit_frame(ctx, sub, frames, best[0], best[1], best[2])
    return (p_r, t_r, e_r) if math.isfinite(e_r) else best
