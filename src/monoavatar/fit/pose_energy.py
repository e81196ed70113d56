"""The pose energy of Sec. B.3.2 and its optimiser, for every fitter that poses the body to
observations: :mod:`~monoavatar.fit.pose` (initialisation, tracking, refinement),
:mod:`~monoavatar.fit.flow_refine` (with flow and outline correspondences) and the tracker.

The body is posed at a fixed random subset of its vertices (:class:`Subset`, the model points)
with the shape fixed. Energy per frame (:func:`energy_terms`, weighted by
:func:`weighted_energy`): robust confidence-weighted keypoints; silhouette (Eq. B.4) on a
Gaussian pyramid; A-pose prior; joint limits; capsule self-penetration of forearms and torso;
optional flow and outline correspondences (:class:`Correspondences`); temporal smoothness across
a window (:func:`fit_window`).

The silhouette term gets its gradient without a differentiable rasteriser: the model points are
projected, and (i) the distance transform of the observed mask's complement is sampled
bilinearly at them (model outside the mask), and (ii) each observed boundary pixel is pulled by
its nearest projected model point (mask the model misses).

Optimiser: L-BFGS with a strong-Wolfe line search on all frames of a window at once
(:func:`lbfgs`, :func:`fit_window`); frames fitted each on its own are batched with one L-BFGS
state per frame (:func:`fit_frames`). Image-space residuals are in percent of the person's
height in pixels.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from monoavatar.body import BodyModel, lbs
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.errors import MonoavatarError
from monoavatar.core.landmarks import MEDIAPIPE_MIRROR
from monoavatar.fit import energies
from monoavatar.fit.batched_lbfgs import minimize_rows
from monoavatar.fit.prior import PosePrior
from monoavatar.perception.observations import Observations


class PoseSettingsError(MonoavatarError, ValueError):
    """A pose-fitting option out of its range (the message names it)."""


@dataclass
class PoseSettings:
    """Options of pose fitting (``ReconstructConfig.pose`` in Python; the CLI sets ``height``
    from ``--height`` and keeps the other defaults).

    Weights multiply energies measured in percent of the person's height (image terms),
    radians (prior, limits, smoothness) and centimetres (penetration).
    """

    height: float | None = None  # metres; None: up to scale
    init_frames: int = 5
    init_span: float = 0.08  # the init frames are spread over this fraction of the sequence
    init_iterations: int = 80
    window: int = 8
    iterations: int = 40
    refine_iterations: int = 20  # per window in refine_poses (it starts from a good fit)
    rigid_iterations: int = 10  # root rotation and translation alone, before each window
    keypoint_weight: float = 1.0
    keypoint_sigma: float = 10.0  # percent of height
    min_confidence: float = 0.3
    outside_weight: float = 0.5
    coverage_weight: float = 0.1
    coverage_sigma: float = 10.0
    prior_weight: float = 0.05
    limit_weight: float = 100.0
    smooth_weight: float = 20.0
    penetration_weight: float = 0.01
    shape_prior_weight: float = 1.0
    height_weight: float = 1.0e4
    pyramid_levels: int = 4
    silhouette_points: int = 1200
    boundary_points: int = 300
    threads: int = 1  # PyTorch threads while fitting (small tensors: one is fastest)
    refit_factor: float = 3.0
    flip_penalty_deg: float | None = 30.0  # None: keep frames that face against the turn
    flip_energy_factor: float = 3.0
    fail_energy: float = 20.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.height is not None and not 0.5 <= self.height <= 2.6:
            raise PoseSettingsError(
                f"height must be in metres, between 0.5 and 2.6, got {self.height} "
                "(a value like 175 is centimetres: use 1.75)"
            )
        for name in ("init_frames", "window", "iterations", "init_iterations",
                     "refine_iterations", "pyramid_levels", "silhouette_points",
                     "boundary_points"):  # fmt: skip
            if getattr(self, name) < 1:
                raise PoseSettingsError(f"{name} must be at least 1, got "
                                        f"{getattr(self, name)}")  # fmt: skip


# -- the posed model at a subset of vertices ---------------------------------------------------


@dataclass(frozen=True)
class Subset:
    """The body with a fixed shape, posed only at a subset of vertices (the silhouette points)
    and at its keypoints. ``rest``, ``weights`` and ``offsets`` carry a leading frame
    dimension B when every frame has points of its own (:func:`fit_frames`); ``valid`` then
    says which are real and which pad the frames to one count."""

    rest: Tensor  # (M, 3) or (B, M, 3) rest positions of the silhouette points
    weights: Tensor  # (M, J) or (B, M, J)
    rest_joints: Tensor  # (J, 3)
    keypoint_basis: Tensor  # (33, J, 4): see keypoint_basis
    parents: tuple[int, ...]
    offsets: Tensor | None = None  # (M, 3) or (B, M, 3) canonical offsets D of the points
    valid: Tensor | None = None  # (B, M) bool: the real points (None: all)

    def pose(self, rotations: Tensor, translation: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """rotations (B, J, 3, 3), translation (B, 3) → keypoints (B, 33, 3) of the body,
        joints (B, J, 3) and silhouette points (B, M, 3) (with the offsets, when the subset
        has them; the keypoints go without)."""
        return self.posed(self.transforms(rotations, translation))

    def transforms(self, rotations: Tensor, translation: Tensor) -> Tensor:
        """(B, J, 4, 4) the joint transforms of rotations (B, J, 3, 3), translation (B, 3)."""
        joints = self.rest_joints.expand(rotations.shape[0], -1, -1)
        return lbs.joint_transforms(rotations, joints, self.parents, translation)

    def posed(self, transforms: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """:meth:`pose` from joint transforms (B, J, 4, 4)."""
        b = transforms.shape[0]
        joints = self.rest_joints.expand(b, -1, -1)
        posed_joints = transforms[..., :3, 3] + (
            transforms[..., :3, :3] @ joints.unsqueeze(-1)
        ).squeeze(-1)
        rest = self.rest if self.offsets is None else self.rest + self.offsets
        silhouette = lbs.skin(rest.expand(b, -1, -1) if rest.dim() == 2 else rest,
                              self.weights, transforms)  # fmt: skip
        keypoints = torch.einsum("bjmn,kjn->bkm", transforms[:, :, :3, :], self.keypoint_basis)
        return keypoints, posed_joints, silhouette


class Variables:
    """Pose variables of B frames. The root rotation is a rotation vector ``delta`` (world
    axes) applied to a fixed reference ``root_ref``, so it has no wrap-around at half a turn
    (a person turning around passes it); the other joints are axis-angle."""

    def __init__(self, pose: np.ndarray, translation: np.ndarray, dtype: torch.dtype) -> None:
        p = torch.as_tensor(pose, dtype=dtype)
        self.root_ref = lbs.axis_angle_to_matrix(p[:, 0])
        self.delta = torch.zeros(p.shape[0], 3, dtype=dtype, requires_grad=True)
        self.body = p[:, 1:].clone().requires_grad_(True)
        self.translation = torch.as_tensor(translation, dtype=dtype).clone().requires_grad_(True)

    @classmethod
    def of(cls, root_ref: Tensor, delta: Tensor, body: Tensor, translation: Tensor) -> Variables:
        """Variables from tensors (B, 3, 3), (B, 3), (B, J − 1, 3), (B, 3), used as given."""
        var = cls.__new__(cls)
        var.root_ref, var.delta, var.body, var.translation = root_ref, delta, body, translation
        return var

    @property
    def params(self) -> list[Tensor]:
        return [self.delta, self.body, self.translation]

    def root(self) -> Tensor:
        return lbs.axis_angle_to_matrix(self.delta) @ self.root_ref

    def rotations(self) -> Tensor:
        """(B, J, 3, 3) joint rotations."""
        return torch.cat([self.root()[:, None], lbs.axis_angle_to_matrix(self.body)], dim=1)

    def numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-angle poses (B, J, 3) and translations (B, 3)."""
        with torch.no_grad():
            root = lbs.matrix_to_axis_angle(self.root())
            pose = torch.cat([root[:, None], self.body], dim=1)
        return pose.double().numpy().copy(), self.translation.detach().double().numpy().copy()


def subset_ids(body: BodyModel, count: int, seed: int) -> Tensor:
    """(M,) ids of ``count`` random vertices: the silhouette points."""
    rng = np.random.default_rng(seed)
    return torch.from_numpy(rng.choice(body.num_vertices, min(count, body.num_vertices), False))


def keypoint_basis(body: BodyModel, rest: Tensor) -> Tensor:
    """(33, J, 4) ``Σ_v K_kv w_vj (x_v, 1)`` for the keypoint regressor K (33, V), skinning
    weights w and rest vertices x (V, 3): LBS is linear in the rest position, so keypoint k of
    the posed body is ``Σ_j A_j[:3] basis_kj`` for joint transforms A (exactly what posing all
    of K's vertices and regressing gives, at the cost of 33 points instead of thousands).
    Differentiable in ``rest``."""
    k = body.keypoint_weights
    used = torch.nonzero(k.abs().sum(0) > 0).flatten()
    x = rest[used]
    homogeneous = torch.cat([x, torch.ones_like(x[:, :1])], dim=1)  # (U, 4)
    return torch.einsum("ku,uj,un->kjn", k[:, used], body.skin_weights[used], homogeneous)


def make_subset(body: BodyModel, rest: Tensor, joints: Tensor, ids: Tensor) -> Subset:
    """The subset at vertex ids (M,) for rest vertices (V, 3) and rest joints (J, 3) of one
    shape (differentiable in both)."""
    return Subset(
        rest=rest[ids],
        weights=body.skin_weights[ids],
        rest_joints=joints,
        keypoint_basis=keypoint_basis(body, rest),
        parents=tuple(body.parents),
    )


# -- energy --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Correspondences:
    """2D targets of the subset's silhouette points (e.g. from optical flow), per frame.

    Attributes:
        targets: (B, M, 2) pixel positions where each point should project.
        valid: (B, M) bool, which points have a target.
        weight: weight of the term (its energy is in percent of the person's height).
        sigma: Geman-McClure scale, percent of the person's height.
        normals: (B, M, 2) unit image normals: only the offset along them counts (outline
            points matched to the observed edge); None: the whole 2D offset.
    """

    targets: Tensor
    valid: Tensor
    weight: float
    sigma: float
    normals: Tensor | None = None


@dataclass(frozen=True)
class Frames:
    """Observations of a batch of frames, as tensors."""

    keypoints: Tensor  # (B, 33, 3), scaled confidences, low ones zeroed
    targets: energies.SilhouetteTargets
    flow: Correspondences | None = None  # only in the flow refinement
    contour: Correspondences | None = None  # outline points to the observed edge (ditto)


def frames_at(obs: Observations, idx: np.ndarray, settings: PoseSettings,
            dtype: torch.dtype) -> Frames:  # fmt: skip
    kp = obs.keypoints[idx].astype(np.float64).copy()
    kp[kp[..., 2] < settings.min_confidence, 2] = 0.0
    targets = energies.silhouette_targets(obs.masks[idx], settings.pyramid_levels,
                                          settings.boundary_points, settings.seed)  # fmt: skip
    targets = energies.SilhouetteTargets(
        outside=targets.outside.to(dtype),
        boundary=targets.boundary.to(dtype),
        boundary_valid=targets.boundary_valid,
        scale=(targets.scale / 100.0).to(dtype),  # percent of the person's height
    )
    return Frames(torch.as_tensor(kp, dtype=dtype), targets)


@dataclass(frozen=True)
class EnergyContext:
    body: BodyModel
    camera: PinholeCamera
    settings: PoseSettings
    prior: PosePrior
    limits: tuple[tuple[int, int, float, float], ...]
    torso_radius: float


def energy_context(body: BodyModel, camera: PinholeCamera, settings: PoseSettings, prior: PosePrior,
             rest: Tensor, joints: Tensor) -> EnergyContext:  # fmt: skip
    torso = body.regions == 0  # REGIONS[0] == "torso"
    pelvis, neck = joints[body.joint_index("pelvis")], joints[body.joint_index("neck")]
    points = rest[torso]
    d = energies.segment_distance(points, pelvis.expand_as(points), neck.expand_as(points))
    radius = float(0.8 * d.median()) + 0.03
    return EnergyContext(body, camera, settings, prior.to(body.dtype), joint_limits(body), radius)


def joint_limits(body: BodyModel) -> tuple[tuple[int, int, float, float], ...]:
    """Soft limits (joint, axis, lo, hi) in radians on the body joints (index 0 = the first
    joint after the root): knees and elbows do not bend backwards or sideways much (canonical
    axes: knee flexion is +X, elbow flexion −X)."""
    out = []
    for side in ("l", "r"):
        knee = body.joint_index(f"knee_{side}") - 1
        out += [(knee, 0, -0.1, 2.6), (knee, 2, -0.4, 0.4)]
        out.append((body.joint_index(f"elbow_{side}") - 1, 0, -2.6, 0.15))
    return tuple(out)


def energy_terms(ctx: EnergyContext, sub: Subset, var: Variables, frames: Frames,
                 posed: tuple[Tensor, Tensor, Tensor] | None = None
                 ) -> dict[str, Tensor]:  # fmt: skip
    """Per-frame (B,) values of each energy term (unweighted); ``posed``: the subset already
    posed by ``var`` (:meth:`Subset.pose`), when at hand."""
    body = ctx.body
    keypoints, joints, silhouette = (posed if posed is not None
                                     else sub.pose(var.rotations(), var.translation))  # fmt: skip
    kp_px, _ = ctx.camera.project(keypoints)
    sil_px, _ = ctx.camera.project(silhouette)
    s = ctx.settings
    b = var.body.shape[0]
    terms = {
        "keypoints": energies.keypoint_energy(kp_px, frames.keypoints, frames.targets.scale,
                                              s.keypoint_sigma),  # fmt: skip
        "outside": energies.outside_energy(sil_px, frames.targets, sub.valid),
        "coverage": energies.coverage_energy(sil_px, frames.targets, s.coverage_sigma,
                                             sub.valid),  # fmt: skip
        "prior": energies.gaussian_prior_energy(var.body.reshape(b, -1), ctx.prior.mean,
                                                ctx.prior.precision),  # fmt: skip
        "limits": energies.hinge_limit_energy(var.body, ctx.limits),
    }
    for name in ("flow", "contour"):
        c = getattr(frames, name)
        if c is not None:
            terms[name] = energies.correspondence_energy(
                sil_px, c.targets, c.valid, frames.targets.scale, c.sigma, c.normals
            )
    pelvis, neck = body.joint_index("pelvis"), body.joint_index("neck")
    pen = torch.zeros_like(terms["limits"])
    for side in ("l", "r"):
        elbow = joints[:, body.joint_index(f"elbow_{side}")]
        wrist = joints[:, body.joint_index(f"wrist_{side}")]
        points = torch.stack([wrist, 0.5 * (elbow + wrist)], dim=1)
        pen = pen + energies.penetration_energy(points, joints[:, pelvis], joints[:, neck],
                                                ctx.torso_radius)  # fmt: skip
    terms["penetration"] = pen
    return terms


def weighted_energy(ctx: EnergyContext, terms: dict[str, Tensor], flow_weight: float = 0.0,
              contour_weight: float = 0.0) -> Tensor:  # fmt: skip
    """The weighted sum of the terms; the flow and contour terms (when present) count with
    ``flow_weight`` and ``contour_weight``."""
    s = ctx.settings
    total = (
        s.keypoint_weight * terms["keypoints"]
        + s.outside_weight * terms["outside"]
        + s.coverage_weight * terms["coverage"]
        + s.prior_weight * terms["prior"]
        + s.limit_weight * terms["limits"]
        + s.penetration_weight * terms["penetration"]
    )
    if "flow" in terms:
        total = total + flow_weight * terms["flow"]
    if "contour" in terms:
        total = total + contour_weight * terms["contour"]
    return total


def lbfgs(params: list[Tensor], closure: Callable[[], Tensor], iterations: int) -> None:
    optimiser = torch.optim.LBFGS(params, lr=1.0, max_iter=iterations, history_size=20,
                                  line_search_fn="strong_wolfe", tolerance_grad=1e-7,
                                  tolerance_change=1e-9)  # fmt: skip

    def step() -> Tensor:
        optimiser.zero_grad()
        loss = closure()
        loss.backward()
        return loss

    optimiser.step(step)


# -- fitting a window of frames ------------------------------------------------------------


def frame_slice(frames: Frames, k: int) -> Frames:
    t = frames.targets
    return Frames(
        frames.keypoints[k : k + 1],
        energies.SilhouetteTargets(t.outside[k : k + 1], t.boundary[k : k + 1],
                                   t.boundary_valid[k : k + 1], t.scale[k : k + 1]),  # fmt: skip
    )


def fix_swaps(ctx: EnergyContext, sub: Subset, frames: Frames, pred_p: np.ndarray,
               pred_t: np.ndarray) -> Frames:  # fmt: skip
    """Undo the detector's left/right swaps: where the predicted pose explains the keypoints
    with left and right exchanged much better, exchange them."""
    dtype = frames.keypoints.dtype
    with torch.no_grad():
        keypoints, _, _ = sub.pose(
            lbs.axis_angle_to_matrix(torch.as_tensor(pred_p, dtype=dtype)),
            torch.as_tensor(pred_t, dtype=dtype),
        )
        kp_px, _ = ctx.camera.project(keypoints)
        scale = frames.targets.scale
        sigma = ctx.settings.keypoint_sigma
        as_is = energies.keypoint_energy(kp_px, frames.keypoints, scale, sigma)
        swapped_kp = frames.keypoints[:, list(MEDIAPIPE_MIRROR)]
        swapped = energies.keypoint_energy(kp_px, swapped_kp, scale, sigma)
    swap = swapped < 0.5 * as_is
    if not bool(swap.any()):
        return frames
    kp = torch.where(swap[:, None, None], swapped_kp, frames.keypoints)
    return Frames(kp, frames.targets)


def fit_window(ctx: EnergyContext, sub: Subset, frames: Frames, pred_p: np.ndarray,
                pred_t: np.ndarray, history: tuple[Tensor, Tensor, Tensor] | None,
                iterations: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit B frames together from predicted poses (B, J, 3) and translations (B, 3). Returns
    poses, translations and the per-frame energy without the smoothness, flow and contour terms."""
    var = Variables(pred_p, pred_t, frames.keypoints.dtype)
    s = ctx.settings
    flow_weight = frames.flow.weight if frames.flow is not None else 0.0
    contour_weight = frames.contour.weight if frames.contour is not None else 0.0

    def total() -> Tensor:
        e = weighted_energy(ctx, energy_terms(ctx, sub, var, frames), flow_weight, contour_weight)
        smooth = energies.smoothness_energy(var.root(), var.body, var.translation, history)
        return (e + s.smooth_weight * smooth).sum()

    if s.rigid_iterations:  # the global rotation and translation first: well conditioned
        lbfgs([var.delta, var.translation], total, s.rigid_iterations)
    lbfgs(var.params, total, iterations or s.iterations)
    with torch.no_grad():
        e = weighted_energy(ctx, energy_terms(ctx, sub, var, frames))
    p, t = var.numpy()
    return p, t, e.double().numpy().copy()


def select_frames(sub: Subset, frames: Frames, rows: Tensor) -> tuple[Subset, Frames]:
    """Frames ``rows`` (R,) int64 of a batch: the subset's per-frame points (when it has them)
    and every observation, for :func:`fit_frames`' line search."""

    def pick(x: Tensor | None, batched: bool = True) -> Tensor | None:
        return x.index_select(0, rows) if x is not None and batched else x

    def pick_c(c: Correspondences | None) -> Correspondences | None:
        if c is None:
            return None
        return Correspondences(c.targets.index_select(0, rows), c.valid.index_select(0, rows),
                               c.weight, c.sigma, pick(c.normals))  # fmt: skip

    per_frame = sub.rest.dim() == 3
    sub_r = Subset(pick(sub.rest, per_frame), pick(sub.weights, per_frame),  # type: ignore[arg-type]
                   sub.rest_joints, sub.keypoint_basis, sub.parents,
                   pick(sub.offsets, per_frame), pick(sub.valid))  # fmt: skip
    t = frames.targets
    targets = energies.SilhouetteTargets(t.outside.index_select(0, rows),
                                         t.boundary.index_select(0, rows),
                                         t.boundary_valid.index_select(0, rows),
                                         t.scale.index_select(0, rows))  # fmt: skip
    return sub_r, Frames(frames.keypoints.index_select(0, rows), targets, pick_c(frames.flow),
                         pick_c(frames.contour))  # fmt: skip


def fit_frames(ctx: EnergyContext, sub: Subset, frames: Frames, pred_p: np.ndarray,
               pred_t: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit B frames each on its own (no smoothness between them), in one batched pass: one
    L-BFGS state per frame (:func:`monoavatar.fit.batched_lbfgs.minimize_rows`), the energies
    of all frames evaluated together. ``sub`` may hold points of each frame's own
    (:class:`Subset`). Returns poses (B, J, 3), translations (B, 3) and the per-frame energy
    without the flow and contour terms, as :func:`fit_window`."""
    dtype = frames.keypoints.dtype
    b = pred_p.shape[0]
    flow_weight = frames.flow.weight if frames.flow is not None else 0.0
    contour_weight = frames.contour.weight if frames.contour is not None else 0.0
    root_ref = lbs.axis_angle_to_matrix(torch.as_tensor(pred_p[:, 0], dtype=dtype))

    def variables(x: Tensor, rows: Tensor) -> Variables:
        """x (R, 3 + 3 (J − 1) + 3): the root's delta, the body joints, the translation."""
        return Variables.of(root_ref.index_select(0, rows), x[:, :3],
                            x[:, 3:-3].reshape(len(rows), -1, 3), x[:, -3:])  # fmt: skip

    def energy(x: Tensor, rows: Tensor) -> Tensor:
        s, f = (sub, frames) if len(rows) == b else select_frames(sub, frames, rows)
        terms = energy_terms(ctx, s, variables(x, rows), f)
        return weighted_energy(ctx, terms, flow_weight, contour_weight)

    start = Variables(pred_p, pred_t, dtype)
    x = torch.cat([start.delta, start.body.reshape(b, -1), start.translation], 1).detach()
    if ctx.settings.rigid_iterations:  # the global rotation and translation first
        body = x[:, 3:-3]
        rigid = minimize_rows(
            lambda r, rows: energy(torch.cat([r[:, :3], body[rows], r[:, 3:]], 1), rows),
            torch.cat([x[:, :3], x[:, -3:]], 1), ctx.settings.rigid_iterations,
        )
        x = torch.cat([rigid.x[:, :3], body, rigid.x[:, 3:]], 1)
    var = variables(minimize_rows(energy, x, iterations).x, torch.arange(b))
    with torch.no_grad():
        e = weighted_energy(ctx, energy_terms(ctx, sub, var, frames))
    p, t = var.numpy()
    return p, t, e.double().numpy().copy()
