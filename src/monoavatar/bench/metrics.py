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

The held-out measurements are in :mod:`monoavatar.bench.heldout`; the whole evaluation of
one folder is :func:`monoavatar.bench.evaluate.evaluate_reconstruction`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from monoavatar.core.errors import MonoavatarError
from monoavatar.eval.alignment import SimilarityTransform
from monoavatar.eval.icp import ICP_POINTS
from monoavatar.io.export_mesh import read_obj

if TYPE_CHECKING:
    from monoavatar.body import BodyModel
    from monoavatar.datasets.synth_scene import SynthScene

__all__ = [
    "BACKGROUND_GREY",
    "ICP_POINTS",
    "BodyCache",
    "HeatMap",
    "MetricsError",
    "Rig",
    "SubjectMetrics",
    "SubjectTruth",
    "SurfaceMetrics",
    "body_model_name",
    "canonical_bone_angles_deg",
    "load_truth",
    "surface_metrics",
]


BACKGROUND_GREY = 0.5
"""Background of the held-out renders: ground-truth person pixels the avatar misses count
against this grey."""


class MetricsError(MonoavatarError, ValueError):
    """A reconstruction folder that cannot be evaluated (missing files, unknown body model)."""


# -- reading ------------------------------------------------------------------------------------


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
        regions: named (V_gt,) bool vertex sets the errors are also reported on
            (:func:`truth_regions`).
    """

    scene: SynthScene
    vertices: np.ndarray
    faces: np.ndarray
    joints: np.ndarray
    joint_names: tuple[str, ...]
    sh: np.ndarray
    root_transforms: np.ndarray
    regions: dict[str, np.ndarray] = field(default_factory=dict)


REGIONS = ("face", "garments", "hair", "skin")
"""The regions of :func:`truth_regions`."""


def truth_regions(body: BodyModel, shape: np.ndarray, vertices: np.ndarray,
                  garments: np.ndarray) -> dict[str, np.ndarray]:  # fmt: skip
    """Named (V_f,) bool sets of the ground truth's canonical vertices: ``face`` (skin weighted
    mostly to the head, in front of the plane halfway between the ears and the nose),
    ``garments`` (top and bottom), ``hair``, and ``skin`` other than the face.

    Args:
        body: the model that generated the scene; shape: (S,) its shape parameters;
        vertices: (V_f, 3) the clothed canonical mesh (the once-subdivided body's vertices);
        garments: (V_f,) labels 0 skin, 1 top, 2 bottom, 3 hair, 4 shoes.
    """
    import torch

    from monoavatar.body import MEDIAPIPE_LANDMARKS
    from monoavatar.body.subdivide import subdivide

    weights = subdivide(body.faces, body.uv, body.face_uv, body.skin_weights).weights.numpy()
    if weights.shape[0] != len(vertices) or garments.shape != (len(vertices),):
        raise MetricsError(
            f"the ground truth has {len(vertices)} vertices, its body subdivided "
            f"{weights.shape[0]} and {garments.shape} garment labels"
        )
    with torch.no_grad():
        rest = body.rest_shape(torch.as_tensor(shape, dtype=body.dtype)[None])[0]
        kp = body.keypoints(rest)[0].double().numpy()
    names = list(MEDIAPIPE_LANDMARKS)
    ears = 0.5 * (kp[names.index("left_ear"), 2] + kp[names.index("right_ear"), 2])
    front = vertices[:, 2] > 0.5 * (ears + kp[names.index("nose"), 2])
    head = weights[:, body.joint_index("head")] > 0.5
    skin = garments == 0
    face = skin & head & front
    return {"face": face, "garments": (garments == 1) | (garments == 2),
            "hair": garments == 3, "skin": skin & ~face}  # fmt: skip


def load_truth(scene_folder: str | Path, bodies: BodyCache) -> SubjectTruth:
    """Read a synth scene and pose its ground-truth body (joints of every frame)."""
    from monoavatar.datasets.synth_scene import read_synth_scene

    scene = read_synth_scene(scene_folder, keypoints="exact")
    gt = scene.ground_truth
    gt_body = bodies.get(gt.body_model)
    posed = gt.body_output(gt_body)
    joints = posed.joints.double().numpy()
    root_transforms = posed.transforms[:, 0].double().numpy()
    vertices, faces = read_obj(scene.folder / "gt" / "subject_000" / "canonical.obj")
    with np.load(scene.folder / "gt" / "params.npz") as params:
        sh = np.asarray(params["sh"], dtype=np.float64)
        garments = np.asarray(params["garments"][0])
    regions = truth_regions(gt_body, gt.shapes[0], vertices, garments)
    return SubjectTruth(scene, vertices, faces, joints, tuple(gt_body.joint_names), sh,
                        root_transforms, regions)  # fmt: skip


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
        normal_error_deg: the bi-directional normal angular error after the same alignment
            as ``mean_mm`` (:func:`monoavatar.eval.compare_surfaces`), degrees.
        rigid_normal_error_deg: the same after the similarity alignment alone.
        regions: per region of the truth (``surface_metrics``'s ``regions``), the surface
            error in mm and the normal error in degrees after the full alignment.
        bone_angles_deg: (J,) how far each bone of the avatar's rest skeleton is from the
            truth's, degrees (:func:`canonical_bone_angles_deg` of ``aligned_pose``; NaN for
            the root), None without pose alignment.
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
    normal_error_deg: float | None = None
    rigid_normal_error_deg: float | None = None
    regions: dict[str, tuple[float, float]] = field(default_factory=dict)
    bone_angles_deg: np.ndarray | None = None


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
            "normal_error_deg": self.surface.normal_error_deg,
            "normal_error_rigid_deg": self.surface.rigid_normal_error_deg,
            "bone_angle_median_deg": None if self.surface.bone_angles_deg is None
            else float(np.nanmedian(self.surface.bone_angles_deg)),
            "bone_angle_max_deg": None if self.surface.bone_angles_deg is None
            else float(np.nanmax(self.surface.bone_angles_deg)),
            "regions": {name: {"surface_error_mm": mm, "normal_error_deg": deg}
                        for name, (mm, deg) in self.surface.regions.items()},
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


def _mm_deg(region: tuple[float, float]) -> tuple[float, float]:
    return 1000.0 * region[0], region[1]


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


def canonical_bone_angles_deg(rest_joints: np.ndarray, parents: tuple[int, ...],
                              pose: np.ndarray) -> np.ndarray:  # fmt: skip
    """(J,) the angle, degrees, by which ``pose`` (J, 3) axis-angle turns each bone (parent
    joint → joint, of the rest skeleton ``rest_joints`` (J, 3)) with the root's own rotation
    left out; NaN for the root. A bone turns with the product of its ancestors' rotations,
    ``R_p = R_parent(p) ⋯ R_p``, so its angle is that between ``c_j − c_p`` and
    ``R_p (c_j − c_p)``: a twist about the bone itself, or a rotation split between a collar
    and a shoulder, counts as much as it moves the bone, which the joint angles alone do not
    say (they are not unique)."""
    from scipy.spatial.transform import Rotation

    local = Rotation.from_rotvec(np.asarray(pose, dtype=np.float64)).as_matrix()
    local[0] = np.eye(3)
    world = np.empty_like(local)
    out = np.full(len(parents), np.nan)
    for j, p in enumerate(parents):
        world[j] = local[j] if p < 0 else world[p] @ local[j]
        if p < 0:
            continue
        bone = np.asarray(rest_joints[j], dtype=np.float64) - rest_joints[p]
        turned = world[p] @ bone
        cos = bone @ turned / max(float(np.linalg.norm(bone) * np.linalg.norm(turned)), 1e-12)
        out[j] = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return out


def surface_metrics(
    pred_vertices: np.ndarray,
    pred_faces: np.ndarray,
    gt_vertices: np.ndarray,
    gt_faces: np.ndarray,
    icp_points: int = ICP_POINTS,
    with_scale: bool = True,
    rig: Rig | None = None,
    regions: dict[str, np.ndarray] | None = None,
) -> tuple[SurfaceMetrics, HeatMap]:
    """Similarity alignment (ICP) of a canonical prediction to the ground truth, then, with a
    ``rig``, the articulated pose alignment (:func:`~monoavatar.bench.pose_alignment.
    align_pose_and_scale`); then the exact bi-directional vertex-to-surface error on all
    vertices (metres in, mm out). ``with_scale=False`` aligns rotation and translation only
    (and skips the pose alignment, which fits a scale). The normal angular error is measured
    after each alignment, and both errors on each of ``regions`` ((V_gt,) bool ground-truth
    vertex sets) after the last."""
    from monoavatar.eval import align_icp, compare_surfaces

    icp = align_icp(pred_vertices, gt_vertices, gt_faces, source_faces=pred_faces,
                    with_scale=with_scale, max_points=icp_points)  # fmt: skip
    aligned = icp.transform.apply(pred_vertices)
    error = compare_surfaces(aligned, pred_faces, gt_vertices, gt_faces)
    rigid_mm = 1000.0 * error.distance
    rigid_deg = error.angle
    posed = rig is not None and with_scale
    fit = None
    if posed:
        from monoavatar.bench.pose_alignment import align_pose_and_scale

        assert rig is not None
        fit = align_pose_and_scale(pred_vertices, pred_faces, rig.skin_weights, rig.rest_joints,
                                   rig.parents, gt_vertices, gt_faces, icp.transform,
                                   max_points=icp_points)  # fmt: skip
        aligned = fit.vertices
        error = compare_surfaces(aligned, pred_faces, gt_vertices, gt_faces)
    a, b = error.pred_to_gt, error.gt_to_pred
    mean = error.distance
    # equal-weight mixture of both directions, consistent with the mean
    var = 0.5 * (a.var() + (a.mean() - mean) ** 2) + 0.5 * (b.var() + (b.mean() - mean) ** 2)
    metrics = SurfaceMetrics(
        mean_mm=1000.0 * mean,
        std_mm=1000.0 * float(np.sqrt(var)),
        pred_to_gt_mm=1000.0 * float(a.mean()),
        gt_to_pred_mm=1000.0 * float(b.mean()),
        scale=float(icp.transform.scale),
        alignment=icp.transform,
        rigid_mean_mm=rigid_mm,
        pose_aligned=posed,
        aligned_pose=None if fit is None else fit.pose,
        pose_alignment=None if fit is None else fit.transform,
        normal_error_deg=error.angle,
        rigid_normal_error_deg=rigid_deg,
        regions={name: _mm_deg(error.region(mask)) for name, mask in (regions or {}).items()},
        bone_angles_deg=None if fit is None or rig is None else canonical_bone_angles_deg(
            rig.rest_joints, rig.parents, fit.pose),
    )
    return metrics, HeatMap(aligned, np.asarray(pred_faces), error.pred_to_gt)
