"""Consensus shape in the canonical pose from unposed silhouette rays (Sec. B.3.3, Eq. B.6–B.11).

Given the poses of F frames and the person's masks, every silhouette boundary ray is matched to
a contour vertex of the posed model and mapped into the canonical pose by the inverse skinning
transform of that vertex (:mod:`monoavatar.fit.rays`). In the canonical frame one mesh is then
fitted to all frames' rays at once:

``E_cons = E_data + w_lp E_lp + w_var E_var + w_sym E_sym + w_rigid E_rigid``  (Eq. B.7)

- ``E_data``: Geman-McClure robust distance between each ray's vertex and its canonical ray.
  ``data_term="line"`` is Eq. B.8, the point-to-line distance ``ρ(|v × n − m|)`` in Plücker
  coordinates; ``"plane"`` (default) measures only the component across the silhouette, the
  distance to the plane through the line that contains the silhouette's tangent (the
  along-contour component of the line distance is set by which vertex happens to be nearest
  to the ray, up to half a vertex spacing, not by the shape). The term is normalised to the
  mean over rays times V, so the weights do not depend on how many frames or rays are used.
- ``E_lp`` (Eq. B.9): ``Σ τ_i |L(v)_i − δ_i|²``, uniform Laplacian L, δ the Laplacian of the
  mesh at (re-)initialisation (so that offsets vary smoothly);
- ``E_var`` (Eq. B.10): ``Σ τ_i |d_i − d_ref,i|²``: offsets stay small (``d_ref = 0``) or,
  with ``reinit``, near their value at the last correspondence step;
- ``E_sym`` (Eq. B.11): ``Σ |diag(−1, 1, 1) d_i − d_mirror(i)|²``;
- ``E_face`` (Eq. C.5–C.7, with ``face`` landmarks and ``w_face > 0``): Geman-McClure
  distance between each detected face-mesh landmark's unposed camera ray and its fixed point
  on the body's surface (:class:`~monoavatar.body.face_map.FaceMap`,
  :func:`monoavatar.fit.face.face_rays`), each landmark weighted by its confidence; normalised
  like ``E_data`` (``w_face`` times the confidence-weighted mean over the face rays, times V);
- ``E_rigid`` (not in the dissertation): ``Σ_edges τ_ij |d_i − d_j|²`` over the face, hands
  and feet, whose silhouettes say little about their shape: they keep the body model's shape
  and move as a whole (e.g. a foot follows the sole's rays down a longer leg instead of being
  stretched). By default (``rigid_regions``) the feet get a fiftieth of the face's and hands'
  weight: enough to keep them whole, not enough to keep a shoe (real displacement outside the
  body model) out of the avatar.

Vertices are ``v = T(β) + D``: the body model's rest shape for shape parameters β plus
per-vertex offsets D (SMPL+D, Eq. B.3). The optimisation alternates (B.6.1): correspondence
search (pose the current canonical mesh into every frame; optionally correct each frame's
translation in the image plane), Levenberg-Marquardt steps on β (Jacobian by finite
differences) and, for the offsets, iteratively reweighted least squares: for fixed robust
weights E is quadratic in D, so each step is one sparse linear solve of size 3V
(Jacobi-preconditioned conjugate gradients). The robust scale shrinks and the regulariser
weights are lowered (``decay``) from round to round.

Units: metres. Scale: the result has the scale implied by the given poses, translations,
shape parameters and camera; nothing here resolves the monocular scale ambiguity (Sec. B.6.2):
a known height must be imposed by the pose step (or by rescaling the result).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import torch
from torch import Tensor

from monoavatar.body import REGIONS, BodyModel, lbs
from monoavatar.body.face_map import FaceMap
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.errors import MonoavatarError
from monoavatar.core.geometry import vertex_normals
from monoavatar.core.landmarks import NUM_FACE_LANDMARKS
from monoavatar.core.threads import torch_threads
from monoavatar.fit import shape_solver as solver
from monoavatar.fit.energies import geman_mcclure
from monoavatar.fit.face import face_rays
from monoavatar.fit.laplacian import edge_laplacian, symmetry_operators, uniform_laplacian
from monoavatar.fit.rays import (
    BoundarySamples,
    CanonicalRays,
    silhouette_boundary,
    silhouette_correspondences,
)

__all__ = [
    "CanonicalShape",
    "RoundDiagnostics",
    "ShapeFitError",
    "ShapeSettings",
    "fit_consensus_shape",
    "geman_mcclure",
]


class ShapeFitError(MonoavatarError, ValueError):
    """Invalid input to the consensus-shape fit (shapes, sizes, settings)."""


@dataclass(frozen=True)
class ShapeSettings:
    """Options of :func:`fit_consensus_shape`.

    Attributes:
        rounds: correspondence rounds (each: match rays, then optimise).
        shape_rounds: leading rounds that fit only the shape parameters (offsets held at 0).
        fit_shape: optimise the shape parameters β.
        fit_offsets: optimise the per-vertex offsets D (False: the shape-only baseline).
        offsets_along_normals: one offset per vertex along its canonical normal instead of a
            free 3D offset.
        data_term: ``"line"`` (point-to-line, Eq. B.8) or ``"plane"`` (point to the
            silhouette plane through the line).
        rays_per_frame: boundary samples per frame (spread evenly along the contours).
        max_frames: use at most this many frames, evenly spaced (None: all).
        sigma: Geman-McClure scale, metres; ``sigma_final`` is reached in the last round
            (geometric interpolation).
        w_laplacian, w_body, w_symmetry: initial weights of E_lp, E_var, E_sym (B.6.1).
        decay: factor applied to the three weights after every offset round.
        reinit: after each correspondence step, regularise towards the current mesh (δ and
            D_ref from it) rather than towards the body model without offsets.
        laplacian_regions, body_regions: (region name, τ multiplier) pairs for E_lp and
            E_var; regions of :data:`REGIONS` not listed get 1.
        w_rigid: weight of the rigidity term ``Σ_edges τ_ij |d_i − d_j|²`` that makes the
            offsets of regions that silhouettes barely constrain (face, hands, feet) nearly
            constant, so that these parts move as a whole instead of stretching; not decayed.
        rigid_regions: (region name, τ) pairs of the rigidity term; unlisted regions get 0.
        w_face: weight of E_face against E_data (0: no face term).
        face_min_facing: landmarks whose face point turns further away from the camera
            (cosine of its normal with the direction to the camera) are left out.
        face_max_turn: degrees; frames whose face turns further from the camera give no
            face rays.
        shape_prior: weight of ``|β − β_init|²`` in the β steps.
        shape_iterations: Gauss-Newton iterations on β per round.
        irls_iterations: reweighted sparse solves of the offsets per round.
        max_match_distance: matching radius around each boundary sample, metres at the
            person's depth (converted to pixels per frame).
        contour_cos: |cos| between normal and line of sight below which a vertex counts as on
            the contour. A vertex up to asin(contour_cos) before the contour generator lies
            inside the outline, so pulled onto a silhouette ray it pushes the outline out; a
            smaller value leaves fewer candidates, so samples are matched farther along the
            outline.
        normal_weight: pixels per unit of normal difference in the matching.
        min_normal_dot: minimum cosine between matched image normals.
        blur: Gaussian sigma (pixels) for the boundary normals and sub-pixel edges.
        refine_translations: correct each frame's translation in every correspondence step
            (absorbs translation errors of the poses; see
            :func:`monoavatar.fit.rays.silhouette_correspondences`).
        chunk: frames posed at once in the correspondence search.
        workers: threads that match and unpose the frames of a chunk side by side (the
            result does not depend on it).
        threads: torch intra-op threads during the fit (restored afterwards); None leaves
            them. The fit is many small tensor operations, for which threads cost more than
            they save.
    """

    rounds: int = 7
    shape_rounds: int = 1
    fit_shape: bool = True
    fit_offsets: bool = True
    offsets_along_normals: bool = False
    data_term: Literal["line", "plane"] = "plane"
    rays_per_frame: int = 300
    max_frames: int | None = None
    sigma: float = 0.06
    sigma_final: float = 0.01
    w_laplacian: float = 10.0
    w_body: float = 0.03
    w_symmetry: float = 1.0
    decay: float = 0.7
    reinit: bool = False
    laplacian_regions: tuple[tuple[str, float], ...] = (
        ("face", 4.0),
        ("hands", 10.0),
        ("feet", 4.0),
        ("hair", 0.2),
    )
    body_regions: tuple[tuple[str, float], ...] = ()
    w_rigid: float = 100.0
    rigid_regions: tuple[tuple[str, float], ...] = (("face", 1.0), ("hands", 1.0), ("feet", 0.02))
    w_face: float = 0.0
    face_min_facing: float = 0.2
    face_max_turn: float = 180.0
    shape_prior: float = 1e-3
    shape_iterations: int = 3
    irls_iterations: int = 1
    max_match_distance: float = 0.1
    contour_cos: float = 0.15
    normal_weight: float = 8.0
    min_normal_dot: float = 0.5
    blur: float = 1.5
    refine_translations: bool = True
    chunk: int = 8
    workers: int = 2
    threads: int | None = 1

    def __post_init__(self) -> None:
        if self.rounds < 1 or self.shape_rounds < 0:
            raise ShapeFitError(
                f"rounds must be >= 1 and shape_rounds >= 0, got {self.rounds}, {self.shape_rounds}"
            )
        if self.data_term not in ("line", "plane"):
            raise ShapeFitError(f"data_term must be 'line' or 'plane', got {self.data_term!r}")
        if self.rays_per_frame < 1:
            raise ShapeFitError(f"rays_per_frame must be >= 1, got {self.rays_per_frame}")
        if self.max_frames is not None and self.max_frames < 1:
            raise ShapeFitError(f"max_frames must be >= 1 or None, got {self.max_frames}")
        positive = {
            "sigma": self.sigma,
            "sigma_final": self.sigma_final,
            "max_match_distance": self.max_match_distance,
            "blur": self.blur,
        }
        for name, value in positive.items():
            if not value > 0:
                raise ShapeFitError(f"{name} must be > 0, got {value}")
        weights = {
            "w_laplacian": self.w_laplacian,
            "w_body": self.w_body,
            "w_symmetry": self.w_symmetry,
            "shape_prior": self.shape_prior,
            "w_rigid": self.w_rigid,
            "w_face": self.w_face,
        }
        for name, value in weights.items():
            if value < 0:
                raise ShapeFitError(f"{name} must be >= 0, got {value}")
        if not 0 < self.face_max_turn <= 180 or not -1 <= self.face_min_facing < 1:
            raise ShapeFitError(
                f"face_max_turn must lie in (0, 180] degrees and face_min_facing in [-1, 1), "
                f"got {self.face_max_turn}, {self.face_min_facing}"
            )
        if not 0 < self.decay <= 1:
            raise ShapeFitError(f"decay must lie in (0, 1], got {self.decay}")
        for attr in ("laplacian_regions", "body_regions", "rigid_regions"):
            pairs = tuple((str(n), float(v)) for n, v in getattr(self, attr))
            object.__setattr__(self, attr, pairs)
        for name, value in self.laplacian_regions + self.body_regions + self.rigid_regions:
            if name not in REGIONS:
                raise ShapeFitError(f"unknown region {name!r}; regions are {list(REGIONS)}")
            if value < 0:
                raise ShapeFitError(f"region weight of {name!r} must be >= 0, got {value}")
        if self.chunk < 1 or self.workers < 1:
            raise ShapeFitError(
                f"chunk and workers must be >= 1, got {self.chunk}, {self.workers}"
            )
        if self.threads is not None and self.threads < 1:
            raise ShapeFitError(f"threads must be >= 1 or None, got {self.threads}")


@dataclass(frozen=True)
class RoundDiagnostics:
    """What one correspondence round did.

    Attributes:
        round: index, from 0.
        stage: ``"shape"`` (β only) or ``"offsets"`` (β and D).
        rays: number of matched rays.
        median_distance_mm: median ray-to-vertex distance after the round, millimetres.
        inlier_fraction: fraction of rays closer than ``sigma`` after the round.
        face_rays: number of face rays (0 without the face term).
        face_median_mm: median face-point-to-ray distance after the round, millimetres
            (None without face rays).
        data, laplacian, body, symmetry: unweighted energy terms after the round
            (data normalised as in the module docstring; the others in m²).
        seconds: wall time of the round.
    """

    round: int
    stage: str
    rays: int
    median_distance_mm: float
    inlier_fraction: float
    data: float
    laplacian: float
    body: float
    symmetry: float
    seconds: float
    face_rays: int = 0
    face_median_mm: float | None = None


@dataclass(frozen=True)
class CanonicalShape:
    """The consensus shape (hand-off of :mod:`monoavatar.fit.shape`).

    Attributes:
        shape: (S,) shape parameters β of the body model.
        offsets: (V, 3) per-vertex offsets D in the canonical frame, metres.
        vertices: (V, 3) canonical vertices ``T(β) + D`` (zero pose), metres.
        faces: (F, 3) int64 triangles (the body model's).
        frames: (K,) indices of the frames (into the inputs) that were used.
        frame_shifts: (K, 3) world translations, metres, added to those frames' translations
            by the correspondence steps (zeros unless ``refine_translations``).
        diagnostics: one :class:`RoundDiagnostics` per round.
        seconds: total wall time of the fit.
    """

    shape: Tensor
    offsets: Tensor
    vertices: Tensor
    faces: Tensor
    frames: np.ndarray
    frame_shifts: np.ndarray
    diagnostics: list[RoundDiagnostics] = field(default_factory=list)
    seconds: float = 0.0


# -- public entry point -----------------------------------------------------------------------


def _check_inputs(
    body: BodyModel,
    masks: np.ndarray,
    camera: PinholeCamera,
    poses: Tensor,
    translations: Tensor,
    shape_init: Tensor,
    transforms: Tensor | None,
) -> None:
    if masks.ndim != 3:
        raise ShapeFitError(f"masks: expected (F, H, W), got shape {masks.shape}")
    F = masks.shape[0]
    if F == 0:
        raise ShapeFitError("masks: no frames given")
    if masks.shape[1:] != (camera.height, camera.width):
        raise ShapeFitError(
            f"masks are {masks.shape[2]}x{masks.shape[1]} but the camera is "
            f"{camera.width}x{camera.height}"
        )
    J = body.num_joints
    if tuple(poses.shape) != (F, J, 3):
        raise ShapeFitError(f"poses: expected ({F}, {J}, 3) axis-angle, got {tuple(poses.shape)}")
    if tuple(translations.shape) != (F, 3):
        raise ShapeFitError(f"translations: expected ({F}, 3), got {tuple(translations.shape)}")
    if tuple(shape_init.shape) != (body.shape_dim,):
        raise ShapeFitError(
            f"shape_init: expected ({body.shape_dim},), got {tuple(shape_init.shape)}"
        )
    if transforms is not None and tuple(transforms.shape) != (F, J, 4, 4):
        raise ShapeFitError(f"transforms: expected ({F}, {J}, 4, 4), got {tuple(transforms.shape)}")


def _key_frames(count: int, limit: int | None) -> np.ndarray:
    if limit is None or limit >= count:
        return np.arange(count)
    return np.unique(np.linspace(0, count - 1, limit).round().astype(np.int64))


def _region_tau(
    body: BodyModel, region_weights: Sequence[tuple[str, float]], default: float = 1.0
) -> np.ndarray:
    factor = np.full(len(REGIONS), default)
    for name, value in region_weights:
        factor[REGIONS.index(name)] = value
    return np.asarray(factor[body.regions.cpu().numpy()])


def fit_consensus_shape(
    body: BodyModel,
    masks: np.ndarray,
    camera: PinholeCamera,
    poses: Tensor | np.ndarray,
    translations: Tensor | np.ndarray,
    shape_init: Tensor | np.ndarray,
    settings: ShapeSettings | None = None,
    *,
    transforms: Tensor | None = None,
    offsets_init: Tensor | np.ndarray | None = None,
    face: np.ndarray | None = None,
    face_map: FaceMap | None = None,
    progress: bool = False,
) -> CanonicalShape:
    """Fit the consensus shape (β and offsets D) of a person to the silhouettes of F frames
    with known poses (Sec. B.3.3).

    Args:
        body: the body model (e.g. ``load_body_model("anny")``).
        masks: (F, H, W) bool person masks, the camera's image size.
        camera: the (static) camera of all frames.
        poses: (F, J, 3) axis-angle joint rotations, radians (the body's skeleton).
        translations: (F, 3) root translations, metres.
        shape_init: (S,) initial shape parameters (e.g. from pose fitting).
        settings: options, :class:`ShapeSettings` defaults when None.
        transforms: optional (F, J, 4, 4) rest → posed joint transforms to pose and unpose
            with instead of those of ``poses``/``translations`` on the current shape's skeleton
            (e.g. a ground-truth skeleton's; they are then held fixed while β changes).
        offsets_init: optional (V, 3) offsets D to start from, metres; they are also the
            reference of E_var and E_lp (the fit stays near them where the rays say little),
            e.g. a learned prediction (``reconstruct --fast``). None: start from D = 0.
        face: (F, 468, 3) face-mesh landmarks per frame (x px, y px, confidence; NaN rows
            where no face was found) for E_face, with ``face_map`` the landmarks' points on
            the body; used when ``settings.w_face > 0``.
        progress: print one line per round.
    Returns:
        :class:`CanonicalShape`.
    Raises:
        ShapeFitError: inconsistent input shapes or settings.
    """
    settings = settings or ShapeSettings()
    with torch_threads(settings.threads):
        return _fit(
            body, masks, camera, poses, translations, shape_init, settings, transforms,
            offsets_init, face if face_map is not None and settings.w_face > 0 else None,
            face_map, progress,
        )  # fmt: skip


def _fit(
    body: BodyModel,
    masks: np.ndarray,
    camera: PinholeCamera,
    poses: Tensor | np.ndarray,
    translations: Tensor | np.ndarray,
    shape_init: Tensor | np.ndarray,
    settings: ShapeSettings,
    transforms: Tensor | None,
    offsets_init: Tensor | np.ndarray | None,
    face: np.ndarray | None,
    face_map: FaceMap | None,
    progress: bool,
) -> CanonicalShape:
    t_start = time.perf_counter()
    masks = np.asarray(masks, dtype=bool)
    poses_t = torch.as_tensor(poses, dtype=torch.float64)
    trans_t = torch.as_tensor(translations, dtype=torch.float64)
    beta_t = torch.as_tensor(shape_init, dtype=torch.float64)
    _check_inputs(body, masks, camera, poses_t, trans_t, beta_t, transforms)
    expected = (masks.shape[0], NUM_FACE_LANDMARKS, 3)
    if face is not None and face.shape != expected:
        raise ShapeFitError(f"face: expected {expected}, got {face.shape}")

    frames = _key_frames(masks.shape[0], settings.max_frames)
    samples: list[BoundarySamples] = [
        silhouette_boundary(masks[f], settings.rays_per_frame, settings.blur) for f in frames
    ]
    rotations = lbs.axis_angle_to_matrix(poses_t[frames])
    trans_f = trans_t[frames]
    fixed_tf = None if transforms is None else transforms[frames].to(torch.float64)
    # matching radius in pixels: max_match_distance at the depth of the root
    depth = camera.world_to_camera(trans_f)[:, 2].clamp_min(0.1).numpy()
    radius = settings.max_match_distance * camera.K[0, 0] / depth

    faces_np = body.faces.cpu().numpy()
    V = body.num_vertices
    sym_x, sym_yz = symmetry_operators(body.mirror.cpu().numpy())
    problem = solver.Problem(
        body=body,
        laplacian=uniform_laplacian(faces_np, V),
        sym_x=sym_x,
        sym_yz=sym_yz,
        tau_lp=_region_tau(body, settings.laplacian_regions),
        tau_var=_region_tau(body, settings.body_regions),
        rigidity=settings.w_rigid
        * edge_laplacian(faces_np, V, _region_tau(body, settings.rigid_regions, default=0.0)),
        num_vertices=V,
    )
    beta_init = beta_t.numpy().copy()
    beta = beta_init.copy()
    prior = np.zeros((V, 3))
    if offsets_init is not None:
        prior = torch.as_tensor(offsets_init, dtype=torch.float64).numpy().copy()
        if prior.shape != (V, 3):
            raise ShapeFitError(f"offsets_init must have shape ({V}, 3), got {prior.shape}")
    offsets = prior.copy()
    shift_total = np.zeros((len(frames), 3))
    diagnostics: list[RoundDiagnostics] = []
    w_lp, w_var, w_sym = settings.w_laplacian, settings.w_body, settings.w_symmetry
    rounds = settings.rounds
    for r in range(rounds):
        t0 = time.perf_counter()
        frac = r / max(rounds - 1, 1)
        sigma = settings.sigma * (settings.sigma_final / settings.sigma) ** frac
        rest = solver.rest_vertices(body, beta)
        canonical = torch.as_tensor(rest + offsets, dtype=body.dtype)
        if fixed_tf is None:
            with torch.no_grad():
                _, joints = body.rest_shape(torch.as_tensor(beta, dtype=body.dtype)[None])
            tf = lbs.joint_transforms(
                rotations,
                joints.double().expand(len(frames), -1, -1),
                body.parents,
                trans_f,
            )
        else:
            tf = fixed_tf
        tf = tf.clone()
        tf[:, :, :3, 3] += torch.as_tensor(shift_total, dtype=tf.dtype)[:, None]
        rays, shifts = silhouette_correspondences(
            body,
            canonical,
            tf,
            samples,
            camera,
            rotations=rotations,
            max_distance=radius,
            max_cos=settings.contour_cos,
            normal_weight=settings.normal_weight,
            min_dot=settings.min_normal_dot,
            shift_sigma=sigma if settings.refine_translations else None,
            chunk=settings.chunk,
            workers=settings.workers,
        )
        shift_total += shifts
        n_sil = len(rays)
        if n_sil == 0:
            raise ShapeFitError("no silhouette ray matched the model: check poses and masks")
        proj = solver.projectors(rays, settings.data_term)
        scale: float | np.ndarray = V / n_sil
        n_face = 0
        if face is not None and face_map is not None:
            tf_face = tf.clone()
            tf_face[:, :, :3, 3] += torch.as_tensor(shifts, dtype=tf.dtype)[:, None]
            frays, conf = face_rays(body, face_map, canonical, tf_face, face[frames], camera,
                                    rotations=rotations, min_facing=settings.face_min_facing,
                                    max_turn_deg=settings.face_max_turn)
            n_face = len(frays)
            if n_face:
                rays = CanonicalRays.concatenate([rays, frays])
                proj = np.concatenate([proj, solver.projectors(frays, "line")])
                scale = np.concatenate([np.full(n_sil, V / n_sil),
                                        settings.w_face * V * conf / conf.sum()])
        stage = "shape" if (r < settings.shape_rounds or not settings.fit_offsets) else "offsets"
        anchor = rays.closest_points()
        if settings.fit_shape:
            beta = solver.shape_step(
                problem, beta, beta_init, offsets, rays, proj, anchor, sigma, scale, settings
            )
            rest = solver.rest_vertices(body, beta)
        if stage == "offsets":
            reference = offsets.copy() if settings.reinit else prior
            normals = None
            if settings.offsets_along_normals:
                normals = vertex_normals(rest + offsets, faces_np).numpy()
                offsets = np.einsum("vc,vc->v", offsets, normals)[:, None] * normals
            offsets = solver.offset_step(
                problem,
                rest,
                offsets,
                reference,
                rays,
                proj,
                anchor,
                sigma,
                scale,
                (w_lp, w_var, w_sym),
                normals,
                settings.irls_iterations,
            )
            w_lp, w_var, w_sym = (w * settings.decay for w in (w_lp, w_var, w_sym))
        d2 = solver.squared_distances(rest + offsets, rays, proj, anchor)
        lap = problem.laplacian @ offsets
        sym = np.stack(
            [
                problem.sym_x @ offsets[:, 0],
                problem.sym_yz @ offsets[:, 1],
                problem.sym_yz @ offsets[:, 2],
            ],
            axis=1,
        )
        diag = RoundDiagnostics(
            round=r,
            stage=stage,
            rays=n_sil,
            median_distance_mm=float(np.sqrt(np.median(d2[:n_sil])) * 1000),
            inlier_fraction=float(np.mean(d2[:n_sil] < sigma * sigma)),
            data=solver.data_energy(d2[:n_sil], sigma, V / n_sil),
            laplacian=float(np.sum(problem.tau_lp[:, None] * lap**2)),
            body=float(np.sum(problem.tau_var[:, None] * offsets**2)),
            symmetry=float(np.sum(sym**2)),
            seconds=time.perf_counter() - t0,
            face_rays=n_face,
            face_median_mm=float(np.sqrt(np.median(d2[n_sil:])) * 1000) if n_face else None,
        )
        diagnostics.append(diag)
        if progress:
            print(
                f"round {r} ({stage}): {diag.rays} rays, median {diag.median_distance_mm:.2f} mm, "
                f"inliers {diag.inlier_fraction:.2f}, {diag.seconds:.2f} s"
            )
    rest = solver.rest_vertices(body, beta)
    dtype = body.dtype
    return CanonicalShape(
        shape=torch.as_tensor(beta, dtype=dtype),
        offsets=torch.as_tensor(offsets, dtype=dtype),
        vertices=torch.as_tensor(rest + offsets, dtype=dtype),
        faces=body.faces.clone(),
        frames=frames,
        frame_shifts=shift_total,
        diagnostics=diagnostics,
        seconds=time.perf_counter() - t_start,
    )
