"""Linear blend skinning and its inverse, as pure functions.

Notation (dissertation Sec. 3.1, Eq. 3.1–3.4 and B.5–B.6):
- a skeleton of J joints with ``parents[j] < j`` (``parents[0] == -1``);
- per-joint local rotations ``R_j`` expressed in the canonical (world-aligned) axes and applied
  about the joint's rest position ``c_j``; joint 0's rotation is the global orientation;
- the rigid transform of joint j, rest → posed: ``A_j = A_parent(j) ∘ Rot(R_j, about c_j)`` with
  ``A_0 = Trans(t) ∘ Rot(R_0, about c_0)``;
- a vertex with skinning weights ``w`` is posed by the blended transform ``M = Σ_j w_j A_j``
  (Eq. B.5), and unposed by ``M⁻¹`` (Eq. B.6).

All transforms are homogeneous ``(..., 4, 4)`` matrices acting on column vectors.
"""

from __future__ import annotations

from collections.abc import Sequence

import roma
import torch
from torch import Tensor


def axis_angle_to_matrix(axis_angle: Tensor) -> Tensor:
    """Rodrigues' formula. axis_angle: (..., 3) radians → (..., 3, 3); smooth at zero."""
    return roma.rotvec_to_rotmat(axis_angle)


def matrix_to_axis_angle(rotation: Tensor) -> Tensor:
    """(..., 3, 3) rotation matrices → (..., 3) axis-angle, radians, angle in [0, π]."""
    return roma.rotmat_to_rotvec(rotation)


def homogeneous(rotation: Tensor, translation: Tensor) -> Tensor:
    """rotation (..., 3, 3), translation (..., 3) → (..., 4, 4)."""
    top = torch.cat([rotation, translation.unsqueeze(-1)], dim=-1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], dim=-2)


def joint_transforms(
    rotations: Tensor, joints: Tensor, parents: Sequence[int], translation: Tensor | None = None
) -> Tensor:
    """Rest → posed rigid transforms of every joint (forward kinematics).

    Args:
        rotations: (B, J, 3, 3) local rotations in canonical axes; index 0 is the global one.
        joints: (B, J, 3) rest joint positions (canonical frame, metres).
        parents: J parent indices, ``parents[0] = -1`` and ``parents[j] < j``.
        translation: (B, 3) global translation in metres, or None.
    Returns:
        (B, J, 4, 4) transforms ``A_j`` with posed = A_j @ rest for points rigidly attached to j.
    """
    # Rot(R, about c) = [R | c - R c]
    local = homogeneous(rotations, joints - (rotations @ joints.unsqueeze(-1)).squeeze(-1))
    root = local[:, 0]
    if translation is not None:
        root = homogeneous(root[:, :3, :3], root[:, :3, 3] + translation)
    chain = [root]
    for j in range(1, len(parents)):
        chain.append(chain[parents[j]] @ local[:, j])
    return torch.stack(chain, dim=1)


def blend_transforms(weights: Tensor, transforms: Tensor) -> Tensor:
    """Per-vertex blended transforms ``M_i = Σ_j w_ij A_j`` (Eq. B.5).

    Args:
        weights: (V, J) or (B, V, J) skinning weights (rows sum to 1).
        transforms: (B, J, 4, 4).
    Returns:
        (B, V, 4, 4).
    """
    if weights.dim() == 2:
        return torch.einsum("vj,bjmn->bvmn", weights, transforms)
    return torch.einsum("bvj,bjmn->bvmn", weights, transforms)


def transform_points(transforms: Tensor, points: Tensor) -> Tensor:
    """transforms (..., 4, 4), points (..., 3) → (..., 3): ``M p``."""
    return (transforms[..., :3, :3] @ points.unsqueeze(-1)).squeeze(-1) + transforms[..., :3, 3]


def transform_directions(transforms: Tensor, directions: Tensor) -> Tensor:
    """The linear part only: ``L d`` for transforms (..., 4, 4), directions (..., 3)."""
    return (transforms[..., :3, :3] @ directions.unsqueeze(-1)).squeeze(-1)


def transform_normals(transforms: Tensor, normals: Tensor) -> Tensor:
    """Normals by the inverse transpose ``L⁻ᵀ n``, renormalised. (..., 4, 4), (..., 3)."""
    linear = transforms[..., :3, :3]
    n = torch.linalg.solve(linear.transpose(-1, -2), normals.unsqueeze(-1)).squeeze(-1)
    return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def invert_affine(transforms: Tensor) -> Tensor:
    """Inverse of affine (..., 4, 4) matrices whose linear part is invertible (blended LBS
    transforms are not rigid in general, so this is a true 3×3 inverse, not a transpose)."""
    linear_inv = torch.linalg.inv(transforms[..., :3, :3])
    t = -(linear_inv @ transforms[..., :3, 3:]).squeeze(-1)
    return homogeneous(linear_inv, t)


def skin(vertices: Tensor, weights: Tensor, transforms: Tensor) -> Tensor:
    """Linear blend skinning (Eq. 3.1 / B.5).

    Args:
        vertices: (B, V, 3) rest vertices (template + shape + correctives + offsets).
        weights: (V, J) skinning weights, or (B, V, J) when each batch entry has its own
            vertices.
        transforms: (B, J, 4, 4) joint transforms.
    Returns:
        (B, V, 3) posed vertices.
    """
    pattern = "vj,bjmn->bvmn" if weights.dim() == 2 else "bvj,bjmn->bvmn"
    blend = torch.einsum(pattern, weights, transforms[:, :, :3, :])
    return (blend[..., :3] @ vertices.unsqueeze(-1)).squeeze(-1) + blend[..., 3]
