"""Key-frame poses refined by optical flow from the textured avatar to each frame.

After a first texture, the avatar is rendered into every key-frame with that texture, over the
frame itself, and optical flow (OpenCV DIS) from the render to the frame says where the colour
at each rendered point really is. A visible model point whose render lies at ``p`` should then
project to ``p + flow(p)``: a 2D correspondence inside the silhouette, where keypoints and
silhouettes say nothing (a turned forearm, the heading of a diagonal view). The poses are
re-fitted with these correspondences as one more energy term (robust, in percent of the
person's height) beside the usual ones, and the texture is built again from the new poses.

A second term pins the outline: vertices on the posed avatar's visible contour generator are
matched to the observed mask's sub-pixel edge and pulled onto it along the edge normal
(:func:`contour_correspondences`; point-to-line, as the silhouette rays of the shape stage).
The pose energy's own silhouette terms see the outline through random model points a few
pixels apart, and the flow is not trusted within ``edge_margin`` of it.

This is the analysis-by-synthesis idea of Paper A (minimise the difference between observed
and rendered flow, Eq. A.1) and of the key-frame matching term of Paper C (warp a key-frame by
the model and correct the warp by optical flow, E_match of Eq. C.13), with the textured
avatar's render in place of the neighbouring frame: it aligns every key-frame with the same
texture, so the views agree where they are combined.

"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import cv2
import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from monoavatar.body import BodyModel
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.threads import frame_pool, torch_threads
from monoavatar.fit import energies
from monoavatar.fit import pose as posefit
from monoavatar.fit import pose_energy as pe
from monoavatar.fit.prior import apose_prior
from monoavatar.fit.rays import contour_candidates, match_boundary, silhouette_boundary
from monoavatar.perception.flow import DISFlow
from monoavatar.perception.observations import Observations
from monoavatar.render import Fragments, rasterize, render_over_image, vertex_normals

__all__ = [
    "FlowRefineSettings",
    "contour_correspondences",
    "flow_correspondences",
    "inside_distance",
    "refine_poses_with_flow",
]


@dataclass(frozen=True)
class FlowRefineSettings:
    """Options of :func:`refine_poses_with_flow`.

    Attributes:
        points: model points (random vertices) that get a flow correspondence.
        iterations: L-BFGS iterations per key-frame.
        rigid_iterations: iterations on the root rotation and translation alone first (the
            poses are already close: none by default).
        weight: weight of the flow term against the pose energy's terms (whose keypoint term
            has weight 1); its residuals are in percent of the person's height.
        sigma: Geman-McClure scale of the flow term, percent of the person's height (≈ 5 px
            on a 500 px person: flow residuals of a few pixels count almost quadratically).
        max_flow: pixels; longer flow is not trusted (an occlusion or a wrong match).
        depth_tolerance: metres; a point is visible when it lies within this of the depth
            buffer at its pixel.
        edge_margin: pixels; points closer than this to the render's outline get no target.
            Flow there mixes the person with the background, which is the same in both
            images, and comes out too short.
        preset: the DIS preset (``"ultrafast"``, ``"fast"``, ``"medium"``).
        contour_weight: weight of the outline term (0: none): vertices on the posed
            avatar's outline (contour generator) matched to the observed mask's sub-pixel
            edge, pulled onto it along the edge normal (:func:`contour_correspondences`).
            The silhouette terms of the pose energy see the outline only through random
            model points a few pixels apart; this one sees it at sub-pixel precision.
        contour_sigma: Geman-McClure scale of the outline term, percent of the height.
        contour_samples: samples along the observed mask's boundary.
        contour_max_cos: outline vertices are those whose normal is within this cosine of
            perpendicular to the line of sight (0.1: within 6°, where a vertex lies less than
            1 % of the local radius inside the outline; wider picks vertices that sit inside
            and would push the outline out when pulled onto the edge).
        contour_max_distance: pixels; edge samples farther than this from every outline
            vertex get no match.
        workers: threads that prepare key-frames' terms side by side (render, flow, outline;
            :func:`monoavatar.core.threads.frame_pool`), and PyTorch's threads in the
            batched fit.
        batch: key-frames fitted in one batched L-BFGS (one state per frame,
            :func:`monoavatar.fit.pose_energy.fit_frames`); each frame's fit is its own, so
            the poses depend on the count only through rounding.
    """

    points: int = 1500
    iterations: int = 30
    rigid_iterations: int = 0
    weight: float = 300.0
    sigma: float = 1.0
    max_flow: float = 8.0
    depth_tolerance: float = 0.01
    edge_margin: float = 3.0
    preset: str = "medium"
    contour_weight: float = 300.0
    contour_sigma: float = 0.5
    contour_samples: int = 1500
    contour_max_cos: float = 0.1
    contour_max_distance: float = 6.0
    workers: int = 2
    batch: int = 20

    def __post_init__(self) -> None:
        for name in ("points", "iterations", "contour_samples", "workers", "batch"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.rigid_iterations < 0:
            raise ValueError(f"rigid_iterations must be >= 0, got {self.rigid_iterations}")
        if self.edge_margin < 0:
            raise ValueError(f"edge_margin must be >= 0, got {self.edge_margin}")
        if self.contour_weight < 0:
            raise ValueError(f"contour_weight must be >= 0, got {self.contour_weight}")
        if not 0 < self.contour_max_cos < 1:
            raise ValueError(f"contour_max_cos must be in (0, 1), got {self.contour_max_cos}")
        for name in ("weight", "sigma", "max_flow", "depth_tolerance", "contour_sigma",
                     "contour_max_distance"):  # fmt: skip
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


def flow_correspondences(
    points: np.ndarray,
    camera: PinholeCamera,
    frags: Fragments,
    flow: np.ndarray,
    mask: np.ndarray,
    settings: FlowRefineSettings,
    inside_px: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """2D targets of model points from a render→frame flow.

    Args:
        points: (N, 3) posed model points, world metres.
        camera: the camera the render was made with.
        frags: the rasterisation of the posed avatar (its depth buffer decides visibility).
        flow: (H, W, 2) flow from the render to the frame, pixels.
        mask: (H, W) bool observed person mask: a target must lie on the person.
        settings: ``max_flow``, ``depth_tolerance`` and ``edge_margin``.
        inside_px: :func:`inside_distance` of ``frags``, when the caller has it already.
    Returns:
        targets (N, 2) pixels (projection + flow at it) and valid (N,) bool: visible, inside
        the image, at least ``edge_margin`` px inside the render's outline, flow shorter than
        ``max_flow``, target on the mask.
    """
    px_t, z_t = camera.project(torch.as_tensor(points, dtype=torch.float64))
    px, z = px_t.numpy(), z_t.numpy()
    h, w = mask.shape
    inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h) & (z > 0)
    col = np.clip(np.floor(px[:, 0]).astype(int), 0, w - 1)
    row = np.clip(np.floor(px[:, 1]).astype(int), 0, h - 1)
    covered = frags.face_id.numpy() >= 0
    visible = inside & covered[row, col]
    visible &= np.abs(z - frags.depth.numpy()[row, col]) < settings.depth_tolerance
    if settings.edge_margin > 0:
        if inside_px is None:
            inside_px = inside_distance(frags)
        visible &= inside_px[row, col] >= settings.edge_margin
    f = flow[row, col].astype(np.float64)
    targets = px + f
    tcol = np.clip(np.floor(targets[:, 0]).astype(int), 0, w - 1)
    trow = np.clip(np.floor(targets[:, 1]).astype(int), 0, h - 1)
    valid = visible & (np.linalg.norm(f, axis=1) < settings.max_flow) & mask[trow, tcol]
    return targets, valid


def inside_distance(frags: Fragments) -> np.ndarray:
    """(H, W) float32: each covered pixel's distance in pixels to the nearest pixel the
    render does not cover (0 off the render)."""
    covered = (frags.face_id.numpy() >= 0).astype(np.uint8)
    return cv2.distanceTransform(covered, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def contour_correspondences(
    vertices: np.ndarray,
    faces: np.ndarray,
    camera: PinholeCamera,
    frags: Fragments,
    mask: np.ndarray,
    settings: FlowRefineSettings,
    inside_px: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices on a posed mesh's visible outline matched to the observed mask's edge.

    Outline vertices are those whose normal is nearly perpendicular to the line of sight
    (:func:`monoavatar.fit.rays.contour_candidates` with ``contour_max_cos``) and whose
    projection lies within 1.5 px of the render's outline (a contour hidden behind another
    part projects inside the render); each sub-pixel sample of the mask's edge
    (:func:`monoavatar.fit.rays.silhouette_boundary`) is matched to the one nearest in image
    position and normal (:func:`monoavatar.fit.rays.match_boundary`).

    Args:
        vertices: (V, 3) posed vertices, world metres; faces: (F, 3).
        camera: the camera; frags: the rasterisation of the posed mesh.
        mask: (H, W) bool observed person mask.
        settings: the ``contour_*`` options.
        inside_px: :func:`inside_distance` of ``frags``, when the caller has it already.
    Returns:
        vertex ids (M,), their targets on the edge (M, 2) pixels, and the edge's unit outward
        normals there (M, 2).
    """
    empty = (np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)))
    normals = vertex_normals(vertices, faces).numpy()
    ids, pixels, directions = contour_candidates(vertices, normals, camera,
                                                 settings.contour_max_cos)  # fmt: skip
    if len(ids) == 0:
        return empty
    if inside_px is None:
        inside_px = inside_distance(frags)
    h, w = mask.shape
    col = np.clip(np.floor(pixels[:, 0]).astype(int), 0, w - 1)
    row = np.clip(np.floor(pixels[:, 1]).astype(int), 0, h - 1)
    on_outline = inside_px[row, col] <= 1.5
    ids, pixels, directions = ids[on_outline], pixels[on_outline], directions[on_outline]
    samples = silhouette_boundary(mask, settings.contour_samples)
    si, ci, _ = match_boundary(samples, pixels, directions, settings.contour_max_distance)
    if len(si) == 0:
        return empty
    return ids[ci], samples.points[si], samples.normals[si]


def refine_poses_with_flow(
    body: BodyModel,
    obs: Observations,
    images: np.ndarray,
    track: posefit.PoseTrack,
    shape: Tensor | np.ndarray,
    offsets: Tensor | np.ndarray,
    texture: np.ndarray,
    sh: np.ndarray | None,
    settings: FlowRefineSettings | None = None,
    pose_settings: posefit.PoseSettings | None = None,
    *,
    progress: bool = False,
) -> posefit.PoseTrack:
    """Re-fit the key-frame poses with flow correspondences to the textured avatar's render.

    Args:
        body: the body model.
        obs: the key-frames' observations (masks, keypoints, camera).
        images: (N, H, W, 3) uint8 key-frames.
        track: the poses to refine (as the texture was built from them); frames flagged
            ``failed`` are left as they are.
        shape: (S,) the avatar's shape parameters; offsets: (V, 3) its canonical offsets D.
        texture: (T, T, 3) the texture in [0, 1] (an albedo when ``sh`` is given).
        sh: (3, 9) the lighting the texture was divided by, or None.
        settings: the flow term's options; pose_settings: the pose energy's.
    Returns:
        A new track (poses and translations of the refined frames; ``energy`` is the pose
        energy without the flow term; ``timings["flow"]`` this pass's seconds).
    """
    settings = settings or FlowRefineSettings()
    pose_settings = pose_settings or posefit.PoseSettings()
    n = len(obs)
    if track.poses.shape[0] != n or len(images) != n:
        raise ValueError(
            f"the track has {track.poses.shape[0]} frames, the images {len(images)}, the "
            f"observations {n}"
        )
    with torch_threads(pose_settings.threads):
        return _refine(body, obs, images, track, shape, offsets, texture, sh, settings,
                       pose_settings, progress)  # fmt: skip


def _refine(body: BodyModel, obs: Observations, images: np.ndarray, track: posefit.PoseTrack,
            shape: Tensor | np.ndarray, offsets: Tensor | np.ndarray, texture: np.ndarray,
            sh: np.ndarray | None, settings: FlowRefineSettings,
            pose_settings: posefit.PoseSettings, progress: bool) -> posefit.PoseTrack:  # fmt: skip
    start = time.perf_counter()
    pose_settings = replace(pose_settings, rigid_iterations=settings.rigid_iterations)
    dtype = body.dtype
    beta = torch.as_tensor(shape, dtype=dtype).reshape(1, -1)
    d = torch.as_tensor(offsets, dtype=dtype)
    camera = obs.camera
    with torch.no_grad():
        rest, joints = body.rest_shape(beta)
    ctx = pe.energy_context(body, camera, pose_settings, apose_prior(body), rest[0], joints[0])
    ids = pe.subset_ids(body, settings.points, pose_settings.seed)
    sub = replace(pe.make_subset(body, rest[0], joints[0], ids), offsets=d[ids])
    point_ids = ids.numpy()
    faces = body.faces.numpy()
    uv, face_uv = body.uv.double().numpy(), body.face_uv.numpy()
    tex = torch.as_tensor(np.asarray(texture, dtype=np.float64))

    poses, trans = track.poses.copy(), track.translations.copy()
    energy = track.energy.copy()
    good = np.flatnonzero(~track.failed & ~obs.no_person)

    def prepare(i: int) -> _FrameTerms:
        pose_i = torch.as_tensor(poses[i : i + 1], dtype=dtype)
        trans_i = torch.as_tensor(trans[i : i + 1], dtype=dtype)
        with torch.no_grad():
            out = body(shape=beta, pose=pose_i, translation=trans_i, offsets=d)
        verts = out.vertices[0].double().numpy()
        frags = rasterize(verts, faces, camera)
        render = render_over_image(verts, faces, frags, uv, face_uv, tex, images[i], sh=sh)
        drawn = frags.face_id.numpy() >= 0
        flow = DISFlow(settings.preset).estimate_near(render, images[i], drawn)
        inside_px = inside_distance(frags)  # for both the flow's margin and the outline
        targets, valid = flow_correspondences(verts[point_ids], camera, frags, flow,
                                              obs.masks[i], settings, inside_px)  # fmt: skip
        contour = (contour_correspondences(verts, faces, camera, frags, obs.masks[i], settings,
                                           inside_px)
                   if settings.contour_weight > 0 else None)  # fmt: skip
        frames = pe.frames_at(obs, np.array([i]), pose_settings, dtype)
        return _FrameTerms(frames, targets, valid, contour)

    # every frame on its own, without the smoothness term: every frame is tied to the one
    # texture; the frames' terms are prepared side by side in ``workers`` threads, then a
    # chunk of ``batch`` frames is fitted in one batched L-BFGS (one state per frame)
    with tqdm(total=len(good), desc="flow refinement", unit="frame",
              disable=not progress) as bar:  # closed before an interruption is reported
        for chunk in np.array_split(good, max(1, -(-len(good) // settings.batch))):
            if len(chunk) == 0:
                continue
            with frame_pool(settings.workers) as pool:
                prepared = list(pool.map(prepare, chunk))
            sub_b, frames_b = _batch_terms(sub, body, rest[0], d, point_ids, prepared, settings)
            with torch_threads(settings.workers):
                p_out, t_out, e_out = pe.fit_frames(ctx, sub_b, frames_b, poses[chunk],
                                                    trans[chunk], settings.iterations)  # fmt: skip
            poses[chunk], trans[chunk], energy[chunk] = p_out, t_out, e_out
            bar.update(len(chunk))
    seconds = time.perf_counter() - start
    return replace(track, poses=poses, translations=trans, energy=energy,
                   seconds=track.seconds + seconds,
                   timings={**track.timings, "flow": seconds})  # fmt: skip


@dataclass(frozen=True)
class _FrameTerms:
    """One key-frame's terms for the flow round: its observations, the flow targets of the
    model points (N, 2) px with their validity (N,), and the outline matches
    (:func:`contour_correspondences`, None without the outline term)."""

    frames: pe.Frames
    flow_targets: np.ndarray
    flow_valid: np.ndarray
    contour: tuple[np.ndarray, np.ndarray, np.ndarray] | None


def _batch_terms(
    sub: pe.Subset,
    body: BodyModel,
    rest: Tensor,
    offsets: Tensor,
    point_ids: np.ndarray,
    prepared: list[_FrameTerms],
    settings: FlowRefineSettings,
) -> tuple[pe.Subset, pe.Frames]:
    """The subset and terms of B frames fitted together: each frame's model points are the
    flow points followed by its own matched outline vertices, padded to one count M
    (``Subset.valid``); the flow targets on the first, the outline's edge targets
    (point-to-line) on the second."""
    n_flow = len(point_ids)
    contours = [t.contour if t.contour is not None else
                (np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2))) for t in prepared]
    m = n_flow + max(len(c[0]) for c in contours)
    b = len(prepared)
    ids = np.full((b, m), point_ids[0], np.int64)
    point_valid = np.zeros((b, m), bool)
    flow_targets, flow_valid = np.zeros((b, m, 2)), np.zeros((b, m), bool)
    edge, normals, edge_valid = np.zeros((b, m, 2)), np.zeros((b, m, 2)), np.zeros((b, m), bool)
    for k, (terms, (vids, edge_k, normals_k)) in enumerate(zip(prepared, contours, strict=True)):
        end = n_flow + len(vids)
        ids[k, :n_flow], ids[k, n_flow:end] = point_ids, vids
        point_valid[k, :end] = True
        flow_targets[k, :n_flow], flow_valid[k, :n_flow] = terms.flow_targets, terms.flow_valid
        edge[k, n_flow:end], normals[k, n_flow:end] = edge_k, normals_k
        edge_valid[k, n_flow:end] = True
    dtype = prepared[0].frames.keypoints.dtype
    index = torch.from_numpy(ids)
    batched = replace(sub, rest=rest[index], weights=body.skin_weights[index],
                      offsets=offsets[index], valid=torch.from_numpy(point_valid))  # fmt: skip
    frames = _stack_frames([t.frames for t in prepared])
    frames = replace(
        frames,
        flow=pe.Correspondences(torch.as_tensor(flow_targets, dtype=dtype),
                                torch.from_numpy(flow_valid), settings.weight,
                                settings.sigma),  # fmt: skip
        contour=(pe.Correspondences(torch.as_tensor(edge, dtype=dtype),
                                    torch.from_numpy(edge_valid), settings.contour_weight,
                                    settings.contour_sigma, torch.as_tensor(normals, dtype=dtype))
                 if settings.contour_weight > 0 else None),  # fmt: skip
    )
    return batched, frames


def _stack_frames(frames: list[pe.Frames]) -> pe.Frames:
    """The observations of single frames as one batch (boundary samples padded)."""
    targets = [f.targets for f in frames]
    count = max(t.boundary.shape[1] for t in targets)
    boundary = torch.zeros(len(frames), count, 2, dtype=targets[0].boundary.dtype)
    boundary_valid = torch.zeros(len(frames), count, dtype=torch.bool)
    for k, t in enumerate(targets):
        boundary[k, : t.boundary.shape[1]] = t.boundary[0]
        boundary_valid[k, : t.boundary.shape[1]] = t.boundary_valid[0]
    return pe.Frames(
        torch.cat([f.keypoints for f in frames]),
        energies.SilhouetteTargets(torch.cat([t.outside for t in targets]), boundary,
                                   boundary_valid, torch.cat([t.scale for t in targets])),
    )
