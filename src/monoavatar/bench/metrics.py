"""Per-subject metrics of one reconstruction against its synthetic ground truth.

Inputs are a ``monoavatar reconstruct`` output folder (``avatar.obj``, ``params.npz``,
``texture.png``, ``report.json``) and the ``monoavatar synth`` scene it was made from. The
measurements themselves are :mod:`monoavatar.eval`'s, which shares no code with the
reconstruction; this module only reads files, poses body models and renders.

* **Surface error** (Table B.1): the canonical avatar (``avatar.obj``) is aligned to the
  ground-truth clothed canonical mesh by one similarity transform (rotation, translation,
  isotropic scale; point-to-surface ICP started from centroid and RMS-radius alignment, on
  at most :data:`ICP_POINTS` evenly spaced vertices per direction); then, as the
  dissertation does ("we adjust the pose and scale of our reconstruction to match the ground
  truth", Sec. B.4.2 and D.4.2, "this disentangles errors in pose from errors in shape"), the
  avatar's articulated pose is fitted to the ground truth with its own skeleton and skinning
  weights (:mod:`monoavatar.bench.pose_alignment`; the shape is not changed; the avatar must
  be on the body model's vertices, else the rigid alignment is all). Then the exact
  bi-directional vertex-to-surface distance is measured on *all* vertices; the rigid-only
  figure is kept beside it (``surface_error_rigid_mm``). Mean = average of
  the two directional means; std = standard deviation of the equal-weight mixture of both
  directions' per-vertex distances. Meshes are read from the OBJ files' ``v``/``f`` records
  (no vertex splitting at UV seams).
* **Body-only error**: the same measurement for the fitted body *without* its offsets (the
  fitted shape parameters, offsets removed; not a separately fitted shape-only baseline).
* **Joint error**: PA-MPJPE (per-frame Procrustes with scale) of the fitted skeleton's joints
  at the key-frames against the ground-truth skeleton's, matched by joint name, in mm.
* **Root orientation error**: the angle between the fitted and the true root (pelvis)
  orientation at each key-frame, both taken into their camera's axes (so it holds when the
  reconstruction's camera differs from the scene's); median and maximum over the key-frames,
  and how many key-frames are more than 30° off. PA-MPJPE aligns each frame's skeleton by a
  rotation and so cannot see a body fitted facing the wrong way; this can.
* **Silhouette IoU**: the posed avatar (shape + offsets, the reconstruction's own poses,
  translations and camera) rasterised at each key-frame against the exact ground-truth mask;
  mean and minimum over key-frames.
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
  carried into the world by the ground-truth root joint's transform of the frame. (Where a
  joint centre lies inside the body is not visible and differs between body models; placing
  the root joint *onto* the true root joint instead shifted a whole avatar by its canonical
  root offset, about 1 cm, and cost 2.7 dB (estimated poses) to 4.8 dB (true poses) on the
  suite's means.) It is rendered with the scene camera, and reads lower than the tracked
  figure: the same rotations on two skeletons whose joints sit differently inside the body,
  and a surface aligned by closest points (which lets it slide along itself), put the texture
  a pixel or two off where the frame has it (the 2026-12-01 suite: 23.4 dB transferred, 25.6
  tracked; at the key-frames, with the avatar's own poses, clothed-tight-s24 reads 24.4 dB,
  transferred 21.5 dB). This was the headline figure before: the held-out PSNRs that
  docstrings elsewhere quote from earlier measurements are of this placement.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from monoavatar.eval.alignment import SimilarityTransform
from monoavatar.eval.surface import ICP_POINTS

if TYPE_CHECKING:
    from monoavatar.body import BodyModel
    from monoavatar.camera import PinholeCamera
    from monoavatar.fit.pose import PoseTrack
    from monoavatar.io.synth_scene import SynthScene

__all__ = [
    "BACKGROUND_GREY",
    "ICP_POINTS",
    "BodyCache",
    "HELDOUT_TRACK_ROUNDS",
    "HeatMap",
    "MetricsError",
    "ROOT_OFF_DEG",
    "Reconstruction",
    "Rig",
    "SubjectMetrics",
    "SubjectTruth",
    "SurfaceMetrics",
    "body_model_name",
    "evaluate_reconstruction",
    "heldout_frames",
    "load_truth",
    "read_obj",
    "read_reconstruction",
    "root_orientation_error_deg",
    "surface_metrics",
]


BACKGROUND_GREY = 0.5
"""Background of the held-out renders: ground-truth person pixels the avatar misses count
against this grey."""


class MetricsError(ValueError):
    """A reconstruction folder that cannot be evaluated (missing files, unknown body model)."""


# -- reading ------------------------------------------------------------------------------------


def read_obj(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 and triangles (F, 3) int64 of an OBJ file.

    Only ``v`` and ``f`` records are read (texture coordinates and normals are ignored, so no
    vertex is duplicated at a UV seam); polygons are split into fans; indices may be negative
    (relative), as the format allows.
    """
    path = Path(path)
    vertices: list[list[float]] = []
    faces: list[list[int]] = []
    try:
        text = path.read_text()
    except OSError as exc:
        raise MetricsError(f"cannot read {path}: {exc}") from exc
    for line in text.splitlines():
        if line.startswith("v "):
            vertices.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            idx = [int(tok.split("/")[0]) for tok in line.split()[1:]]
            idx = [i - 1 if i > 0 else len(vertices) + i for i in idx]
            faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    if not vertices or not faces:
        raise MetricsError(f"{path}: no vertices or no faces")
    return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)


def body_model_name(identity: str) -> str:
    """The :func:`monoavatar.body.load_body_model` name of a body-model identity string
    (``"anny-0.6.2:local_changes=none"`` → ``"anny"``, ``…=all`` → ``"anny-local"``)."""
    if identity in ("anny", "anny-local"):
        return identity
    if identity.startswith("anny"):
        return "anny-local" if identity.endswith("local_changes=all") else "anny"
    raise MetricsError(
        f"the benchmark can pose Anny avatars only; this one is for body model {identity!r}"
    )


class BodyCache:
    """Body models loaded once per benchmark run (Anny takes seconds to build)."""

    def __init__(self) -> None:
        self._models: dict[str, BodyModel] = {}

    def get(self, identity: str) -> BodyModel:
        """The model for an identity string (see :func:`body_model_name`)."""
        name = body_model_name(identity)
        if name not in self._models:
            import torch

            from monoavatar.body import load_body_model

            self._models[name] = load_body_model(name, dtype=torch.float64)
        return self._models[name]


@dataclass(frozen=True)
class Reconstruction:
    """A ``monoavatar reconstruct`` output folder, read back.

    Attributes:
        folder: the folder.
        vertices: (V, 3) canonical avatar vertices from ``avatar.obj``, metres.
        faces: (F, 3) its triangles.
        body_model: identity string of the fitted body model.
        shape: (S,) shape parameters.
        offsets: (V_b, 3) canonical per-vertex offsets, metres.
        poses: (K, J, 3) axis-angle per key-frame, radians.
        translations: (K, 3) metres.
        frame_indices: (K,) key-frame indices in the input.
        camera: the reconstruction's camera.
        texture: (T, T, 3) uint8 texture, or None when ``texture.png`` is missing.
        lighting_sh: (3, 9) SH lighting divided out of an albedo texture (world axes of the
            reconstruction's camera), or None.
        report: the parsed ``report.json`` (empty when missing).
    """

    folder: Path
    vertices: np.ndarray
    faces: np.ndarray
    body_model: str
    shape: np.ndarray
    offsets: np.ndarray
    poses: np.ndarray
    translations: np.ndarray
    frame_indices: np.ndarray
    camera: PinholeCamera
    texture: np.ndarray | None
    lighting_sh: np.ndarray | None
    report: dict[str, Any]

    @property
    def texture_is_albedo(self) -> bool:
        """Whether ``report.json`` says the texture is albedo (shading divided out)."""
        texture = self.report.get("texture")
        return bool(texture.get("albedo", False)) if isinstance(texture, dict) else False


def read_reconstruction(folder: str | Path) -> Reconstruction:
    """Read a reconstruction output folder (see :mod:`monoavatar.reconstruct`)."""
    from monoavatar.camera import PinholeCamera

    folder = Path(folder)
    for name in ("avatar.obj", "params.npz"):
        if not (folder / name).is_file():
            raise MetricsError(f"{folder}: {name} missing; not a finished reconstruction")
    vertices, faces = read_obj(folder / "avatar.obj")
    try:
        with np.load(folder / "params.npz") as params:
            p = {key: params[key] for key in params.files}
    except (OSError, ValueError) as exc:
        raise MetricsError(f"{folder / 'params.npz'}: {exc}") from exc
    needed = ("body_model", "shape", "offsets", "poses", "translations", "frame_indices",
              "camera_K", "camera_R", "camera_t", "image_size")  # fmt: skip
    missing = [key for key in needed if key not in p]
    if missing:
        raise MetricsError(f"{folder / 'params.npz'}: keys {missing} missing")
    width, height = (int(x) for x in p["image_size"])
    camera = PinholeCamera(p["camera_K"], p["camera_R"], p["camera_t"], width, height)
    texture = None
    if (folder / "texture.png").is_file():
        texture = np.asarray(Image.open(folder / "texture.png").convert("RGB"))
    report: dict[str, Any] = {}
    if (folder / "report.json").is_file():
        report = json.loads((folder / "report.json").read_text())
    return Reconstruction(
        folder=folder,
        vertices=vertices,
        faces=faces,
        body_model=str(p["body_model"]),
        shape=np.asarray(p["shape"], dtype=np.float64).reshape(-1),
        offsets=np.asarray(p["offsets"], dtype=np.float64),
        poses=np.asarray(p["poses"], dtype=np.float64),
        translations=np.asarray(p["translations"], dtype=np.float64),
        frame_indices=np.asarray(p["frame_indices"], dtype=np.int64).reshape(-1),
        camera=camera,
        texture=texture,
        lighting_sh=(
            np.asarray(p["lighting_sh"], dtype=np.float64).reshape(3, 9)
            if "lighting_sh" in p
            else None
        ),  # fmt: skip
        report=report,
    )


@dataclass(frozen=True)
class SubjectTruth:
    """The ground truth of one suite subject, read once for all its reconstructions.

    Attributes:
        scene: the synth scene (all frames).
        vertices: (V_gt, 3) clothed canonical mesh, metres (``gt/subject_000/canonical.obj``).
        faces: (F_gt, 3) its triangles.
        joints: (N, J, 3) ground-truth joint positions per frame, world metres.
        joint_names: names of those joints.
        sh: (N, 3, 9) SH lighting of each frame.
        root_transforms: (N, 4, 4) the ground-truth root joint's skinning transform of each
            frame (canonical → world, metres).
    """

    scene: SynthScene
    vertices: np.ndarray
    faces: np.ndarray
    joints: np.ndarray
    joint_names: tuple[str, ...]
    sh: np.ndarray
    root_transforms: np.ndarray


def load_truth(scene_folder: str | Path, bodies: BodyCache) -> SubjectTruth:
    """Read a synth scene and pose its ground-truth body (joints of every frame)."""
    from monoavatar.io.synth_scene import read_synth_scene

    scene = read_synth_scene(scene_folder, keypoints="exact")
    gt = scene.ground_truth
    gt_body = bodies.get(gt.body_model)
    posed = gt.body_output(gt_body)
    joints = posed.joints.double().numpy()
    root_transforms = posed.transforms[:, 0].double().numpy()
    vertices, faces = read_obj(scene.folder / "gt" / "subject_000" / "canonical.obj")
    with np.load(scene.folder / "gt" / "params.npz") as params:
        sh = np.asarray(params["sh"], dtype=np.float64)
    return SubjectTruth(scene, vertices, faces, joints, tuple(gt_body.joint_names), sh,
                        root_transforms)  # fmt: skip


# -- results ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SurfaceMetrics:
    """Surface error after alignment, in millimetres.

    Attributes:
        mean_mm: the metric (average of both directional means).
        std_mm: standard deviation of the equal-weight mixture of both directions.
        pred_to_gt_mm: mean over avatar vertices of the distance to the ground-truth surface.
        gt_to_pred_mm: mean over ground-truth vertices of the distance to the avatar surface.
        scale: the alignment's scale (avatar → ground truth).
        alignment: the rigid ICP's similarity transform (avatar canonical → ground-truth
            canonical, metres; the held-out renders are placed by it).
        rigid_mean_mm: the mean after the similarity alignment alone (no articulated pose).
        pose_aligned: whether the articulated pose was aligned too (``mean_mm`` etc. then
            measure the pose-aligned avatar; without a rig they equal the rigid figures).
        aligned_pose: (J, 3) the joint rotations (axis-angle, radians) that took the avatar's
            canonical pose to the truth's, None without pose alignment.
        pose_alignment: the similarity transform applied after that pose (None without).
    """

    mean_mm: float
    std_mm: float
    pred_to_gt_mm: float
    gt_to_pred_mm: float
    scale: float
    alignment: SimilarityTransform = field(default_factory=SimilarityTransform.identity)
    rigid_mean_mm: float | None = None
    pose_aligned: bool = False
    aligned_pose: np.ndarray | None = None
    pose_alignment: SimilarityTransform | None = None


@dataclass(frozen=True)
class HeatMap:
    """Per-vertex surface error of the aligned avatar (for heat-map images and PLY files).

    Attributes:
        vertices: (V, 3) avatar vertices after alignment to the ground truth, metres.
        faces: (F, 3) triangles.
        errors: (V,) distance of each vertex to the ground-truth surface, metres.
    """

    vertices: np.ndarray
    faces: np.ndarray
    errors: np.ndarray


@dataclass(frozen=True)
class SubjectMetrics:
    """Everything the benchmark measures of one reconstruction (see the module docstring).

    Attributes:
        surface: surface error of the avatar.
        body_only_mm: surface error of the fitted body with its offsets removed, mm (None when
            not measured).
        shape_only_mm: the reconstruction's own shape-only baseline from ``report.json``
            (``shape_only_error_mm``), mm, None when it reports none.
        pa_mpjpe_mm: PA-MPJPE of the fitted joints at the key-frames, mm.
        silhouette_iou: mean IoU of the posed avatar and the ground-truth masks at the
            key-frames; ``silhouette_iou_min`` the worst key-frame.
        psnr_db: texture PSNR in held-out poses (tracked) on the ground-truth mask, dB (None
            without held-out frames or texture); ``psnr_overlap_db`` on pixels covered by
            both; ``psnr_union_db`` on pixels covered by either (spill counted too).
        heldout_frames: how many held-out frames the PSNR averages (MSE pooled over them).
        texture_lighting: how the held-out renders were lit: ``"estimated"`` (an albedo
            texture shaded by the reconstruction's own SH estimate ``lighting_sh`` in
            ``params.npz``, in the reconstruction's world for the tracked renders and rotated
            into the scene's world, if the cameras differ, for the transferred ones),
            ``"ground-truth"`` (an albedo texture without an estimate: the frame's true SH;
            albedo and lighting share an unknown scale, so this can be off in brightness),
            ``"unlit"`` (a texture with the shading baked in).
        keyframes: number of key-frames of the reconstruction.
        timings: per-stage seconds from ``report.json``.
        reconstruct_seconds: the reconstruction's total seconds from ``report.json``.
        peak_memory_mb: peak memory from ``report.json``.
        warnings: warnings from ``report.json``.
        psnr_true_poses_db: on the person mask, with the true poses transferred (module
            docstring) instead of tracked; ``psnr_rigid_db`` the same with the avatar in its
            own canonical pose (only the similarity transform of the surface alignment).
        psnr_interpolated_db: on the person mask, with the key-frames' poses interpolated to
            the held-out frames, before the tracker's flow rounds.
        heldout_track_seconds: the tracker's seconds for the held-out frames (perception
            included).
        heldout_pa_mpjpe_mm: PA-MPJPE of the tracked held-out poses' joints against the
            truth's, mm (how well the tracker tracks); ``heldout_root_error_deg`` the median
            root orientation error over the held-out frames; the ``_interpolated`` variants
            for the interpolated poses.
        missed_fraction: in the held-out renders, the fraction of ground-truth person pixels
            the avatar does not cover (they count against grey in ``psnr_db``).
        missed_error_share: the share of ``psnr_db``'s squared error that lies on them.
        root_error_deg: median over the key-frames of the root orientation error, degrees
            (:func:`root_orientation_error_deg`); ``root_error_max_deg`` the worst key-frame,
            ``root_off_frames`` how many key-frames are more than :data:`ROOT_OFF_DEG` off.
    """

    surface: SurfaceMetrics
    body_only_mm: float | None
    shape_only_mm: float | None
    pa_mpjpe_mm: float
    silhouette_iou: float
    silhouette_iou_min: float
    psnr_db: float | None
    psnr_overlap_db: float | None
    heldout_frames: int
    texture_lighting: str
    keyframes: int
    timings: dict[str, float] = field(default_factory=dict)
    reconstruct_seconds: float | None = None
    peak_memory_mb: float | None = None
    warnings: list[str] = field(default_factory=list)
    psnr_rigid_db: float | None = None
    missed_fraction: float | None = None
    missed_error_share: float | None = None
    root_error_deg: float | None = None
    root_error_max_deg: float | None = None
    root_off_frames: int | None = None
    psnr_union_db: float | None = None
    psnr_true_poses_db: float | None = None
    psnr_interpolated_db: float | None = None
    heldout_track_seconds: float | None = None
    heldout_pa_mpjpe_mm: float | None = None
    heldout_pa_mpjpe_interpolated_mm: float | None = None
    heldout_root_error_deg: float | None = None
    heldout_root_error_interpolated_deg: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready values (non-finite numbers become None)."""

        def clean(value: Any) -> Any:
            if isinstance(value, float) and not math.isfinite(value):
                return None
            if isinstance(value, dict):
                return {k: clean(v) for k, v in value.items()}
            return value

        return clean({
            "surface_error_mm": self.surface.mean_mm,
            "surface_error_std_mm": self.surface.std_mm,
            "avatar_to_gt_mm": self.surface.pred_to_gt_mm,
            "gt_to_avatar_mm": self.surface.gt_to_pred_mm,
            "alignment_scale": self.surface.scale,
            "surface_error_rigid_mm": self.surface.rigid_mean_mm,
            "pose_aligned": self.surface.pose_aligned,
            "body_only_error_mm": self.body_only_mm,
            "shape_only_error_mm": self.shape_only_mm,
            "pa_mpjpe_mm": self.pa_mpjpe_mm,
            "silhouette_iou": self.silhouette_iou,
            "silhouette_iou_min": self.silhouette_iou_min,
            "texture_psnr_db": self.psnr_db,
            "texture_psnr_overlap_db": self.psnr_overlap_db,
            "texture_psnr_union_db": self.psnr_union_db,
            "texture_psnr_true_poses_db": self.psnr_true_poses_db,
            "texture_psnr_rigid_db": self.psnr_rigid_db,
            "texture_psnr_interpolated_db": self.psnr_interpolated_db,
            "heldout_track_seconds": self.heldout_track_seconds,
            "heldout_pa_mpjpe_mm": self.heldout_pa_mpjpe_mm,
            "heldout_pa_mpjpe_interpolated_mm": self.heldout_pa_mpjpe_interpolated_mm,
            "heldout_root_error_deg": self.heldout_root_error_deg,
            "heldout_root_error_interpolated_deg": self.heldout_root_error_interpolated_deg,
            "texture_missed_fraction": self.missed_fraction,
            "texture_missed_error_share": self.missed_error_share,
            "root_error_deg": self.root_error_deg,
            "root_error_max_deg": self.root_error_max_deg,
            "root_off_frames": self.root_off_frames,
            "heldout_frames": self.heldout_frames,
            "texture_lighting": self.texture_lighting,
            "keyframes": self.keyframes,
            "timings_s": dict(self.timings),
            "reconstruct_seconds": self.reconstruct_seconds,
            "peak_memory_mb": self.peak_memory_mb,
            "warnings": list(self.warnings),
        })  # fmt: skip


# -- surface ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Rig:
    """What the articulated pose alignment needs of a reconstruction's canonical mesh.

    Attributes:
        skin_weights: (V, J) skinning weights of its vertices.
        rest_joints: (J, 3) rest joint positions, metres (canonical frame).
        parents: J parent indices.
    """

    skin_weights: np.ndarray
    rest_joints: np.ndarray
    parents: tuple[int, ...]


def surface_metrics(
    pred_vertices: np.ndarray,
    pred_faces: np.ndarray,
    gt_vertices: np.ndarray,
    gt_faces: np.ndarray,
    icp_points: int = ICP_POINTS,
    with_scale: bool = True,
    rig: Rig | None = None,
) -> tuple[SurfaceMetrics, HeatMap]:
    """Similarity alignment (ICP) of a canonical prediction to the ground truth, then, with a
    ``rig``, the articulated pose alignment (:func:`~monoavatar.bench.pose_alignment.
    align_pose_and_scale`); then the exact bi-directional vertex-to-surface error on all
    vertices (metres in, mm out). ``with_scale=False`` aligns rotation and translation only
    (and skips the pose alignment, which fits a scale)."""
    from monoavatar.eval import align_icp, bidirectional_surface_error

    icp = align_icp(pred_vertices, gt_vertices, gt_faces, source_faces=pred_faces,
                    with_scale=with_scale, max_points=icp_points)  # fmt: skip
    aligned = icp.transform.apply(pred_vertices)
    error = bidirectional_surface_error(aligned, pred_faces, gt_vertices, gt_faces)
    rigid_mm = 1000.0 * error.mean
    posed = rig is not None and with_scale
    fit = None
    if posed:
        from monoavatar.bench.pose_alignment import align_pose_and_scale

        assert rig is not None
        fit = align_pose_and_scale(pred_vertices, pred_faces, rig.skin_weights, rig.rest_joints,
                                   rig.parents, gt_vertices, gt_faces, icp.transform,
                                   max_points=icp_points)  # fmt: skip
        aligned = fit.vertices
        error = bidirectional_surface_error(aligned, pred_faces, gt_vertices, gt_faces)
    a, b = error.pred_to_gt, error.gt_to_pred
    mean = error.mean
    # equal-weight mixture of both directions, consistent with the mean
    var = 0.5 * (a.var() + (a.mean() - mean) ** 2) + 0.5 * (b.var() + (b.mean() - mean) ** 2)
    metrics = SurfaceMetrics(
        mean_mm=1000.0 * mean,
        std_mm=1000.0 * float(np.sqrt(var)),
        pred_to_gt_mm=1000.0 * error.pred_to_gt_mean,
        gt_to_pred_mm=1000.0 * error.gt_to_pred_mean,
        scale=float(icp.transform.scale),
        alignment=icp.transform,
        rigid_mean_mm=rigid_mm,
        pose_aligned=posed,
        aligned_pose=None if fit is None else fit.pose,
        pose_alignment=None if fit is None else fit.transform,
    )
    return metrics, HeatMap(aligned, np.asarray(pred_faces), error.pred_to_gt)


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
    recon: Reconstruction,
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
    scene = truth.scene
    if not recon.texture_is_albedo:
        lighting, sh = "unlit", None
    elif recon.lighting_sh is not None:
        own = _sh_to_world(recon.lighting_sh, recon.camera.R, scene.camera.R)
        lighting, sh = "estimated", np.repeat(own[None], len(truth.sh), axis=0)
    else:
        lighting, sh = "ground-truth", truth.sh
    gt = scene.ground_truth
    poses = gt.poses[frames]
    if aligned_pose is not None:
        poses = _compose(poses, aligned_pose)
    verts, joints = _pose(body, recon.shape, poses, np.zeros((len(frames), 3)),
                          recon.offsets)  # fmt: skip
    _, rest_joints = _pose(body, recon.shape, np.zeros((1, body.num_joints, 3)), np.zeros((1, 3)),
                           recon.offsets)  # fmt: skip
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


def _key_track(recon: Reconstruction) -> PoseTrack:
    """The reconstruction's key-frame poses as a track (flagged frames from ``report.json``)."""
    from monoavatar.fit.pose import PoseTrack

    k = len(recon.frame_indices)
    failed = np.asarray((recon.report.get("fit") or {}).get("failed") or np.zeros(k), bool)
    if failed.shape != (k,):
        failed = np.zeros(k, bool)
    nan = np.full(k, np.nan)
    return PoseTrack(
        body_model=recon.body_model, shape=recon.shape, poses=recon.poses,
        translations=recon.translations, camera=recon.camera, frame_indices=recon.frame_indices,
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


def _tracked_psnr(recon: Reconstruction, body: BodyModel, truth: SubjectTruth,
                  frames: np.ndarray, perception: str, rounds: int) -> _Tracked:  # fmt: skip
    """Held-out figures with the avatar tracked into the frames
    (:func:`monoavatar.fit.track.track_frames`, ``rounds`` flow rounds; perception
    ``"mediapipe"`` or ``"ground-truth"``: the scene's own), and with the interpolated poses
    before the flow rounds. (Lit by the true light, an albedo without an estimate is tracked
    with the first held-out frame's light.)"""
    import time
    from dataclasses import replace

    from monoavatar.fit.track import track_frames
    from monoavatar.io.synth_scene import read_synth_scene
    from monoavatar.perception import perceive

    start = time.perf_counter()
    if recon.texture is None or len(frames) == 0:
        return _Tracked(_HeldOut(None, None, "unlit"), _HeldOut(None, None, "unlit"), 0.0)
    held = read_synth_scene(truth.scene.folder, frames=frames)
    if perception == "ground-truth":
        obs = held.observations
    elif perception == "mediapipe":
        obs = perceive(held.frames, recon.camera, use_cache=False)
    else:
        raise ValueError(f"perception must be 'mediapipe' or 'ground-truth', got {perception!r}")
    obs = replace(obs, camera=recon.camera)
    if not recon.texture_is_albedo:
        lighting, sh = "unlit", None
    elif recon.lighting_sh is not None:
        lighting, sh = "estimated", np.repeat(recon.lighting_sh[None], len(frames), axis=0)
    else:
        lighting = "ground-truth"
        sh = np.stack([_sh_to_world(truth.sh[f], truth.scene.camera.R, recon.camera.R)
                       for f in frames])  # fmt: skip
    texture = recon.texture.astype(np.float64) / 255.0
    key_track = _key_track(recon)
    figures, poses = [], []
    for n in (0, rounds) if rounds > 0 else (0,):  # 0 rounds: the interpolated poses are it
        track = track_frames(body, obs, held.frames.images, key_track, recon.shape,
                             recon.offsets, texture, None if sh is None else sh[0], n)  # fmt: skip
        verts, _ = _pose(body, recon.shape, track.poses, track.translations, recon.offsets)
        pred, covered = _render_heldout(body, verts, recon.camera, recon.texture, sh)
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


def evaluate_reconstruction(
    folder: str | Path,
    truth: SubjectTruth,
    bodies: BodyCache | None = None,
    *,
    max_heldout: int = 20,
    body_only: bool = True,
    perception: str = "mediapipe",
    track_rounds: int = HELDOUT_TRACK_ROUNDS,
) -> tuple[SubjectMetrics, HeatMap]:
    """Measure a reconstruction output folder against the synth scene it was made from.

    Args:
        folder: the ``monoavatar reconstruct`` output folder.
        truth: the scene's ground truth (:func:`load_truth`).
        bodies: body models to reuse between calls.
        max_heldout: at most this many held-out frames (evenly spread) for the PSNR.
        body_only: also measure the fitted body without its offsets.
        perception: what the held-out tracker sees of the held-out frames: ``"mediapipe"``
            (masks and keypoints perceived from the frames) or ``"ground-truth"`` (the
            scene's own, as ``reconstruct --perception ground-truth``).
        track_rounds: the tracker's flow rounds (0: the interpolated poses).

    Returns:
        The metrics, and the per-vertex error of the aligned avatar for heat maps.
    """
    from monoavatar.eval import pa_mpjpe

    bodies = bodies or BodyCache()
    recon = read_reconstruction(folder)
    gt = truth.scene.ground_truth
    n = len(gt.poses)
    idx = recon.frame_indices
    if len(idx) == 0 or len(idx) != len(recon.poses) or idx.min() < 0 or idx.max() >= n:
        raise MetricsError(f"{folder}: frame_indices do not match the {n}-frame scene")

    body = bodies.get(recon.body_model)
    if recon.offsets.shape != (body.num_vertices, 3):
        raise MetricsError(
            f"{folder}: offsets have shape {recon.offsets.shape}, the body model has "
            f"{body.num_vertices} vertices"
        )
    rest, rest_joints = _pose(body, recon.shape, np.zeros((1, body.num_joints, 3)),
                              np.zeros((1, 3)), None)  # fmt: skip
    rig = Rig(body.skin_weights.double().numpy(), rest_joints[0], tuple(body.parents))
    # the articulated alignment needs the avatar on the body model's vertices (not, e.g., a
    # mesh of another resolution)
    same_mesh = recon.vertices.shape == (body.num_vertices, 3)
    surface, heat = surface_metrics(recon.vertices, recon.faces, truth.vertices, truth.faces,
                                    rig=rig if same_mesh else None)  # fmt: skip

    body_only_mm = None
    if body_only:
        body_only_mm = surface_metrics(rest[0], body.faces.numpy(), truth.vertices,
                                       truth.faces, rig=rig)[0].mean_mm  # fmt: skip

    verts, joints = _pose(body, recon.shape, recon.poses, recon.translations, recon.offsets)
    names = list(body.joint_names)
    gt_names = list(truth.joint_names)
    common = [j for j in names if j in gt_names]
    if len(common) < 3 or names[0] not in gt_names:
        raise MetricsError(
            f"fitted and ground-truth skeletons share only joints {common} (root {names[0]!r})"
        )
    mine = joints[:, [names.index(j) for j in common]]
    theirs = truth.joints[idx][:, [gt_names.index(j) for j in common]]
    joint_mm = pa_mpjpe(mine, theirs)

    ious = _silhouettes(body, verts, recon.camera, gt.masks[idx])
    root_deg = root_orientation_error_deg(recon.poses[:, 0], recon.camera.R, gt.poses[idx][:, 0],
                                          truth.scene.camera.R)  # fmt: skip

    held = heldout_frames(n, idx, max_heldout)
    transferred = _heldout_psnr(recon, body, truth, surface.alignment, held)
    psnr_rigid = transferred.mask_db
    if surface.pose_alignment is not None:
        transferred = _heldout_psnr(recon, body, truth, surface.pose_alignment, held,
                                    surface.aligned_pose)  # fmt: skip
    tracked = _tracked_psnr(recon, body, truth, held, perception, track_rounds)
    heldout = tracked.tracked

    def heldout_pose_errors(found: tuple[np.ndarray, np.ndarray] | None,
                            ) -> tuple[float | None, float | None]:  # fmt: skip
        """PA-MPJPE (mm) and median root error (°) of held-out poses against the truth's."""
        if found is None:
            return None, None
        _, held_joints = _pose(body, recon.shape, found[0], found[1], recon.offsets)
        mm = pa_mpjpe(held_joints[:, [names.index(j) for j in common]],
                      truth.joints[held][:, [gt_names.index(j) for j in common]])  # fmt: skip
        deg = root_orientation_error_deg(found[0][:, 0], recon.camera.R, gt.poses[held][:, 0],
                                         truth.scene.camera.R)  # fmt: skip
        return float(mm), float(np.median(deg))

    interp_mm, interp_deg = heldout_pose_errors(tracked.interpolated_poses)
    tracked_mm, tracked_deg = heldout_pose_errors(tracked.tracked_poses)

    report = recon.report
    shape_only = report.get("shape_only_error_mm")
    timings = report.get("timings") or {}
    return (
        SubjectMetrics(
            surface=surface,
            body_only_mm=body_only_mm,
            shape_only_mm=_float_or_none(shape_only),
            pa_mpjpe_mm=float(joint_mm),
            silhouette_iou=float(np.mean(ious)),
            silhouette_iou_min=float(np.min(ious)),
            psnr_db=heldout.mask_db,
            psnr_overlap_db=heldout.overlap_db,
            psnr_union_db=heldout.union_db,
            heldout_frames=int(len(held)) if heldout.mask_db is not None else 0,
            texture_lighting=heldout.lighting,
            keyframes=int(len(idx)),
            timings={str(k): float(v) for k, v in timings.items()},
            reconstruct_seconds=_float_or_none(report.get("seconds")),
            peak_memory_mb=_float_or_none(report.get("peak_memory_mb")),
            warnings=[str(w) for w in report.get("warnings") or []],
            psnr_rigid_db=psnr_rigid,
            missed_fraction=heldout.missed_fraction,
            missed_error_share=heldout.missed_error_share,
            root_error_deg=float(np.median(root_deg)),
            root_error_max_deg=float(root_deg.max()),
            root_off_frames=int((root_deg > ROOT_OFF_DEG).sum()),
            psnr_true_poses_db=transferred.mask_db,
            psnr_interpolated_db=tracked.interpolated.mask_db,
            heldout_track_seconds=tracked.seconds if heldout.mask_db is not None else None,
            heldout_pa_mpjpe_mm=tracked_mm,
            heldout_pa_mpjpe_interpolated_mm=interp_mm,
            heldout_root_error_deg=tracked_deg,
            heldout_root_error_interpolated_deg=interp_deg,
        ),
        heat,
    )


def _float_or_none(value: Any) -> float | None:
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        return None
