"""Pose and scale alignment of a rigged reconstruction to a ground-truth mesh.

The dissertation measures shape "after adjusting the pose and scale of the reconstruction to
match the ground truth" (Sec. B.4.2, D.4.2; following Zhang et al. 2017 and Bogo et al. 2015):
the reconstruction's *articulated* pose is fitted to the ground-truth surface, which separates
errors in pose (an arm held 5° higher in the canonical mesh) from errors in shape. This module
does that fit for a mesh that comes with a skeleton and skinning weights:

* variables: one similarity transform (scale, rotation, translation) and the rotations of
  every non-root joint (axis-angle, radians, local to the parent in canonical axes);
* objective: the symmetric mean squared point-to-surface distance (the reconstruction's
  vertices to the ground-truth surface, and the ground-truth vertices to the posed
  reconstruction's surface), linearised at the closest points as point-to-plane plus a tenth of
  point-to-point, and a weak pull of the joint rotations towards zero;
* iteration: exact closest surface points are found for the current pose, then L-BFGS
  minimises the distances to them with the pairs held fixed (articulated ICP).

The result is only the pose: the shape (rest vertices) is never changed, so what the metric
still measures afterwards is shape error.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np
import torch
from numpy.typing import ArrayLike

from monoavatar.body import lbs
from monoavatar.eval._checks import FloatArray, as_faces, as_points
from monoavatar.eval.alignment import SimilarityTransform
from monoavatar.eval.icp import subsample
from monoavatar.eval.surface import TriangleIndex, closest_points_on_mesh

__all__ = ["PoseAlignment", "align_pose_and_scale"]


@dataclass(frozen=True)
class PoseAlignment:
    """Result of :func:`align_pose_and_scale`.

    Attributes:
        vertices: (V, 3) the reconstruction posed and transformed onto the ground truth, metres.
        pose: (J, 3) the fitted joint rotations, axis-angle radians (row 0, the root, is zero:
            the similarity transform holds the global rotation).
        transform: the similarity transform applied after posing.
        iterations: outer (closest-point) iterations run.
    """

    vertices: FloatArray
    pose: FloatArray
    transform: SimilarityTransform
    iterations: int


def _posed(rest: torch.Tensor, weights: torch.Tensor, joints: torch.Tensor,
           parents: Sequence[int], body_pose: torch.Tensor, log_scale: torch.Tensor,
           rotvec: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:  # fmt: skip
    """(V, 3): skin the rest mesh at ``body_pose`` (J-1, 3), then ``s R x + t``."""
    pose = torch.cat([torch.zeros_like(body_pose[:1]), body_pose])
    rotations = lbs.axis_angle_to_matrix(pose)[None]
    transforms = lbs.joint_transforms(rotations, joints[None], parents)
    skinned = lbs.skin(rest[None], weights, transforms)[0]
    rotation = lbs.axis_angle_to_matrix(rotvec)
    return torch.exp(log_scale) * skinned @ rotation.T + translation


def _face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) unit normals of the triangles (zero for degenerate ones)."""
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _plane_and_point(residual: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
    """Mean of the squared point-to-plane distance plus a tenth of the squared point-to-point
    distance: the plane term lets the surfaces slide along each other (fast convergence, as in
    :func:`~monoavatar.eval.align_icp`), the point term keeps the problem well posed."""
    along = (residual * normal).sum(-1)
    return (along**2 + 0.1 * (residual**2).sum(-1)).mean()


def _loss(current: Callable[[], torch.Tensor], src: torch.Tensor, forward: torch.Tensor,
          n_fwd: torch.Tensor, corner: torch.Tensor, bary: torch.Tensor, target: torch.Tensor,
          n_bwd: torch.Tensor, body_pose: torch.Tensor, pose_weight: float) -> torch.Tensor:
    """The objective with the closest-point pairs held fixed (distances in mm²)."""
    v = current()
    e_fwd = _plane_and_point(v[src] - forward, n_fwd)
    e_bwd = _plane_and_point((bary * v[corner]).sum(1) - target, n_bwd)
    return 1e6 * 0.5 * (e_fwd + e_bwd) + pose_weight * (body_pose**2).sum()


def _minimise(params: list[torch.Tensor], loss: Callable[[], torch.Tensor],
              iterations: int) -> None:  # fmt: skip
    optimiser = torch.optim.LBFGS(params, lr=1.0, max_iter=iterations, history_size=20,
                                  line_search_fn="strong_wolfe")  # fmt: skip

    def closure() -> torch.Tensor:
        optimiser.zero_grad()
        value = loss()
        value.backward()
        return value

    optimiser.step(closure)


def align_pose_and_scale(
    rest_vertices: ArrayLike,
    faces: ArrayLike,
    skin_weights: ArrayLike,
    rest_joints: ArrayLike,
    parents: Sequence[int],
    target_vertices: ArrayLike,
    target_faces: ArrayLike,
    init: SimilarityTransform,
    *,
    iterations: int = 15,
    inner_iterations: int = 30,
    max_points: int = 2000,
    pose_weight: float = 1.0,
) -> PoseAlignment:
    """Fit the articulated pose, scale, rotation and translation of a rigged mesh to a target.

    Args:
        rest_vertices: (V, 3) the reconstruction in its rest pose, metres.
        faces: (F, 3) its triangles.
        skin_weights: (V, J) its skinning weights (rows sum to 1).
        rest_joints: (J, 3) its rest joint positions, metres.
        parents: J parent indices (``parents[0] = -1``).
        target_vertices: (M, 3) ground-truth mesh vertices, metres.
        target_faces: (F_t, 3) its triangles.
        init: the starting similarity transform (e.g. the rigid ICP's result).
        iterations: closest-point iterations.
        inner_iterations: L-BFGS iterations per closest-point iteration.
        max_points: evenly spaced vertices per direction used for the fit (the caller measures
            the error on all of them).
        pose_weight: weight of ``sum(pose²)`` (radians²) against the mean squared distance in
            mm²; 1.0 lets 0.1 rad of rotation cost 0.01 mm², enough only to keep joints that
            the surface does not constrain (e.g. twist of a round limb) where they were.

    Returns:
        :class:`PoseAlignment`.
    """
    rest_np = as_points("rest_vertices", rest_vertices, min_count=1)
    faces_np = as_faces("faces", faces, rest_np.shape[0])
    target = as_points("target_vertices", target_vertices, min_count=1)
    target_f = as_faces("target_faces", target_faces, target.shape[0])
    w_np = np.asarray(skin_weights, dtype=np.float64)
    j_np = np.asarray(rest_joints, dtype=np.float64)
    if w_np.shape != (rest_np.shape[0], len(parents)) or j_np.shape != (len(parents), 3):
        raise ValueError(
            f"skin_weights {w_np.shape} and rest_joints {j_np.shape} must be (V, J) and (J, 3) "
            f"with V = {rest_np.shape[0]} and J = {len(parents)}"
        )
    dt = torch.float64
    rest = torch.as_tensor(rest_np, dtype=dt)
    weights = torch.as_tensor(w_np, dtype=dt)
    joints = torch.as_tensor(j_np, dtype=dt)
    src = torch.as_tensor(subsample(rest_np.shape[0], max_points), dtype=torch.long)
    tgt_sel = target[subsample(target.shape[0], max_points)]
    tgt_t = torch.as_tensor(tgt_sel, dtype=dt)

    target_normals = _face_normals(target, target_f)
    body_pose = torch.zeros(len(parents) - 1, 3, dtype=dt, requires_grad=True)
    log_scale = torch.tensor(float(np.log(init.scale)), dtype=dt, requires_grad=True)
    rotvec = lbs.matrix_to_axis_angle(torch.as_tensor(init.rotation, dtype=dt)).clone()
    rotvec.requires_grad_(True)
    translation = torch.as_tensor(init.translation, dtype=dt).clone().requires_grad_(True)
    params = [body_pose, log_scale, rotvec, translation]

    def current() -> torch.Tensor:
        return _posed(rest, weights, joints, parents, body_pose, log_scale, rotvec, translation)

    target_index = TriangleIndex(target[target_f])  # built once: the target does not move
    for _ in range(iterations):
        with torch.no_grad():
            posed = current().numpy()
        hit = target_index.query(posed[src.numpy()])
        forward = torch.as_tensor(hit.points, dtype=dt)
        n_fwd = torch.as_tensor(target_normals[hit.face_indices], dtype=dt)
        backward = closest_points_on_mesh(tgt_sel, posed, faces_np)
        corner = faces_np[backward.face_indices]  # (K, 3)
        # the objective needs only these vertices: skin just them in the inner iterations
        used, inverse = np.unique(np.concatenate([src.numpy(), corner.ravel()]),
                                  return_inverse=True)  # fmt: skip
        used_t = torch.as_tensor(used, dtype=torch.long)
        src_in = torch.as_tensor(inverse[: len(src)], dtype=torch.long)
        corner_in = torch.as_tensor(inverse[len(src) :].reshape(corner.shape), dtype=torch.long)
        bary = torch.as_tensor(backward.barycentric, dtype=dt)[..., None]  # (K, 3, 1)
        n_bwd = torch.as_tensor(_face_normals(posed, faces_np)[backward.face_indices], dtype=dt)
        subset = partial(_posed, rest[used_t], weights[used_t], joints, parents, body_pose,
                         log_scale, rotvec, translation)  # fmt: skip
        _minimise(params, partial(_loss, subset, src_in, forward, n_fwd, corner_in, bary, tgt_t,
                                  n_bwd, body_pose, pose_weight), inner_iterations)  # fmt: skip

    with torch.no_grad():
        vertices = current().numpy()
        rotation = lbs.axis_angle_to_matrix(rotvec).numpy()
        pose = torch.cat([torch.zeros(1, 3, dtype=dt), body_pose]).numpy()
        transform = SimilarityTransform(
            rotation=rotation, translation=translation.numpy().copy(),
            scale=float(torch.exp(log_scale)),
        )  # fmt: skip
    return PoseAlignment(vertices=vertices, pose=pose, transform=transform, iterations=iterations)
