"""Held-out measurements of a reconstruction: the avatar posed in frames it was not built
from, rendered and compared with the frames, and the root orientation error.

* **Texture PSNR in held-out poses**: on frames that are not key-frames, the avatar (shape,
  offsets, texture and lighting as reconstructed, never changed) is posed by our own tracker,
  :func:`monoavatar.fit.track.track_frames`: the key-frames' poses interpolated in time, then
  refined by the flow rounds on the held-out frame (optical flow from the avatar's render to
  the frame, the outline, and the pose energy on the frame's perception: mediapipe's in the
  estimated modes, the scene's own in the ground-truth-pose mode). Only the poses are fitted
  to the held-out frames (evaluations of avatars from monocular video often refine the test
  frames' poses with the avatar fixed, since estimated test poses are themselves a few degrees
  off); the held-out frames never reach the avatar. The
  avatar is rendered with the reconstruction's camera over a mid-grey background, textured and
  lit as the reconstruction says (see :attr:`SubjectMetrics.texture_lighting`), and compared
  with the ground-truth frame (8-bit, the frame's own noise included) on the pixels of the
  ground-truth person mask (``psnr_db``: missed person pixels count against grey), on the
  pixels covered by both (``psnr_overlap_db``: texture only), and on the pixels covered by
  either (``psnr_union_db``: missed person pixels count against grey and spilled avatar pixels
  against the frame's background, so an outline that is too wide costs as much as one that is
  too narrow; on the person mask alone, spill is free). Two other placements are kept for
  comparison, on the person mask: ``psnr_interpolated_db``, the interpolated poses alone (no
  held-out image used), and ``psnr_true_poses_db``, the ground-truth joint rotations of the
  frame transferred onto the avatar's skeleton (below).
* **The same with the true poses transferred** (``psnr_true_poses_db``): the avatar posed on
  its own skeleton with the ground-truth joint rotations of the frame, applied on top of the
  canonical pose that the surface alignment found (a canonical pose a few degrees off the
  truth's is pose error, which PA-MPJPE measures; ``psnr_rigid_db`` keeps the figure without
  it), and placed by the surface alignment: scaled and turned by its similarity transform,
  with its root joint where that transform puts it in the ground truth's canonical frame,
  carried into the world by the ground-truth root joint's transform of the frame. It is
  rendered with the scene camera; ``docs/decisions.md`` says why it reads lower than the
  tracked figure.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from monoavatar.bench.metrics import BACKGROUND_GREY, SubjectTruth
from monoavatar.eval.alignment import SimilarityTransform
from monoavatar.io.avatar_folder import AvatarFolder

if TYPE_CHECKING:
    from monoavatar.body import BodyModel
    from monoavatar.core.camera import PinholeCamera
    from monoavatar.fit.pose import PoseTrack

# -- posing and rendering -----------------------------------------------------------------------


def _pose(
    body: BodyModel,
    shape: np.ndarray,
    poses: np.ndarray,
    translations: np.ndarray,
    offsets: np.ndarray | None,
    batch: int = 16,
) -> tuple[np.ndarray, np.ndarray]:
    """Posed vertices (K, V, 3) and joints (K, J, 3) of a body, world metres."""
    import torch

    s = torch.as_tensor(shape, dtype=body.dtype).reshape(1, -1)
    d = None if offsets is None else torch.as_tensor(offsets, dtype=body.dtype)
    verts, joints = [], []
    with torch.no_grad():
        for i in range(0, len(poses), batch):
            p = torch.as_tensor(poses[i : i + batch], dtype=body.dtype)
            t = torch.as_tensor(translations[i : i + batch], dtype=body.dtype)
            out = body(shape=s.expand(len(p), -1), pose=p, translation=t, offsets=d)
            verts.append(out.vertices.double().numpy())
            joints.append(out.joints.double().numpy())
    return np.concatenate(verts), np.concatenate(joints)


def _silhouettes(body: BodyModel, vertices: np.ndarray, camera: PinholeCamera,
                 masks: np.ndarray) -> list[float]:  # fmt: skip
    from monoavatar.eval import silhouette_iou
    from monoavatar.render import rasterize

    ious = []
    for v, gt in zip(vertices, masks, strict=True):
        frags = rasterize(v, body.faces, camera)
        ious.append(silhouette_iou((frags.face_id >= 0).numpy(), gt))
    return ious


def _heldout_psnr(
    recon: AvatarFolder,
    body: BodyModel,
    truth: SubjectTruth,
    alignment: SimilarityTransform,
    frames: np.ndarray,
    aligned_pose: np.ndarray | None = None,
) -> _HeldOut:
    """Texture PSNR over the given held-out frames (MSE pooled over frames, 8-bit), and the
    lighting used (see :attr:`SubjectMetrics.texture_lighting`). ``alignment`` maps the
    avatar's canonical frame onto the ground truth's (the surface error's transform); with
    ``aligned_pose`` (J, 3), the avatar's canonical pose is first taken to the truth's by
    those joint rotations and ``alignment`` is the transform that follows them."""
    if recon.texture is None or len(frames) == 0:
        return _HeldOut(None, None, "unlit")
    p = recon.params
    scene = truth.scene
    if not recon.report.texture.albedo:
        lighting, sh = "unlit", None
    elif p.lighting_sh is not None:
        own = _sh_to_world(p.lighting_sh, p.camera.R, scene.camera.R)
        lighting, sh = "estimated", np.repeat(own[None], len(truth.sh), axis=0)
    else:
        lighting, sh = "ground-truth", truth.sh
    gt = scene.ground_truth
    poses = gt.poses[frames]
    if aligned_pose is not None:
        poses = _compose(poses, aligned_pose)
    verts, joints = _pose(body, p.shape, poses, np.zeros((len(frames), 3)),
                          p.offsets)  # fmt: skip
    _, rest_joints = _pose(body, p.shape, np.zeros((1, body.num_joints, 3)),
                           np.zeros((1, 3)), p.offsets)  # fmt: skip
    root_in_truth = alignment.apply(rest_joints[0, :1])[0]  # joint 0: the root
    placed = []
    for k, f in enumerate(frames):
        g = truth.root_transforms[f]
        # the alignment's rotation, conjugated by the root's rotation (both models turn the
        # root by the same axis-angle), then the root carried into the world by the truth's
        turn = g[:3, :3] @ alignment.rotation @ g[:3, :3].T
        relative = (verts[k] - joints[k, 0]) @ turn.T
        placed.append(alignment.scale * relative + g[:3, :3] @ root_in_truth + g[:3, 3])
    pred, covered = _render_heldout(body, np.stack(placed), scene.camera, recon.texture,
                                    None if sh is None else sh[frames])  # fmt: skip
    return _held_out_figures(pred, scene.frames.images[frames], gt.masks[frames], covered,
                             lighting)  # fmt: skip


def _render_heldout(body: BodyModel, vertices: np.ndarray, camera: PinholeCamera,
                    texture: np.ndarray, sh: np.ndarray | None,
                    ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Renders (K, H, W, 3) uint8 of posed avatars (K, V, 3) (the camera's world, metres) with
    a (T, T, 3) uint8 texture, lit by (K, 3, 9) SH (None: unlit) over the grey background,
    and their coverage (K, H, W)."""
    import torch

    from monoavatar.render import rasterize, render_textured

    tex = torch.as_tensor(texture.astype(np.float64) / 255.0)
    renders, covered = [], []
    for k, v in enumerate(vertices):
        frags = rasterize(v, body.faces, camera)
        image = render_textured(v, body.faces, frags, body.uv, body.face_uv, tex,
                                sh=None if sh is None else sh[k],
                                background=BACKGROUND_GREY)  # fmt: skip
        renders.append((np.clip(image.numpy(), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))
        covered.append((frags.face_id >= 0).numpy())
    return np.stack(renders), np.stack(covered)


HELDOUT_TRACK_ROUNDS = 3
"""Flow rounds of the tracker on the held-out frames (as ``reconstruct --flow-rounds``)."""

HELDOUT_TRACK_ITERATIONS = 30
"""L-BFGS iterations per frame and round of that tracker: fixed here, so that the measurement
does not move with ``reconstruct``'s own default (``FlowRefineSettings.iterations``)."""


def _key_track(recon: AvatarFolder) -> PoseTrack:
    """The reconstruction's key-frame poses as a track (flagged frames from ``report.json``)."""
    from monoavatar.fit.pose import PoseTrack

    p = recon.params
    k = len(p.frame_indices)
    failed = np.asarray(recon.report.fit.failed, bool)
    if failed.shape != (k,):
        failed = np.zeros(k, bool)
    nan = np.full(k, np.nan)
    return PoseTrack(
        body_model=p.body_model, shape=p.shape, poses=p.poses,
        translations=p.translations, camera=p.camera, frame_indices=p.frame_indices,
        keypoint_error=nan, silhouette_iou=nan, energy=nan, failed=failed,
        height=float("nan"), scale_known=False, seconds=0.0,
    )  # fmt: skip


@dataclass(frozen=True)
class _Tracked:
    """What :func:`_tracked_psnr` measures: the held-out figures with the interpolated and the
    tracked poses, those poses (K, J, 3) and translations (K, 3) (None without a texture),
    and the tracker's seconds."""

    interpolated: _HeldOut
    tracked: _HeldOut
    seconds: float
    interpolated_poses: tuple[np.ndarray, np.ndarray] | None = None
    tracked_poses: tuple[np.ndarray, np.ndarray] | None = None


def _tracked_psnr(recon: AvatarFolder, body: BodyModel, truth: SubjectTruth,
                  frames: np.ndarray, perception: str, rounds: int,
                  workers: int = 2) -> _Tracked:  # fmt: skip
    """Held-out figures with the avatar tracked into the frames
    (:func:`monoavatar.fit.track.track_frames`, ``rounds`` flow rounds; perception
    ``"mediapipe"`` or ``"ground-truth"``: the scene's own), and with the interpolated poses
    before the flow rounds. (Lit by the true light, an albedo without an estimate is tracked
    with the first held-out frame's light.)"""
    import time
    from dataclasses import replace

    from monoavatar.datasets.synth_scene import read_synth_scene
    from monoavatar.fit.flow_refine import FlowRefineSettings
    from monoavatar.fit.track import track_frames
    from monoavatar.perception import perceive

    p = recon.params
    start = time.perf_counter()
    if recon.texture is None or len(frames) == 0:
        return _Tracked(_HeldOut(None, None, "unlit"), _HeldOut(None, None, "unlit"), 0.0)
    held = read_synth_scene(truth.scene.folder, frames=frames)
    if perception == "ground-truth":
        obs = held.observations
    elif perception == "mediapipe":
        obs = perceive(held.frames, p.camera, use_cache=False)
    else:
        raise ValueError(f"perception must be 'mediapipe' or 'ground-truth', got {perception!r}")
    obs = replace(obs, camera=p.camera)
    if not recon.report.texture.albedo:
        lighting, sh = "unlit", None
    elif p.lighting_sh is not None:
        lighting, sh = "estimated", np.repeat(p.lighting_sh[None], len(frames), axis=0)
    else:
        lighting = "ground-truth"
        sh = np.stack([_sh_to_world(truth.sh[f], truth.scene.camera.R, p.camera.R)
                       for f in frames])  # fmt: skip
    texture = recon.texture.astype(np.float64) / 255.0
    key_track = _key_track(recon)
    figures, poses = [], []
    for n in (0, rounds) if rounds > 0 else (0,):  # 0 rounds: the interpolated poses are it
        track = track_frames(body, obs, held.frames.images, key_track, p.shape, p.offsets,
                             texture, None if sh is None else sh[0], n,
                             FlowRefineSettings(workers=workers,
                                                iterations=HELDOUT_TRACK_ITERATIONS))  # fmt: skip
        verts, _ = _pose(body, p.shape, track.poses, track.translations, p.offsets)
        pred, covered = _render_heldout(body, verts, p.camera, recon.texture, sh)
        figures.append(_held_out_figures(pred, held.frames.images, held.ground_truth.masks,
                                         covered, lighting))  # fmt: skip
        poses.append((track.poses, track.translations))
    return _Tracked(figures[0], figures[-1], time.perf_counter() - start, poses[0], poses[-1])


def _held_out_figures(pred: np.ndarray, truth: np.ndarray, person: np.ndarray,
                      covered: np.ndarray, lighting: str) -> _HeldOut:  # fmt: skip
    """The PSNRs of renders (K, H, W, 3) uint8 against true frames (same), MSE pooled over the
    K frames, on the true person masks (K, H, W), on the pixels that both the masks and the
    renders' coverage (K, H, W) hold, and on those that either holds; with the share of person
    pixels the renders miss and the share of the person mask's squared error on them."""
    from monoavatar.eval import psnr

    both = person & covered
    either = person | covered

    def pooled(mask: np.ndarray) -> float | None:
        if not mask.any():
            return None
        full = np.broadcast_to(mask[..., None], pred.shape)
        return psnr(pred, truth, mask=full)

    missed = person & ~both
    squared = ((pred.astype(np.float64) - truth.astype(np.float64)) ** 2).sum(axis=-1)
    total = float(squared[person].sum())
    return _HeldOut(
        mask_db=pooled(person),
        overlap_db=pooled(both),
        lighting=lighting,
        union_db=pooled(either),
        missed_fraction=float(missed.sum() / person.sum()) if person.any() else None,
        missed_error_share=float(squared[missed].sum() / total) if total > 0 else None,
    )


@dataclass(frozen=True)
class _HeldOut:
    """What :func:`_heldout_psnr` measures: PSNR on the person mask, on the pixels covered
    by both and on those covered by either, the lighting used, the fraction of person pixels
    the render misses, and the share of the squared error (on the person mask) that lies on
    those missed pixels."""

    mask_db: float | None
    overlap_db: float | None
    lighting: str
    union_db: float | None = None
    missed_fraction: float | None = None
    missed_error_share: float | None = None


def _compose(poses: np.ndarray, aligned_pose: np.ndarray) -> np.ndarray:
    """(K, J, 3) local joint rotations ``R_frame @ R_aligned`` for every joint but the root
    (which keeps the frame's): the frame's pose applied on top of the canonical pose that the
    surface alignment found."""
    from scipy.spatial.transform import Rotation

    k, j, _ = poses.shape
    frame = Rotation.from_rotvec(poses.reshape(-1, 3))
    aligned = Rotation.from_rotvec(np.tile(aligned_pose, (k, 1)))
    out = (frame * aligned).as_rotvec().reshape(k, j, 3)
    out[:, 0] = poses[:, 0]
    return out


def _sh_to_world(sh: np.ndarray, rotation_from: np.ndarray, rotation_to: np.ndarray) -> np.ndarray:
    """SH lighting (3, 9) given in the world of a camera with world-to-camera rotation
    ``rotation_from``, expressed in the world of a camera with rotation ``rotation_to`` such
    that the light stays fixed relative to the camera. Exact (band-limited least squares)."""
    import torch

    from monoavatar.render import sh_basis

    m = rotation_from.T @ rotation_to  # direction in the target world → the source world
    if np.allclose(m, np.eye(3), atol=1e-9):
        return np.asarray(sh, dtype=np.float64)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    b_to = sh_basis(torch.as_tensor(d)).numpy()
    b_from = sh_basis(torch.as_tensor(d @ m.T)).numpy()
    # radiance L(d) = b_from(d) @ sh_c must equal b_to(d) @ sh'_c for all d
    solution, *_ = np.linalg.lstsq(b_to, b_from @ np.asarray(sh, dtype=np.float64).T, rcond=None)
    return np.asarray(solution.T)


ROOT_OFF_DEG = 30.0  # a key-frame whose root is further off than this counts as turned wrong


def root_orientation_error_deg(
    fitted_root: np.ndarray, fitted_camera_r: np.ndarray,
    true_root: np.ndarray, true_camera_r: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """(K,) angle in degrees between fitted and true root orientations: axis-angle (K, 3) in
    each one's world, compared in camera axes (``R_cam @ R_root``, with each world's
    world-to-camera rotation (3, 3))."""
    from scipy.spatial.transform import Rotation

    fitted = Rotation.from_matrix(fitted_camera_r) * Rotation.from_rotvec(fitted_root)
    true = Rotation.from_matrix(true_camera_r) * Rotation.from_rotvec(true_root)
    return np.degrees((fitted.inv() * true).magnitude())


def heldout_frames(num_frames: int, keyframes: np.ndarray, limit: int) -> np.ndarray:
    """Up to ``limit`` frames that are not key-frames, evenly spread."""
    rest = np.setdiff1d(np.arange(num_frames), keyframes)
    if len(rest) <= limit:
        return rest
    return rest[np.unique(np.linspace(0, len(rest) - 1, limit).round().astype(int))]
